"""Recordings: rerun ``.rrd`` files of rasters, lattices and comparisons (``core`` and one
module per model family), and ``inspect``, which reads them back without a viewer."""
