"""The CAT cell walk's shared work (``kernels/cat_cells.py``) gives the bits of the work it
replaces: a cell's share from the tails of its entry and exit z (each tail computed once along
the walk) is ``normal_interval``'s, and the corner test's early out (a corner on one side of
every line of the ribbon) returns what the quadratic's roots would. References: the functions
they stand in for (``kernels/common.py``'s ``normal_interval``; the corner solver as written
before the early out, kept here), run in the same kernel."""

import numpy as np
import warp as wp
from hypothesis import given, seed, settings
from hypothesis import strategies as st

from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.kernels import cat_cells
from bananagrid.kernels.common import normal_interval

wp.set_module_options({"enable_backward": False})


@wp.func
def solved_corner(line: wp.vec4d, d: wp.vec4d, cx: wp.float64, cy: wp.float64, after: wp.float64,
                  best: wp.float64):
    """The least root in (after, best) of the corner's quadratic, always solved (the solver of
    ``corner_roots`` without its early out)."""
    rx = cx - line[0]
    ry = cy - line[1]
    c0 = line[2] * ry - line[3] * rx
    c1 = d[2] * ry - line[2] * d[1] - d[3] * rx + line[3] * d[0]
    c2 = d[3] * d[0] - d[2] * d[1]
    zero = wp.float64(0.0)
    scale = wp.abs(c0) + wp.abs(c1) + wp.abs(c2)
    if scale == zero:
        return best
    if wp.abs(c2) <= wp.float64(1.0e-14) * scale:
        if c1 != zero:
            r = -c0 / c1
            if r > after and r < best:
                best = r
        return best
    disc = c1 * c1 - wp.float64(4.0) * c2 * c0
    if disc < zero:
        return best
    q = wp.float64(-0.5) * (c1 + wp.sign(c1) * wp.sqrt(disc))
    r1 = q / c2
    if r1 > after and r1 < best:
        best = r1
    if q != zero:
        r2 = c0 / q
        if r2 > after and r2 < best:
            best = r2
    return best


@wp.kernel
def corners(lines: wp.array(dtype=wp.vec4d), steps: wp.array(dtype=wp.vec4d), points: wp.array(dtype=wp.vec4d),
            out: wp.array2d(dtype=wp.float64)):
    k = wp.tid()
    p = points[k]  # corner x, corner y, after, best
    out[k, 0] = cat_cells.corner_roots(lines[k], steps[k], p[0], p[1], p[2], p[3])
    out[k, 1] = solved_corner(lines[k], steps[k], p[0], p[1], p[2], p[3])


@wp.kernel
def shares(windows: wp.array(dtype=wp.vec2d), out: wp.array2d(dtype=wp.float64)):
    k = wp.tid()
    lo = windows[k][0]
    hi = windows[k][1]
    out[k, 0] = cat_cells.tail_interval(lo, hi, cat_cells.normal_tail(lo), cat_cells.normal_tail(hi))
    out[k, 1] = normal_interval(lo, hi)


def _run(kernel, n, *arrays):
    ctx = WarpContext(np.float64, "cpu", 1)
    out = ctx.zeros((n, 2), dtype=np.float64)
    ctx.launch(kernel, dim=n, inputs=[*arrays, out])
    return ctx.numpy(out)


z = st.floats(-cat_cells.Z_MAX, cat_cells.Z_MAX, allow_nan=False)


@seed(20261127)
@settings(max_examples=30, deadline=None, database=None)
@given(st.lists(st.tuples(z, z), min_size=1, max_size=64),
       st.lists(st.tuples(z, st.floats(0.0, 0.2)), min_size=1, max_size=64))
def test_a_share_from_its_tails_is_normal_intervals(pairs, narrow):
    """Any window [lo, hi] in +-Z_MAX (either side of 0, across it, at +-0 and at 0 width), and
    narrow ones like a cell's: the same bits."""
    windows = [tuple(sorted(p)) for p in pairs] + [(a, a + w) for a, w in narrow]
    windows += [(-0.0, 0.0), (0.0, 0.0), (-0.0, 1.0), (-1.0, -0.0), (0.0, cat_cells.Z_MAX), (-cat_cells.Z_MAX, 0.0)]
    got = _run(shares, len(windows), WarpContext(np.float64, "cpu", 1).array(np.array(windows), dtype=wp.vec2d))
    assert np.array_equal(got[:, 0], got[:, 1]), windows


coordinate = st.floats(-2000.0, 2000.0, allow_nan=False)
direction = st.floats(-50.0, 50.0, allow_nan=False)


@st.composite
def ribbons_and_corners(draw):
    """A ribbon's first line (point at z = 0 and step per z, grid units), its change across the
    interval (small, as the kernel's: a fraction of a cell, a slight turn; or none, or large),
    and a corner at a drawn distance from the line s (often on it or within the ribbon)."""
    line = np.array([draw(coordinate), draw(coordinate), draw(direction), draw(direction)])
    size = draw(st.sampled_from([0.0, 1e-9, 1e-4, 0.125, 1.0, 30.0]))
    d = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(4)]) * size
    s = draw(st.floats(-0.5, 1.5))
    z = draw(st.floats(-cat_cells.Z_MAX, cat_cells.Z_MAX))
    at = line + s * d
    off = draw(st.sampled_from([0.0, 1e-12, 1e-6, 1e-3, 0.1, 2.0]))
    corner = at[:2] + z * at[2:] + off * np.array([draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0))])
    after = draw(st.sampled_from([0.0, draw(st.floats(0.0, 1.0))]))
    best = draw(st.sampled_from([1.0, draw(st.floats(after, 1.0))]))
    return line, d, np.array([*corner, after, best])


@seed(20261127)
@settings(max_examples=40, deadline=None, database=None)
@given(st.lists(ribbons_and_corners(), min_size=1, max_size=64))
def test_the_corner_early_out_never_changes_a_root(cases):
    """Corners on, near and far from the ribbon's lines, ribbons narrow and wide, turning or not,
    after any pass: ``corner_roots`` returns the solver's bits."""
    ctx = WarpContext(np.float64, "cpu", 1)
    lines, steps, points = (ctx.array(np.array([c[k] for c in cases]), dtype=wp.vec4d) for k in range(3))
    got = _run(corners, len(cases), lines, steps, points)
    assert np.array_equal(got[:, 0], got[:, 1]), cases
