"""CAT densities weighted by earlier evidence (``CAT.bind_carried`` through
``engine.carried.evaluate_carried``) against the independent float64 oracle of ``oracles.py``:
its roots (a dense scan in s = omega t and a safeguarded Newton refinement, checked against
literal eq. (1) with scipy.optimize.brentq), each weighted by the evidence objects' own
likelihoods at the root's path positions from literal eq. (1) (written here, with its series
near omega = 0). With heading noise the oracle integrates over theta_0 with scipy.integrate.quad.
And ``CAT.sample_paths``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st
from scipy import integrate

import bananagrid as bg
import oracles
from bananagrid.engine.carried import evaluate_carried
from bananagrid.evidence.packing import pack
from cases import FIG1, FOLDING

#: Relative agreement of every channel with the oracle where the prior density is above 1e-6 of
#: its largest value among the points: measured 2.8e-11 at most (both cases below; the roots
#: agree to ~1e-13 in omega t, the weights add the rounding of a few positions and a sum of
#: logs), held to 1e-9.
TOLERANCE = 1e-9


def path_position(v0, a, w, s):
    """Literal eq. (1) at time s (local frame) for arrays a, w; series below |w s| = 1e-3."""
    u = w * s
    small = np.abs(u) < 1e-3
    us = np.where(small, 1.0, u)
    f1 = np.where(small, u / 2 - u**3 / 24, (1 - np.cos(us)) / us)
    f2 = np.where(small, 1 - u**2 / 6 + u**4 / 120, np.sin(us) / us)
    f3 = np.where(small, u / 3 - u**3 / 30, (np.sin(us) - us * np.cos(us)) / us**2)
    f4 = np.where(small, 0.5 - u**2 / 8 + u**4 / 144, (np.cos(us) + us * np.sin(us) - 1) / us**2)
    return np.column_stack((v0 * s * f1 + a * s * s * f3, v0 * s * f2 + a * s * s * f4))


def oracle_channels(model, x, y, evidence, members, heading=0.0):
    """Oracle density at world points weighted by the product of ``members``' likelihoods (one
    array per list of evidence indices), the model turned by ``heading`` about its origin."""
    pose = bg.Pose(model.pose.origin, model.pose.heading + heading)
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    dx, dy = np.asarray(x) - pose.origin[0], np.asarray(y) - pose.origin[1]
    lx, ly = dx * c - dy * s, dx * s + dy * c
    out = []
    for member in members:
        def weight(index, a, w, member=member):
            total = np.ones(len(a))
            for k in member:
                e = evidence[k]
                p = pose.to_world(path_position(model.v0, a, w, e.time_span[0]))
                total = total * e.likelihood(p[:, 0], p[:, 1])
            return total

        out.append(oracles.cat_density(lx, ly, v0=model.v0, t=model.t, sigma_a=model.sigma_a,
                                       sigma_w=model.sigma_omega, weight=weight))
    return np.array(out)


def point_evidence(model, scale, t1, t2):
    """Two area searches (t1, t2) across the banana's middle at their times, a position report
    (between them), bearings (t1), a raster (t2)."""
    (cx, cy), (dx, dy) = model.sample_paths(1, [t1, t2], np.random.default_rng(1))[0]
    fix = bg.BearingFix(sensors=[(cx - 4 * scale, cy), (cx + 3 * scale, cy - 3 * scale)],
                        bearings=[math.atan2(4.0, 0.3), math.atan2(-3.0, 3.2)], sigmas=[0.2, 0.15])
    raster = bg.RasterSearch(bg.Grid.from_bounds(x=(dx - scale, dx + scale), y=(dy - scale, dy + scale),
                                                 step=scale / 2), t=t2, pod=[[0.2, 0.5, 0.1, 0.0], [0.9, 0.3, 0.6, 0.4],
                                                                             [0.7, 0.8, 0.05, 0.5], [0.1, 0.2, 0.3, 0.4]])
    return [bg.AreaSearch([(cx - scale, cy - 0.4 * scale), (cx + 0.2 * scale, cy - 0.6 * scale),
                           (cx + 0.5 * scale, cy + 0.3 * scale), (cx - 0.6 * scale, cy + 0.5 * scale)], t=t1, pod=0.7),
            bg.AreaSearch([(dx, dy - scale), (dx + 2 * scale, dy - scale), (dx + 2 * scale, dy + scale), (dx, dy + scale)],
                          t=t2, pod=0.55),
            bg.PositionReport((cx + 0.2 * scale, cy), t=0.5 * (t1 + t2), cov=[[scale**2, 0.0], [0.0, (2 * scale) ** 2]]),
            bg.BearingReport(fix, t=t1),
            raster]


def check_channels(model, evidence, points, tolerance=TOLERANCE, dtype=np.float64):
    p = pack(evidence, model.t)
    got = evaluate_carried(model, points[:, 0], points[:, 1], p, dtype=dtype)
    names = list(p.channel_names)
    members = []
    for name in names:
        searches = [k for k, e in enumerate(evidence) if e.kind == "search"]
        others = [k for k, e in enumerate(evidence) if e.kind != "search"]
        members.append({"prior": [], "all": list(range(len(evidence))), "searches": searches,
                        "others": others}.get(name) or ([int(name.split("[")[1][:-1]), *others]
                                                        if name.startswith("search:") else []))
    want = oracle_channels(model, points[:, 0], points[:, 1], evidence, members)
    prior = want[0]
    floor = 1e-6 * prior.max()
    inside = prior >= floor
    assert inside.sum() >= 0.5 * len(points)
    for c, name in enumerate(names):
        w = want[c][inside]
        g = got[c][inside]
        # relative where the channel itself is above the floor, absolute below (the weight may
        # be 0: a search with POD 1)
        big = w >= floor
        assert np.all(np.abs(g[big] / w[big] - 1.0) <= tolerance), (name, np.max(np.abs(g[big] / w[big] - 1.0)))
        assert np.all(np.abs(g[~big] - w[~big]) <= tolerance * floor), name
    return got, want


CASES = {
    "figure1": (bg.CAT(**FIG1), 60.0, 4.0, 7.0),
    "folding, posed": (bg.CAT(**FOLDING, pose=bg.Pose((500.0, -300.0), 0.7)), 300.0, 3.0, 8.0),
}


@pytest.mark.parametrize("name", list(CASES))
def test_every_channel_matches_the_oracle(name):
    """Points drawn from the model itself (so they crowd where the mass is, folds included): the
    prior channel, all the evidence, the searches, the reports and each search with the
    reports agree with the weighted oracle to TOLERANCE."""
    model, scale, t1, t2 = CASES[name]
    points = model.sample(400, np.random.default_rng(3))
    got, want = check_channels(model, point_evidence(model, scale, t1, t2), points)
    # each search matters: its channel differs from the reports' alone
    for c in (2, 4, 5, 6):
        assert np.max(np.abs(got[c] / np.maximum(got[3], 1e-300) - 1.0)) > 0.1


@seed(20261127)
@settings(max_examples=10, deadline=None)
@given(t_frac=st.floats(0.05, 0.95), gap=st.floats(0.0, 0.5), size=st.floats(0.2, 3.0),
       shift=st.floats(-1.0, 1.0), v0=st.floats(5.0, 300.0), t=st.floats(5.0, 600.0),
       sigma_a=st.floats(0.01, 2.0), turn=st.floats(0.02, 1.5), heading=st.floats(-math.pi, math.pi))
def test_sweep_search_times_shapes_and_parameters(t_frac, gap, size, shift, v0, t, sigma_a, turn, heading):
    """Over search times, polygon sizes and places and the CAT's parameters (sigma_omega t up to
    1.5 rad, folds included): every channel equals the weighted oracle to TOLERANCE."""
    model = bg.CAT(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=turn / t, pose=bg.Pose((100.0, -50.0), heading))
    t1 = t_frac * t
    t2 = min(t, t1 + gap * t)
    centre = model.sample_paths(1, [t1], np.random.default_rng(2))[0, 0]
    spread = max(0.5 * sigma_a * t1**2, v0 * t1 * 0.3 * turn, 1.0)
    cx, cy = centre[0] + shift * spread, centre[1]
    evidence = [bg.AreaSearch([(cx - size * spread, cy - size * spread), (cx + size * spread, cy - 0.5 * size * spread),
                               (cx, cy + size * spread)], t=t1, pod=0.8),
                bg.AreaSearch([(cx, cy - 3 * spread), (cx + 4 * spread, cy - 3 * spread), (cx + 4 * spread, cy + 3 * spread),
                               (cx, cy + 3 * spread)], t=t2, pod=0.5)]
    points = model.sample(40, np.random.default_rng(5))
    check_channels(model, evidence, points)


def test_float32_within_its_bound():
    """float32 kernels against float64 where the prior channel exceeds 1e-6 of its largest
    value: within 1e-3 relative (measured 1.9e-4: the plain kernel's stated float32_rtol 2e-4,
    and a path's positions and log-weights in single precision; a path within float32 rounding
    of a polygon's edge could fall on the other side: none does among these points)."""
    model, scale, t1, t2 = CASES["figure1"]
    evidence = point_evidence(model, scale, t1, t2)
    points = model.sample(1000, np.random.default_rng(9))
    p = pack(evidence, model.t)
    f64 = evaluate_carried(model, points[:, 0], points[:, 1], p, dtype=np.float64)
    f32 = evaluate_carried(model, points[:, 0], points[:, 1], p, dtype=np.float32)
    big = f64[0] >= 1e-6 * f64[0].max()
    for c in range(f64.shape[0]):
        keep = big & (f64[c] >= 1e-6 * f64[0].max())
        assert np.all(np.abs(f32[c][keep] / f64[c][keep] - 1.0) <= 1e-3), (p.channel_names[c],
                                                                         np.max(np.abs(f32[c][keep] / f64[c][keep] - 1)))


def heading_oracle(model, x, y, evidence, members):
    """int g(theta_0) weighted density of the model turned by theta_0 d theta_0, by quad."""
    base = bg.CAT(v0=model.v0, t=model.t, sigma_a=model.sigma_a, sigma_omega=model.sigma_omega, pose=model.pose)
    sd = model.sigma_heading

    def integrand(theta):
        g = math.exp(-0.5 * (theta / sd) ** 2) / (sd * math.sqrt(2.0 * math.pi))
        return g * oracle_channels(base, np.array([x]), np.array([y]), evidence, [members], heading=theta)[0, 0]

    return integrate.quad(integrand, -8 * sd, 8 * sd, limit=400, epsabs=0.0, epsrel=1e-10, points=[0.0])[0]


def test_heading_noise_rule_and_its_error():
    """With heading noise the kernel's trapezoidal rule in theta_0 (``heading_nodes``) against
    quad over theta_0 of the oracle: smooth evidence (a report, bearings) within 1e-6 relative;
    an area search (whose weight jumps where a turned path's position crosses the polygon's
    edge) within 2e-2 of the prior channel: the rule is first order at a jump, at most one
    node's share of the integrand times the jump (measured 1.4e-2 at worst among these points
    with 6 nodes per scale; 2.9e-3 with 12 and 3.2e-3 with 24: erratic, as the jump moves
    between nodes). Cell probabilities average it out (the Monte Carlo test with heading noise,
    tests/evidence/test_carried_posterior.py)."""
    model = bg.CAT(**FIG1, sigma_heading=0.05)
    fix = bg.BearingFix(sensors=[(-2000.0, 1000.0), (2000.0, 0.0)], bearings=[math.atan2(2000.0, 400.0),
                                                                            math.atan2(-2000.0, 1400.0)],
                        sigmas=[0.2, 0.2])
    smooth = [bg.PositionReport((100.0, 1350.0), t=5.0, sigma=150.0), bg.BearingReport(fix, t=6.0)]
    area = [bg.AreaSearch([(-300.0, 1000.0), (60.0, 1000.0), (60.0, 1500.0), (-300.0, 1500.0)], t=5.0, pod=0.8)]
    points = model.sample(6, np.random.default_rng(4))
    for evidence, rtol in ((smooth, 1e-6), (area, 2e-2)):
        p = pack(evidence, model.t)
        got = evaluate_carried(model, points[:, 0], points[:, 1], p)
        for i, (x, y) in enumerate(points):
            want_all = heading_oracle(model, x, y, evidence, list(range(len(evidence))))
            want_prior = heading_oracle(model, x, y, evidence, [])
            assert abs(got[p.channel("all"), i] - want_all) <= rtol * want_prior, (i, got[1, i], want_all)
            assert abs(got[p.channel("prior"), i] / want_prior - 1.0) <= 1e-6


def test_sample_paths_is_samples_story():
    """``sample_paths(n, [t])[:, 0]`` is ``sample(n)`` for the same seed (with heading noise too),
    and the positions at earlier times are eq. (1) of the same draws."""
    for model in (bg.CAT(**FIG1, pose=bg.Pose((10.0, 20.0), 0.3)), bg.CAT(**FIG1, sigma_heading=0.1)):
        paths = model.sample_paths(1000, [model.t, 3.0, 0.0], np.random.default_rng(8))
        np.testing.assert_array_equal(paths[:, 0], model.sample(1000, np.random.default_rng(8)))
        assert paths.shape == (1000, 3, 2)
        np.testing.assert_allclose(paths[:, 2], np.broadcast_to(model.pose.origin, (1000, 2)), atol=1e-12)
        rng = np.random.default_rng(8)
        a, w = rng.normal(0, model.sigma_a, 1000), rng.normal(0, model.sigma_omega, 1000)
        theta = rng.normal(0, model.sigma_heading, 1000) if model.sigma_heading > 0 else np.zeros(1000)
        local = path_position(model.v0, a, w, 3.0)
        c, s = np.cos(model.pose.heading + theta), np.sin(model.pose.heading + theta)
        world = np.column_stack((model.pose.origin[0] + local[:, 0] * c + local[:, 1] * s,
                                 model.pose.origin[1] - local[:, 0] * s + local[:, 1] * c))
        # the closed forms here cancel by eps / u^2 just above the series' |u| = 1e-3 (2e-10)
        np.testing.assert_allclose(paths[:, 1], world, rtol=1e-11, atol=1e-9)


@pytest.mark.parametrize("times, message", [
    ([1.0, -2.0], r"^times = \[1\.0, -2\.0\]: expected finite times >= 0"),
    ([], r"^times = \[\]: expected finite times >= 0"),
    ([float("nan")], r"^times = \[nan\]: expected finite times >= 0"),
])
def test_sample_paths_bad_times(times, message):
    with pytest.raises(bg.BananagridError, match=message) as caught:
        bg.CAT(**FIG1).sample_paths(10, times, np.random.default_rng(0))
    assert "\n" not in str(caught.value)


class _ScalarScan:
    """A CPU context that tells the model it is not on the CPU, so that it binds the scalar
    scan (the GPU path's kernel) instead of the lanes."""

    def __init__(self, ctx):
        self._ctx = ctx
        self.device = "not-cpu"

    def __getattr__(self, name):
        return getattr(self._ctx, name)


def test_scalar_scan_equals_the_lanes():
    """The carried kernel of the scalar scan (``kernels/cat.py``, used on a GPU) and of the lanes
    (``kernels/cat_lanes.py``, the CPU's) give the same channels bit for bit (float64 and
    float32), with heading noise too: the lanes only flag the node intervals, the roots and
    their weights are the same functions."""
    from bananagrid.engine.carried import evidence_struct
    from bananagrid.engine.points import PointsExtent
    from bananagrid.engine.warp_runtime import WarpContext

    for model in (bg.CAT(**FIG1), bg.CAT(**FIG1, sigma_heading=0.03)):
        evidence = point_evidence(model, 60.0, 4.0, 7.0)
        p = pack(evidence, model.t)
        points = model.sample(300, np.random.default_rng(6))
        for dtype in (np.float64, np.float32):
            lanes = evaluate_carried(model, points[:, 0], points[:, 1], p, dtype=dtype)
            ctx = WarpContext(dtype, "cpu", 1)
            binding = model.bind_carried(_ScalarScan(ctx), PointsExtent(points[:, 0], points[:, 1]), p)
            assert "cat_lanes" not in binding.kernel_name
            ctx.load(binding.kernels.points)
            out = ctx.zeros((len(points), p.channels.shape[0]))
            ctx.launch(binding.kernels.points, dim=len(points), inputs=[
                ctx.array(points[:, 0]), ctx.array(points[:, 1]), 0, binding.params, evidence_struct(ctx, p),
                ctx.zeros((len(points), p.factors)), out])
            np.testing.assert_array_equal(ctx.numpy(out).T, lanes)


#: A definite-range track across the Figure 1 paths' way (detected iff within 100 m), 1.5 s to 5 s.
DEFINITE = bg.TrackSearch([(150.0, 400.0, 1.5), (150.0, 1300.0, 4.5), (0.0, 1600.0, 5.0)], sweep_width=200.0,
                          law="definite")


def definite_oracle_channels(model, points, evidence):
    """The channels ``prior`` and ``all`` of the oracle with a definite track (first in
    ``evidence``): each root's path weighted by 0 where its closest approach (definite_oracle:
    minimize_scalar per leg on literal eq. (1)) is within W / 2, the rest by their likelihoods;
    and which points have a root whose closest approach is within ``band`` of W / 2."""
    from bananagrid.evidence.packing import DEFINITE_CHORDS
    from definite_oracle import closest_approach

    track, h = evidence[0].track, 0.5 * evidence[0].sweep_width
    dt = model.t / DEFINITE_CHORDS
    grazing = np.zeros(len(points), dtype=bool)

    def weight(index, a, w):
        out = np.ones(len(a))
        for i, (ai, wi) in enumerate(zip(a, w)):
            d = closest_approach(track, lambda s: model.pose.to_world(
                np.vstack([path_position(model.v0, np.array([ai]), np.array([wi]), u) for u in s])))
            # the pack's chords: a path of acceleration M may be misjudged within M dt^2 / 8
            speed = model.v0 + abs(ai) * track[-1, 2]
            band = math.sqrt(ai * ai + (speed * wi) ** 2) * dt * dt / 8.0 + 1e-9 * d
            grazing[index[i]] |= abs(d - h) <= band
            out[i] = 0.0 if d <= h else 1.0
        for e in evidence[1:]:
            p = model.pose.to_world(path_position(model.v0, a, w, e.time_span[0]))
            out = out * e.likelihood(p[:, 0], p[:, 1])
        return out

    assert model.pose == bg.Pose((0.0, 0.0), 0.0)  # the local frame is the world's
    all_ = oracles.cat_density(points[:, 0], points[:, 1], v0=model.v0, t=model.t, sigma_a=model.sigma_a,
                               sigma_w=model.sigma_omega, weight=weight)
    return all_, grazing


def test_definite_track_matches_the_oracle():
    """The Figure 1 CAT with a definite-range track and an area search: channel ``all`` equals
    the oracle (each root weighted by its exact closest approach) to TOLERANCE, at every point
    whose roots all keep more than the chords' bound M dt^2 / 8 from grazing (the others are
    counted: a handful at most, where the pack's chords may judge either way); the track
    removes a share of the paths."""
    model = bg.CAT(**FIG1)
    evidence = [DEFINITE, bg.AreaSearch([(-400.0, 900.0), (150.0, 950.0), (250.0, 1400.0), (-300.0, 1350.0)], t=4.0,
                                        pod=0.8)]
    points = model.sample(100, np.random.default_rng(21))
    p = pack(evidence, model.t)
    got = evaluate_carried(model, points[:, 0], points[:, 1], p)
    want, grazing = definite_oracle_channels(model, points, evidence)
    prior = got[p.channel("prior")]
    keep = (prior >= 1e-6 * prior.max()) & ~grazing
    assert keep.sum() >= 90
    g, w = got[p.channel("all")][keep], want[keep]
    big = w >= 1e-6 * prior.max()
    np.testing.assert_allclose(g[big], w[big], rtol=TOLERANCE)
    assert np.all(np.abs(g[~big] - w[~big]) <= TOLERANCE * 1e-6 * prior.max())
    assert 0.1 < float(np.mean(g / prior[keep])) < 0.9


def test_definite_track_float32():
    """float32 against float64 with the definite-range track: within the float32 bound above
    (1e-3 relative) at all points but those where a root's path grazes the corridor within
    float32's rounding of the positions (measured: none of the 603 points above the floor, the
    largest difference 2e-5; at most 1 % allowed, each such point off by that root's share of
    its density)."""
    model = bg.CAT(**FIG1)
    points = model.sample(1000, np.random.default_rng(9))
    p = pack([DEFINITE], model.t)
    f64 = evaluate_carried(model, points[:, 0], points[:, 1], p, dtype=np.float64)
    f32 = evaluate_carried(model, points[:, 0], points[:, 1], p, dtype=np.float32)
    c = p.channel("all")
    keep = (f64[0] >= 1e-6 * f64[0].max()) & (f64[c] >= 1e-6 * f64[0].max())
    off = np.abs(f32[c][keep] / f64[c][keep] - 1.0) > 1e-3
    assert off.sum() <= 0.01 * keep.sum(), off.sum()
    assert keep.sum() > 300
