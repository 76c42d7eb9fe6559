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
