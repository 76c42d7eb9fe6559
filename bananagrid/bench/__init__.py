"""``bananagrid bench``: kernel throughput against NumPy (and SciPy) baselines measured in the
same run (:mod:`bananagrid.bench.runner`), and the baselines themselves
(:mod:`bananagrid.bench.baselines`)."""
