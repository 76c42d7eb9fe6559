"""Where to look next: search effort spread over a map of cell probabilities to maximise the
probability of success (:mod:`~bananagrid.planning.allocation`), under a detection law
(:mod:`~bananagrid.planning.detection`)."""
