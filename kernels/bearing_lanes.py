"""The bearing-fix kernels in CPU lanes: 8 float64 or 16 float32 cells at a time, by
``bearing.bearing_density`` itself on vectors of cells (the lane atan2, wrap and exp, every other
step in the scalar kernel's order): one cell at a time it ran at 0.7x NumPy's speed on one core
(docs/speed.md; NumPy's arctan2 and exp are SIMD loops).

CPU only (see ``kernels/lanes.py``); the GPU path uses ``bearing.KERNELS``. The grid and points
kernels are generated from the one density, so that ``rasterise`` and ``pdf`` agree bit for bit.
"""

import warp as wp

from .bearing import BEARING, bearing_density
from .generate import density_kernels

# No adjoints: nothing differentiates these kernels (see ``polar_lanes``).
wp.set_module_options({"enable_backward": False})

KERNELS = density_kernels(bearing_density, BEARING, "bearing", lanes=True, bands_per_thread=4, module=__name__)
