"""The shared evidence weights (``kernels/evidence.py``), run through a kernel
(``engine.carried.weigh_paths``) on straight-line paths, against a NumPy float64 reference
built from the evidence objects themselves (their own likelihoods, SciPy's quadrature of the
inverse-cube rate, the exact time a straight path spends in a convex polygon), not from the
pack's arrays; in float64 and float32."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st
from scipy import integrate

import bananagrid as bg
from bananagrid.engine.carried import weigh_paths
from bananagrid.evidence.packing import AREA_PANELS, pack
from bananagrid.evidence.searches import RasterSearch

SQUARE = np.array([(0.0, 0.0), (100.0, 0.0), (100.0, 100.0), (0.0, 100.0)])


def straight(p0, v, times):
    """Positions (N, 2) at ``times`` of the path p0 + v s."""
    return np.asarray(p0)[None, :] + np.asarray(times)[:, None] * np.asarray(v)[None, :]


def time_inside_square(p0, v, t0, t1, lo=0.0, hi=100.0) -> float:
    """Exact time the path p0 + v s spends in [lo, hi]^2 for s in [t0, t1] (slab clipping)."""
    a, b = t0, t1
    for c in range(2):
        if v[c] == 0.0:
            if not lo <= p0[c] <= hi:
                return 0.0
            continue
        with np.errstate(over="ignore"):  # a subnormal speed: the slab's times are +-inf
            s1, s2 = (lo - p0[c]) / v[c], (hi - p0[c]) / v[c]
        a, b = max(a, min(s1, s2)), min(b, max(s1, s2))
    return max(0.0, b - a)


def inverse_cube_exposure(track: bg.TrackSearch, p0, v) -> float:
    """int W^2 v_leg / (8 pi r^3) dt along each leg, r from the searcher to the path (SciPy quad)."""
    total = 0.0
    w = track.sweep_width
    for (ax, ay, ta), (bx, by, tb) in zip(track.track[:-1], track.track[1:]):
        speed = math.hypot(bx - ax, by - ay) / (tb - ta)

        def rate(s):
            f = (s - ta) / (tb - ta)
            px, py = p0[0] + v[0] * s, p0[1] + v[1] * s
            r = math.hypot(px - (ax + f * (bx - ax)), py - (ay + f * (by - ay)))
            return w * w * speed / (8.0 * math.pi * r**3)

        total += integrate.quad(rate, ta, tb, epsabs=0.0, epsrel=1e-12, limit=400)[0]
    return total


def reference(evidence, p0, v):
    """Each factor's weight of the path p0 + v s, from the evidence objects."""
    out = []
    for e in evidence:
        t0, t1 = e.time_span
        if isinstance(e, bg.AreaSearch) and t1 > t0:
            coverage = -math.log(e.miss)
            out.append(math.exp(-coverage * time_inside_square(p0, v, t0, t1) / (t1 - t0)))
        elif isinstance(e, bg.TrackSearch):
            out.append(math.exp(-inverse_cube_exposure(e, p0, v)))
        else:
            x, y = straight(p0, v, [t0])[0]
            out.append(float(e.likelihood(np.array([x]), np.array([y]))[0]))
    return np.array(out)


def evidence_set():
    fix = bg.BearingFix(sensors=[(-500.0, 0.0), (600.0, 20.0)], bearings=[0.8, -0.9], sigmas=[0.3, 0.25])
    raster = RasterSearch(bg.Grid(origin=(-50.0, -50.0), dx=50.0, dy=50.0, nx=4, ny=3), t=2.5,
                          pod=[[0.1, 0.2, 0.0, 0.4], [0.3, 0.9, 0.5, 0.6], [0.05, 0.15, 0.25, 0.35]])
    return [bg.AreaSearch(SQUARE, t=2.0, pod=0.7), bg.AreaSearch(SQUARE, t=(1.0, 3.0), coverage=1.5),
            bg.TrackSearch([(-100.0, -40.0, 0.5), (300.0, -40.0, 4.0), (300.0, 200.0, 6.0)], sweep_width=60.0),
            bg.PositionReport((50.0, 50.0), t=3.0, cov=[[900.0, 300.0], [300.0, 1600.0]]),
            bg.BearingReport(fix, t=3.5), raster]


def paths(n, rng):
    p0 = rng.uniform(-60.0, 160.0, (n, 2))
    v = rng.uniform(-25.0, 25.0, (n, 2))
    return p0, v


def kernel_factors(evidence, p0, v, dtype):
    """Each factor's weight alone, through the kernels: the ``search:K`` channels of a pack
    holding one piece of evidence at a time (channel ``all``)."""
    out = np.empty((len(p0), len(evidence)))
    for k, e in enumerate(evidence):
        p = pack([e], 10.0)
        pos = np.stack([straight(a, b, p.time) for a, b in zip(p0, v)])
        out[:, k] = weigh_paths(p, pos, np.ones(len(p0)), dtype=dtype)[:, p.channel("all")]
    return out


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_each_factor_matches_the_evidence_objects(dtype):
    """Point-time factors (area at a time, report, bearings, raster) equal the objects' own
    likelihoods at the path's position to 1e-12 (float64); the area search over an interval
    errs by at most its stated quadrature bound, C x 0.35 / AREA_PANELS per crossing (two for a
    straight path through a square) in the exponent; the inverse-cube track matches SciPy's
    quadrature of the rate to 5e-5 in the exponent where the path stays over W / 4 from the
    searcher (the stated accuracy of the pack's panels). float32: the same within 2e-5 relative plus its exponent's 2e-6 (measured
    below 1e-6: single precision of a sum of a few terms, exponentiated)."""
    rng = np.random.default_rng(7)
    evidence = evidence_set()
    p0, v = paths(300, rng)
    got = kernel_factors(evidence, p0, v, dtype)
    want = np.array([reference(evidence, a, b) for a, b in zip(p0, v)])
    f32 = dtype == np.float32
    # point-time factors: the same numbers (an even-odd test and a log, exp)
    for k in (0, 3, 4, 5):
        np.testing.assert_allclose(got[:, k], want[:, k], rtol=2e-5 if f32 else 1e-12, atol=1e-30 if f32 else 0)
    # area over (1, 3), coverage 1.5: exponent within 2 crossings x C x 0.35 / AREA_PANELS
    bound = 2 * 1.5 * 0.35 / AREA_PANELS
    assert np.all(np.abs(np.log(got[:, 1]) - np.log(want[:, 1])) <= bound + (2e-6 if f32 else 1e-12))
    # the track: exposure, where the path keeps over W / 4 from the searcher at every time
    track = evidence[2]
    s = np.linspace(0.5, 6.0, 2001)
    searcher = np.column_stack([np.interp(s, track.track[:, 2], track.track[:, c]) for c in (0, 1)])
    far = np.array([np.min(np.hypot(*(straight(a, b, s) - searcher).T)) > 15.0 for a, b in zip(p0, v)])
    assert far.sum() > 100
    np.testing.assert_allclose(np.log(got[far, 2]), np.log(want[far, 2]), rtol=0.0, atol=5e-5 + (2e-5 if f32 else 0))


def test_channels_multiply_their_factors():
    """A pack of all the evidence: each channel is the product of its factors' weights (the
    kernels' own single-factor weights), times the path's density; ``prior`` is the density."""
    rng = np.random.default_rng(11)
    evidence = evidence_set()
    p0, v = paths(200, rng)
    single = kernel_factors(evidence, p0, v, np.float64)
    p = pack(evidence, 7.0)
    density = rng.uniform(0.5, 2.0, len(p0))
    pos = np.stack([straight(a, b, p.time) for a, b in zip(p0, v)])
    out = weigh_paths(p, pos, density)
    searches = [0, 1, 2, 5]
    others = [3, 4]
    np.testing.assert_allclose(out[:, p.channel("prior")], density, rtol=1e-15)
    np.testing.assert_allclose(out[:, p.channel("all")], density * single.prod(axis=1), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(out[:, p.channel("searches")], density * single[:, searches].prod(axis=1), rtol=1e-12,
                               atol=1e-300)
    np.testing.assert_allclose(out[:, p.channel("others")], density * single[:, others].prod(axis=1), rtol=1e-12,
                               atol=1e-300)
    for k in searches:
        np.testing.assert_allclose(out[:, p.channel(f"search:evidence[{k}]")],
                                   density * single[:, [k, *others]].prod(axis=1), rtol=1e-12, atol=1e-300)


@seed(20261127)
@settings(max_examples=40, deadline=None)
@given(t0=st.floats(0.0, 5.0), span=st.floats(0.0, 4.0), pod=st.floats(0.0, 1.0),
       sx=st.floats(-200.0, 200.0), sy=st.floats(-200.0, 200.0), size=st.floats(5.0, 300.0),
       vx=st.floats(-40.0, 40.0), vy=st.floats(-40.0, 40.0))
def test_area_search_sweep(t0, span, pod, sx, sy, size, vx, vy):
    """Over search times, squares and paths: a point-time search's factor is exactly 1 - POD
    inside and 1 outside; an interval's is within its stated quadrature bound."""
    square = SQUARE * (size / 100.0) + np.array([sx, sy])
    t1 = t0 + span
    e = bg.AreaSearch(square, t=(t0, t1) if span > 0 else t0, pod=pod)
    p0, v = np.array([0.0, 0.0]), np.array([vx, vy])
    got = kernel_factors([e], p0[None], v[None], np.float64)[0, 0]
    if span == 0.0:
        x, y = straight(p0, v, [t0])[0]
        assert got == float(e.likelihood(np.array([x]), np.array([y]))[0])
    else:
        inside = time_inside_square(p0 - np.array([sx, sy]), v, t0, t1, 0.0, size)
        coverage = -math.log(e.miss) if e.miss > 0 else math.inf
        want = math.exp(-coverage * inside / span) if inside > 0 else 1.0
        if math.isinf(coverage):  # POD 1: missed only by a path no node finds inside
            if inside == 0.0:
                assert got == 1.0
            elif inside >= span / AREA_PANELS:  # a whole panel's span inside holds a node
                assert got == 0.0
        else:
            assert abs(math.log(max(got, 1e-300)) - math.log(max(want, 1e-300))) <= 2 * coverage * 0.35 / AREA_PANELS + 1e-12


# ---------------------------------------------------------------------------------------------
# Definite-range tracks: a chain of chords, the closest approach of each in closed form
# ---------------------------------------------------------------------------------------------


def definite_weight(track, paths_at, h, dtype, t_map=10.0):
    """The kernel's weight (0 or 1) of each path for the track with W / 2 = h: ``paths_at(s)``
    returns the paths' positions (n, len(s), 2) at the pack's node times."""
    e = bg.TrackSearch(track, sweep_width=2.0 * h, law="definite")
    p = pack([e], t_map)
    pos = paths_at(p.time)
    return weigh_paths(p, pos, np.ones(len(pos)), dtype=dtype)[:, p.channel("all")]


def zigzag(rng, legs):
    """A searcher's track of ``legs`` legs over [0.5, 6] s, turning at random points."""
    times = np.sort(rng.uniform(0.5, 6.0, legs + 1))
    times[0], times[-1] = 0.5, 6.0
    xy = rng.uniform(-100.0, 200.0, (legs + 1, 2))
    return np.column_stack((xy, times))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_definite_closest_approach_matches_the_oracle(dtype):
    """Straight paths (the closed form is exact for them) against the oracle's closest approach
    d (dense sampling and minimize_scalar per leg, tests/support/definite_oracle.py): with W / 2
    just below d the path is missed (weight 1), just above it is detected (weight 0). The margin:
    1e-9 of d in float64 (the oracle's minimize_scalar converges to 1e-12 of a leg's time; the
    closed form rounds at 1e-15 of the coordinates, ~300 m); 3e-5 of d + 3e-3 m in float32
    (positions round at 6e-8 x 300 m = 2e-5 m, and the range to the segment at 6e-8 of it)."""
    from definite_oracle import closest_approach

    rng = np.random.default_rng(33)
    f32 = dtype == np.float32
    for trial in range(40):
        track = zigzag(rng, 1 + trial % 4)
        p0, v = rng.uniform(-100.0, 200.0, 2), rng.uniform(-40.0, 40.0, 2)
        d = closest_approach(track, lambda s, p0=p0, v=v: straight(p0, v, s))
        margin = 3e-5 * d + 3e-3 if f32 else 1e-9 * d

        def at(times, p0=p0, v=v):
            return straight(p0, v, times)[None]

        assert definite_weight(track, at, d - margin, dtype)[0] == 1.0, (trial, d)
        assert definite_weight(track, at, d + margin, dtype)[0] == 0.0, (trial, d)


def cat_paths(v0, a, omega, heading=0.0):
    """World positions (n, len(s), 2) of CAT paths with accelerations ``a`` and turn rates
    ``omega`` from the origin (eq. (1), ``models.cat.cat_position``), heading turned."""
    from bananagrid.models.cat import cat_position

    ch, sh = math.cos(heading), math.sin(heading)

    def at(times):
        out = np.stack([cat_position(v0, s, a, omega) for s in np.atleast_1d(times)], axis=1)
        return np.stack((out[..., 0] * ch + out[..., 1] * sh, -out[..., 0] * sh + out[..., 1] * ch), axis=-1)

    return at


@seed(33)
@settings(max_examples=15, deadline=None)
@given(t_map=st.floats(4.0, 60.0), start=st.floats(0.0, 0.8), span=st.floats(0.05, 0.9), legs=st.integers(1, 4),
       width=st.floats(100.0, 1500.0), v0=st.floats(20.0, 300.0), sigma_omega=st.floats(0.01, 0.2),
       heading=st.floats(-3.0, 3.0), draw=st.integers(0, 2**31 - 1))
def test_definite_chords_on_curved_paths(t_map, start, span, legs, width, v0, sigma_omega, heading, draw):
    """CAT paths (curved) over tracks, times and sweep widths: each path's weight agrees with the
    oracle's closest approach d wherever |d - W / 2| exceeds the pack's stated bound M dt^2 / 8
    (M = max over the track of sqrt(a^2 + (v0 + a s)^2 omega^2), the path's acceleration, dt
    its chords' length, t / DEFINITE_CHORDS at most), plus 1e-9 of the range for rounding. A
    third of the paths are put near grazing (d within 1e-3 W of W / 2): inside the bound either
    answer is allowed (the chord's range, a straight relative path, differs from the curve's by
    at most the bound); where the bound is below 1e-3 W (short map times, slow turns) they are
    checked too."""
    from bananagrid.evidence.packing import DEFINITE_CHORDS
    from definite_oracle import closest_approach

    rng = np.random.default_rng(draw)
    t0 = start * t_map
    t1 = min(t_map, t0 + span * t_map)
    times = np.linspace(t0, t1, legs + 1)
    n = 24
    a = rng.normal(0.0, 2.0, n)
    omega = rng.normal(0.0, sigma_omega, n)
    paths = cat_paths(v0, a, omega, heading)
    # the searcher flies near the paths' positions, crossing their way
    mid = paths(np.array([0.5 * (t0 + t1)]))[:, 0].mean(axis=0)
    track = np.column_stack((mid + rng.normal(0.0, 0.3 * v0 * (t1 - t0) + width, (legs + 1, 2)), times))
    h = 0.5 * width
    d = np.array([closest_approach(track, lambda s, k=k: paths(s)[k]) for k in range(n)])
    # a third near grazing: W / 2 moved to within 1e-3 W of those paths' closest approach is
    # the same as moving the paths; rather than move them, the test gives each its own h
    near = d + rng.uniform(-1e-3, 1e-3, n) * width
    hs = np.where((np.arange(n) % 3 == 0) & (near > 0.0), near, h)
    dt = (t1 - t0) / legs / math.ceil((t1 - t0) / legs / (t_map / DEFINITE_CHORDS) * (1.0 - 1e-12))
    s = np.linspace(t0, t1, 64)
    speed = v0 + np.abs(a)[:, None] * s[None, :]
    accel = np.sqrt(a[:, None] ** 2 + speed**2 * omega[:, None] ** 2).max(axis=1)
    bound = accel * dt * dt / 8.0 + 1e-9 * (np.abs(d) + width)
    checked = 0
    for k in range(n):
        got = definite_weight(track, lambda ts, k=k: paths(ts)[k:k + 1], hs[k], np.float64, t_map)[0]
        if abs(d[k] - hs[k]) > bound[k]:
            checked += 1
            assert got == (1.0 if d[k] > hs[k] else 0.0), (k, d[k], hs[k], bound[k])
    assert checked >= n // 2  # the paths away from grazing are all checked


def test_definite_chain_between_other_evidence():
    """A definite track's chain interleaved in time with other nodes (an area search at a time
    inside the track's span, a second definite track): each channel is the product of the
    single-evidence weights (the chains' slots kept apart, their nodes visited in time order)."""
    rng = np.random.default_rng(5)
    tracks = [bg.TrackSearch([(-50.0, 50.0, 1.0), (150.0, 60.0, 3.0), (160.0, 200.0, 4.0)], 40.0, "definite"),
              bg.TrackSearch([(0.0, 150.0, 2.0), (100.0, -20.0, 5.0)], 30.0, "definite")]
    evidence = [tracks[0], bg.AreaSearch(SQUARE, t=2.5, pod=0.6), tracks[1]]
    p0, v = paths(400, rng)
    single = kernel_factors(evidence, p0, v, np.float64)
    assert 20 < (single[:, 0] == 0).sum() < 380 and 20 < (single[:, 2] == 0).sum() < 380
    p = pack(evidence, 7.0)
    assert p.slots == 4 and p.scratch == 7
    pos = np.stack([straight(a, b, p.time) for a, b in zip(p0, v)])
    out = weigh_paths(p, pos, np.ones(len(p0)))
    np.testing.assert_array_equal(out[:, p.channel("all")], single.prod(axis=1))
    np.testing.assert_array_equal(out[:, p.channel("search:evidence[2]")], single[:, 2])
