"""The interpolating kernels of a tabulated density (``kernels/tabulated.py``) in CPU lanes: 8
float64 or 16 float32 cells at a time, end to end (``lanes.lane_tabulated``: the square root, the
lane atan2 and exp, the stencils' weights in whole registers; each lane's 16 entries read from the
padded lattice). Values agree with the scalar kernel's to a few ulps of the log (fused
multiply-adds, the lane exp's 3 ulp): within ``models/_cat_heading.interpolation_bound``'s 0.1 %
allowance, and far inside the table's 1e-6 interpolation target.

CPU only (see ``kernels/lanes.py``); the GPU path uses ``tabulated.KERNELS``. The grid and points
kernels are generated from the one density, so that ``rasterise`` and ``pdf`` agree bit for bit.
"""

from typing import Any

import warp as wp

from .generate import density_kernels
from .lanes import lane_tabulated, tabulated_row
from .tabulated import TABLE

# No adjoints: nothing differentiates these kernels (see ``polar_lanes``).
wp.set_module_options({"enable_backward": False})


@wp.func(inline=True)
def table_density_lanes(x: Any, y: Any, p: Any):
    """The interpolated density at a vector of world points: the launch kernels' maths."""
    return lane_tabulated(x, y, p.log_table, p.table, p.r0, p.dr, p.theta0, p.dtheta, p.floor_value, p.mirror,
                          p.pose[0], p.pose[1], p.pose[2], p.pose[3])


@wp.func(inline=True)
def table_row_lanes(xs: wp.array(dtype=Any), y: Any, out: wp.array2d(dtype=Any), row: int, j0: int, j1: int, p: Any):
    """The generated grid kernel's row in one native loop (``lanes.tabulated_row``: two registers of
    lanes a step, the same bits as :func:`table_density_lanes`): 1."""
    tabulated_row(xs, y, out, row, j0, j1, p.log_table, p.table, p.r0, p.dr, p.theta0, p.dtheta, p.floor_value,
                  p.mirror, p.pose[0], p.pose[1], p.pose[2], p.pose[3])
    return 1


KERNELS = density_kernels(table_density_lanes, TABLE, "table", lanes=True, bands_per_thread=4, module=__name__,
                          row=table_row_lanes)
