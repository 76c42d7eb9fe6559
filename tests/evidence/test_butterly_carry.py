"""Butterly's carried maps: earlier evidence weighed inside the course integral
(``Butterly.bind_carried``, kernels/butterly.py's carried section), against the independent
scipy.quad oracle (tests/support/butterly_carry_oracle.py), the prior's own density, float32,
and bad input. The Monte Carlo check of the generative story is in test_butterly_monte_carlo.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid import BananagridError
from bananagrid.engine.carried import evaluate_carried
from bananagrid.evidence.packing import pack
from butterly_carry_oracle import carried_density

#: The kernel's course rule (Gauss-Legendre panels of 1.6 of the integrand's narrowest width,
#: the density's own trapezoid sum where no break cuts an arc) against the oracle's quad at a
#: relative 1e-12: both converge to ~1e-13 (measured: 1e-14 on the cases below), so 1e-9 leaves
#: room for the rounding of exponents at r / sigma ~ 50 (eps r / sigma |residual| ~ 1e-12).
RTOL = 1e-9


def butterly(rho=0.5, sx=300.0, sy=150.0, speeds=(3.0, 6.0), weights=(0.4, 0.6), t=1000.0, kappa=0.0, mean=(100.0, -50.0)):
    cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
    return bg.Butterly(mean=mean, cov=cov, speeds=list(speeds), weights=list(weights), t=t, course_kappa=kappa,
                       course_mean=0.7)


def rect(x0, x1, y0, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


NORTH = bg.AreaSearch(rect(-2000, 3000, 1000, 2500), t=400.0, pod=0.8)
TRIANGLE = bg.AreaSearch([(0, -4000), (2500, -4000), (1000, 0)], t=700.0, pod=0.6)
REPORT = bg.PositionReport((1500.0, 1500.0), t=500.0, sigma=800.0)
BEARINGS = bg.BearingReport(bg.BearingFix(sensors=[(-8000.0, 0.0), (0.0, -9000.0)],
                                          bearings=[math.radians(80.0), math.radians(15.0)],
                                          sigmas=[math.radians(5.0), math.radians(5.0)]), t=800.0)
BARRIER = bg.AreaSearch(rect(-5000, 5000, 2000, 3000), t=(200.0, 600.0), coverage=1.5)
STAR = bg.AreaSearch([(0, 3000), (700, 800), (3000, 700), (900, -300), (1800, -3000), (0, -1000), (-1800, -3000),
                      (-900, -300), (-3000, 700), (-700, 800)], t=300.0, pod=0.9)

#: A patrol's definite-range track across the paths' way (legs from 300 s to 850 s, 600 m wide).
PATROL = bg.TrackSearch([(-3000.0, 1500.0, 300.0), (3000.0, 2000.0, 600.0), (2500.0, -2500.0, 850.0)],
                        sweep_width=600.0, law="definite")

CASES = {
    "definite-range track": [PATROL],
    "definite-range track with searches and a report": [NORTH, PATROL, BARRIER, REPORT],
    "two point-time searches": [NORTH, TRIANGLE],
    "searches and a report": [NORTH, TRIANGLE, REPORT],
    "bearings": [BEARINGS],
    "star search, same time as the map": [STAR, bg.AreaSearch(rect(-500, 500, -500, 500), t=1000.0, pod=0.5)],
    "search over an interval": [BARRIER],
}


def points(model, n=6, seed_=1):
    return model.sample(n, np.random.default_rng(seed_))


@pytest.mark.parametrize("name", list(CASES))
def test_carried_density_matches_the_oracle(name):
    """The "all" channel against the oracle; an area search over an interval exactly (the time
    a straight path spends inside: Butterly's kernel takes the path's segment, not the pack's
    time nodes)."""
    model = butterly()
    evidence = CASES[name]
    p = points(model, 8)
    got = evaluate_carried(model, p[:, 0], p[:, 1], pack(evidence, model.t))
    assert np.any(got[1] < 0.99 * got[0])  # the evidence weighs these points' paths
    want = carried_density(model, evidence, p[:, 0], p[:, 1])
    # a definite track's switches are bisected to 1e-13 of the arc (the oracle's to 1e-14 rad):
    # where it removes nearly all of a point's paths, the rest is within 1e-12 of the prior's
    np.testing.assert_allclose(got[1], want, rtol=RTOL, atol=1e-12 * float(got[0].max()))


def test_prior_channel_is_the_density():
    """The "prior" channel (no factor) is the model's pdf: where no break cuts an arc it is the
    same trapezoid sum (to rounding), elsewhere the Gauss-Legendre pieces (1e-12: their error
    bound, 5e-14 per panel, over a few dozen panels)."""
    model = butterly()
    p = points(model, 40)
    got = evaluate_carried(model, p[:, 0], p[:, 1], pack([NORTH, TRIANGLE, BARRIER], model.t))
    np.testing.assert_allclose(got[0], model.pdf(p[:, 0], p[:, 1]), rtol=1e-12, atol=0.0)
    empty = evaluate_carried(model, p[:, 0], p[:, 1], pack([], model.t))
    np.testing.assert_allclose(empty[0], model.pdf(p[:, 0], p[:, 1]), rtol=1e-14, atol=0.0)


def test_channels_combine_their_factors():
    """Each search's channel is that search's weighting alone (no reports here): compared with
    the oracle given that search only; "searches" equals "all" without reports."""
    model = butterly()
    p = points(model, 4, 3)
    pk = pack([NORTH, TRIANGLE], model.t)
    got = evaluate_carried(model, p[:, 0], p[:, 1], pk)
    for k, search in enumerate((NORTH, TRIANGLE)):
        want = carried_density(model, [search], p[:, 0], p[:, 1])
        np.testing.assert_allclose(got[pk.channel(f"search:evidence[{k}]")], want, rtol=RTOL, atol=0.0)
    np.testing.assert_array_equal(got[pk.channel("searches")], got[pk.channel("all")])


@pytest.mark.parametrize("panels", [16, 40])
def test_interval_search_of_another_rule_keeps_its_nodes(panels):
    """A polygon factor whose nodes are not one composite Gauss-Legendre rule over an interval
    (the pack's nodes, one moved) is taken node by node, as the pack states it: within the time
    rule's bound of the exact weight. With 40 panels (160 nodes, more than ACTIVE) every polygon
    node is visited at every piece."""
    model = butterly()
    p = points(model, 6, 5)
    pk = pack([BARRIER], model.t, area_panels=panels)
    uneven = dict(pk.__dict__)
    times = pk.time.copy()
    times[0] = times[0] + 1e-3 * (times[1] - times[0])
    times.setflags(write=False)
    uneven["time"] = times
    odd = type(pk)(**uneven)
    got = evaluate_carried(model, p[:, 0], p[:, 1], odd)[1]
    exact = carried_density(model, [BARRIER], p[:, 0], p[:, 1])
    # the pack's rule errs by at most C 0.35 / panels per crossing of an edge (two at most)
    bound = math.expm1(2 * 1.5 * 0.35 / panels)
    assert np.all(np.abs(got - exact) <= bound * exact)
    assert not np.allclose(got, exact, rtol=1e-9, atol=0.0)  # node by node: not the exact rule


POLYGONS = st.lists(st.tuples(st.floats(0.2, 1.0), st.floats(-0.2, 0.2)), min_size=3, max_size=7)


@seed(20261127)
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shape=POLYGONS, centre=st.tuples(st.floats(-3000, 3000), st.floats(-3000, 3000)),
       size=st.floats(500.0, 4000.0), when=st.floats(0.0, 1.0), pod=st.floats(0.0, 1.0),
       speed=st.floats(0.5, 12.0), kappa=st.sampled_from([0.0, 0.5, 4.0]), rho=st.floats(-0.9, 0.9),
       report_t=st.floats(0.0, 1.0), length=st.sampled_from([0.0, 0.05, 0.4]))
def test_sweep_against_the_oracle(shape, centre, size, when, pod, speed, kappa, rho, report_t, length):
    """Star-shaped polygons (vertices at sorted angles, random radii: not convex), searches at
    one time or over intervals of 5 % and 40 % of the map's time, anywhere in the span, PODs,
    speeds (r / sigma_min up to ~90), von Mises concentrations and correlations, with a
    position report: every point within RTOL of the oracle (intervals exactly)."""
    k = len(shape)
    angles = np.sort(2 * math.pi * (np.arange(k) / k + np.array([d for _, d in shape]) / k))
    radii = np.array([a for a, _ in shape]) * size
    vertices = np.column_stack((centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)))
    model = butterly(rho=rho, speeds=(speed,), weights=(1.0,), kappa=kappa)
    start = when * (1.0 - length) * model.t
    span = start if length == 0.0 else (start, start + length * model.t)
    evidence = [bg.AreaSearch(vertices, t=span, pod=pod),
                bg.PositionReport((centre[0], centre[1] + 500.0), t=report_t * model.t, sigma=3000.0)]
    p = points(model, 3, 7)
    got = evaluate_carried(model, p[:, 0], p[:, 1], pack(evidence, model.t))[1]
    want = carried_density(model, evidence, p[:, 0], p[:, 1])
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-300)


@seed(20261128)
@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shape=POLYGONS, shift=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
       size=st.floats(500.0, 4000.0), when=st.floats(0.0, 1.0), coverage=st.floats(0.1, 3.0),
       speed=st.floats(0.5, 12.0), rho=st.floats(-0.9, 0.9), length=st.sampled_from([0.02, 0.1, 0.4]),
       second=st.booleans())
def test_interval_searches_alone_against_the_oracle(shape, shift, size, when, coverage, speed, rho, length, second):
    """Searches over intervals with no other evidence (the kernel then takes one weight for a
    course piece, or a whole arc, on which no path segment crosses an edge, and each node's
    weight elsewhere): star-shaped polygons about the straight path from the mean to the first
    point (shifted by up to half their size), one or two searches (the second the first's
    polygon mirrored about that path's line, later), each point's channels within RTOL of the
    oracle."""
    model = butterly(rho=rho, speeds=(speed,), weights=(1.0,))
    p = points(model, 2, 11)
    start = when * (1.0 - length) * model.t
    mid = (start + 0.5 * length * model.t) / model.t
    mean = np.asarray(model.mean)
    centre = mean + mid * (p[0] - mean) + size * np.asarray(shift)
    k = len(shape)
    angles = np.sort(2 * math.pi * (np.arange(k) / k + np.array([d for _, d in shape]) / k))
    radii = np.array([a for a, _ in shape]) * size
    vertices = np.column_stack((centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)))
    evidence = [bg.AreaSearch(vertices, t=(start, start + length * model.t), coverage=coverage)]
    late = 0.5 * (start + length * model.t + model.t)
    second = second and late < model.t
    if second:
        evidence.append(bg.AreaSearch(vertices[::-1] * [1.0, -1.0] + [0.0, 2.0 * centre[1]],
                                      t=(late, min(late + length * model.t, model.t)), coverage=coverage))
    pk = pack(evidence, model.t)
    got = evaluate_carried(model, p[:, 0], p[:, 1], pk)
    want = carried_density(model, evidence, p[:, 0], p[:, 1])
    np.testing.assert_allclose(got[1], want, rtol=RTOL, atol=1e-300)
    if second:
        want = carried_density(model, evidence[:1], p[:, 0], p[:, 1])
        np.testing.assert_allclose(got[pk.channel("search:evidence[0]")], want, rtol=RTOL, atol=1e-300)


@seed(33)
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(x0=st.floats(-1500.0, 1500.0), y0=st.floats(-1500.0, 1500.0), heading=st.floats(0.0, 2 * math.pi),
       length=st.floats(1000.0, 8000.0), turn=st.floats(-2.5, 2.5), t0=st.floats(0.0, 700.0), span=st.floats(20.0, 300.0),
       width=st.floats(100.0, 1500.0), legs=st.integers(1, 3))
def test_definite_track_sweep_against_the_oracle(x0, y0, heading, length, turn, t0, span, width, legs):
    """Definite-range tracks over positions, headings, turns, times and widths: the carried
    density at sampled points against the oracle (closest approach by minimize_scalar, the
    course integral cut at the switches it finds by brentq), as the cases above. The track
    starts within 1.5 km of the first point's sampled path at its start time (so that it
    meets some of the paths through the points: 3 of the 6 seeded examples remove 1 % to all of
    a point's density)."""
    model = butterly()
    t1 = min(t0 + span, model.t)
    drawn = model.sample_paths(4, [t0, model.t], np.random.default_rng(3))
    p = drawn[:, 1]
    pts = [(drawn[0, 0, 0] + x0, drawn[0, 0, 1] + y0, t0)]
    for k in range(legs):
        a = heading + k * turn
        x, y, _ = pts[-1]
        pts.append((x + length / legs * math.sin(a), y + length / legs * math.cos(a), t0 + (t1 - t0) * (k + 1) / legs))
    evidence = [bg.TrackSearch(pts, sweep_width=width, law="definite")]
    got = evaluate_carried(model, p[:, 0], p[:, 1], pack(evidence, model.t))
    want = carried_density(model, evidence, p[:, 0], p[:, 1])
    np.testing.assert_allclose(got[1], want, rtol=RTOL, atol=1e-12 * float(got[0].max()))


def test_float32_within_its_bound():
    """float32 against float64 where the carried density exceeds 1e-6 of its largest value:
    within 1e-4 relative plus 1e-4 of that largest value (the density's float32_rtol, and the
    course breaks' float32 rounding: a crossing's course moves by ~1e-7 R / sigma_c of the
    integrand's width, so a piece's weight moves by as much of the density)."""
    model = butterly()
    p = points(model, 100, 11)
    pk = pack([NORTH, TRIANGLE, REPORT, BARRIER, PATROL], model.t)
    f64 = evaluate_carried(model, p[:, 0], p[:, 1], pk)
    f32 = evaluate_carried(model, p[:, 0], p[:, 1], pk, dtype=np.float32)
    assert f32.dtype == np.float32
    for c in range(f64.shape[0]):
        top = f64[c].max()
        keep = f64[c] > 1e-6 * top
        assert np.all(np.abs(f32[c][keep] - f64[c][keep]) <= 1e-4 * np.abs(f64[c][keep]) + 1e-4 * top)


def test_a_pack_for_another_time_is_refused():
    model = butterly()
    with pytest.raises(BananagridError, match=r"^t = 900\.0: the evidence was packed for a map at t = 900\.0"):
        evaluate_carried(model, [0.0], [0.0], pack([NORTH], 900.0))


# -- sample_paths ----------------------------------------------------------------------------------


def test_sample_paths_follow_the_generative_story():
    """The same draws as ``sample`` at the model's t (same generator state), and straight paths:
    the position is linear in time with the start at s = 0."""
    model = butterly(kappa=2.0)
    paths = model.sample_paths(1000, [0.0, 250.0, model.t, 1500.0], np.random.default_rng(5))
    assert paths.shape == (1000, 4, 2)
    np.testing.assert_allclose(paths[:, 2], model.sample(1000, np.random.default_rng(5)), rtol=0, atol=1e-9)
    np.testing.assert_allclose(paths[:, 3] - paths[:, 0], 6.0 * (paths[:, 1] - paths[:, 0]), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(paths[:, 2] - paths[:, 0], 4.0 * (paths[:, 1] - paths[:, 0]), rtol=1e-12, atol=1e-9)


def test_sample_paths_of_a_continuous_speed_law():
    """Speeds of a continuous law are drawn exactly: the travelled speed |X(1) - X(0)| is
    uniform on [2, 5] (Kolmogorov-Smirnov, alpha 1e-3)."""
    from scipy import stats
    model = bg.Butterly(mean=(0.0, 0.0), cov=[[1.0, 0.0], [0.0, 1.0]], speeds=bg.UniformSpeed(2.0, 5.0), t=10.0)
    paths = model.sample_paths(5000, [0.0, 1.0], 3)
    v = np.hypot(*(paths[:, 1] - paths[:, 0]).T)
    assert stats.kstest(v, stats.uniform(2.0, 3.0).cdf).pvalue > 1e-3


@pytest.mark.parametrize("times, message", [
    ([0.0, -1.0], r"^times\[1\] = -1\.0: must be >= 0 \(s since the last fix\)$"),
    ([0.0, math.nan], r"^times = .*: every value must be finite"),
    ([], r"^times = \[\]: expected a non-empty list of numbers$"),
    ([[1.0, 2.0]], r"^times = .*: expected a non-empty list of numbers$"),
])
def test_sample_paths_bad_times(times, message):
    with pytest.raises(BananagridError, match=message):
        butterly().sample_paths(10, times, 1)


def test_sample_paths_bad_n_and_rng():
    with pytest.raises(BananagridError, match=r"^n = -1: expected a non-negative integer$"):
        butterly().sample_paths(-1, [1.0], 1)
    with pytest.raises(BananagridError, match=r"^rng = 'x': expected a numpy.random.Generator"):
        butterly().sample_paths(1, [1.0], "x")
