"""Warp device code for bananagrid, installed as ``bananagrid.kernels``.

Only ``@wp.func`` math and ``@wp.kernel`` rasterisers live here; nothing imports from
``bananagrid``. One module per model family, so each compiles as one unit.
"""
