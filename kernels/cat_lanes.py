"""The CAT scan in CPU lanes: F at 8 (float64) or 16 (float32) turn-rate nodes at a time.

The exact CAT kernel (``kernels/cat.py``) scans every cell's turn-rate nodes for intervals that
can hold a root: F = hx y - hy x - c at each node, and a cheap test on each interval (a sign
change, or an end within the chord bound of zero). That scan took about half of the kernel's
time (0.34 s of 0.73 s on the bench's Figure 1 grid, one core). Here the test runs on a group of
intervals at once (``lanes.cat_scan_group``: F at the group's nodes and at their predecessors,
from the table's columns regrouped into vectors by :func:`node_groups`, with the scalar scan's
arithmetic), and each flagged interval is examined by the scalar kernel's own
``cat.cat_node_interval``, in node order. The density is therefore the scalar kernel's, bit for
bit (``tests/kernels/test_lanes.py`` checks it).

CPU only (see ``kernels/lanes.py``); the GPU path uses ``cat.KERNELS``.
"""

from typing import Any

import numpy as np
import warp as wp

from .cat import CAT, CAT_CARRIED, SPLIT, cat_node_interval, cat_scan_noise
from .evidence import EVIDENCE
from .generate import Params, carried_points_kernel, density_kernels
from .common import LANES32, LANES64, lanes32, lanes64, world_to_local
from .lanes import cat_scan_group

# No adjoints: nothing differentiates these kernels (see ``polar_lanes``); the scan's split
# loops stay loops, as in ``cat`` (its module options say why).
wp.set_module_options({"enable_backward": False, "max_unroll": SPLIT - 1})

#: Rows of the node groups: omega, hx, hy, c at nodes 1 + L g .. L (g + 1), then the same at the
#: nodes before them.
GROUP_ROWS = 8


def node_groups(table: np.ndarray, lanes: int) -> np.ndarray:
    """The scan table's omega, hx, hy and c columns at nodes 1 .. n - 1 and at their predecessors
    0 .. n - 2, in groups of ``lanes`` (the last padded with its last node, which the count of
    live intervals then leaves out): shape (GROUP_ROWS, groups, lanes)."""
    n = table.shape[0]
    groups = -(-(n - 1) // lanes)
    out = np.empty((GROUP_ROWS, groups * lanes), dtype=table.dtype)
    for c in range(4):
        for row, nodes in ((c, table[1:, c]), (4 + c, table[:-1, c])):
            out[row, : n - 1] = nodes
            out[row, n - 1 :] = nodes[-1]
    return out.reshape(GROUP_ROWS, groups, lanes)


@wp.func
def group_width(groups: wp.array2d(dtype=lanes64)):
    """Intervals per group (8 float64 lanes)."""
    return LANES64


@wp.func
def group_width(groups: wp.array2d(dtype=lanes32)):  # noqa: F811
    return LANES32


@wp.func
def cat_density_lanes(
    x: Any,
    y: Any,
    table: wp.array2d(dtype=Any),
    groups: wp.array2d(dtype=Any),
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    tol: Any,
    eps: Any,
    carry: Any,
    lw: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """``cat.cat_density_local`` with its scan over nodes in lanes (``groups``: :func:`node_groups`);
    ``carry``, ``lw``, ``out`` as there (the integer 0 and any rows: no evidence)."""
    density = type(x)(0.0)
    r, noise_f, noise_g, chord_coef = cat_scan_noise(x, y, v0, t, eps)
    n = table.shape[0]
    width = group_width(groups)
    for g in range(groups.shape[1]):
        k = 1 + g * width  # the node that the group's first interval ends at
        flags = cat_scan_group(groups, g, x, y, chord_coef, noise_f, n - k)
        if flags != 0:
            for j in range(width):
                if ((flags >> j) & 1) != 0:
                    density += cat_node_interval(x, y, table, k + j, v0, t, sigma_a, sigma_omega, tol, r, noise_f,
                                                 noise_g, carry, lw, out)
    return density


@wp.func
def cat_density_world_lanes(x: Any, y: Any, p: Any):
    """Density per m^2 at the world point (x, y), the scan in lanes: the launch kernels' maths."""
    lx, ly = world_to_local(x, y, p.pose)
    return cat_density_lanes(lx, ly, p.table, p.groups, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, p.eps, int(0),
                             p.table[0], p.table[0])


#: The scalar kernels' parameters and the node groups (:func:`node_groups`).
CAT_LANES = Params("CatLaneParams", __name__, **CAT.fields,
                   groups=lambda scalar: wp.array2d(dtype=lanes64 if scalar == wp.float64 else lanes32))
# one cell per thread, the nodes in lanes: the generated scalar kernels
KERNELS = density_kernels(cat_density_world_lanes, CAT_LANES, "cat", suffix="_lanes")



@wp.func
def cat_carried_lanes(x: Any, y: Any, p: Any, ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    """``cat.cat_carried`` with the scan over nodes in lanes."""
    carry = p.carry
    carry.ev = ev
    for i in range(p.weights.shape[0]):
        carry.pose = p.poses[i]
        carry.scale = p.weights[i]
        lx, ly = world_to_local(x, y, carry.pose)
        cat_density_lanes(lx, ly, p.table, p.groups, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, p.eps, carry, lw,
                          out)


#: The carried kernel's parameters with the node groups.
CAT_CARRIED_LANES = Params("CatCarriedLaneParams", __name__, **CAT_CARRIED.fields,
                           groups=lambda scalar: wp.array2d(dtype=lanes64 if scalar == wp.float64 else lanes32))
CARRIED_POINTS = carried_points_kernel(cat_carried_lanes, CAT_CARRIED_LANES, EVIDENCE, "cat")
