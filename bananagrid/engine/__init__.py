"""The engine: Warp's runtime and every kernel launch (grids, points, polar-lattice cells,
batches). It knows models only through :mod:`bananagrid.protocol`."""

from .batch import frame, pdf_batch, rasterise_batch
from .points import evaluate_points, launch_points
from .polar_cells import rasterise_lattice
from .rasterise import rasterise
from .warp_runtime import WarpContext, default_threads

__all__ = [
    "rasterise", "rasterise_lattice", "evaluate_points", "launch_points", "rasterise_batch", "pdf_batch",
    "frame", "WarpContext", "default_threads",
]
