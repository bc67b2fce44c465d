"""Applications: a source, the engine, evaluation sinks and outputs composed into one job
(``replay`` of a log; the live estimator). The command line calls these; they call the
layers below (ingest, engine, eval, sinks) and nothing below calls them."""
