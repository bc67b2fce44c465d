"""Experiments: Monte Carlo trials of the benchmark systems (:mod:`.montecarlo`) and of
the radar scenarios (:mod:`.radar`), and the speed benchmark (:mod:`.speed`)."""
