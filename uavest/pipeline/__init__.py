"""Log-to-result pipelines: attitude replay of flight logs (:mod:`.replay`) and
forward-backward smoothing on manifolds (:mod:`.smooth`)."""
