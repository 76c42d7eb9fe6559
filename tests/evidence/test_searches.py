"""Searches: the lateral-range laws against their derivation (a long straight leg past a
stationary target gives the lateral-range curve; its integral is the sweep width), parallel
sweeps against Koopman's inverse-cube coverage law (the planning layer's), random search's
POD from the coverage, and every kind of bad input in one line."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st
from scipy import integrate

import bananagrid as bg
from bananagrid.evidence.searches import lateral_range
from bananagrid.planning.detection import INVERSE_CUBE

SWEEP = settings(max_examples=40, deadline=None, database=None, suppress_health_check=list(HealthCheck))


@seed(20261127)
@SWEEP
@given(st.floats(1.0, 5e3), st.floats(1e-3, 50.0), st.floats(0.0, 2.0 * math.pi), st.sampled_from(["inverse_cube", "definite"]))
def test_a_long_straight_leg_gives_the_lateral_range_curve(width, ratio, heading, law):
    """A stationary target abreast of a straight leg 10^5 W long (in any direction) is missed
    with probability 1 - p(x), p the lateral-range curve, x = ratio W: to 1e-9 relative plus what
    the geometry's rounding allows. The leg's finite ends leave out an exposure of W^2 / (8 pi
    s^2) = 1.6e-11 (s = L / 2); the target's lateral distance x, found from coordinates of size
    s, carries eps s of rounding, which moves the exposure E by 2 E eps s / x, and the miss,
    exp(-E), by that relative."""
    x = ratio * width
    direction = np.array([math.sin(heading), math.cos(heading)])
    normal = np.array([direction[1], -direction[0]])
    half = 5e4 * width
    start, end = -half * direction, half * direction
    search = bg.TrackSearch([(*start, 0.0), (*end, 100.0)], sweep_width=width, law=law)
    target = x * normal
    missed = float(search.likelihood(target[0], target[1]))
    # 1 - p(x) written as the miss itself: 1 - lateral_range cancels where p is within 1e-9 of 1
    # (x = W / 16: 1 - p = 1.4e-9, the subtraction keeps 1e-7 of it)
    expected = math.exp(-width**2 / (4.0 * math.pi * x**2)) if law == "inverse_cube" else 1.0 - float(
        lateral_range(x, width, law))
    if law == "definite" and abs(x - 0.5 * width) < 1e-9 * width:
        return  # on the corridor's edge the rounding of the point decides
    exposure = width**2 / (4.0 * math.pi * x**2) if law == "inverse_cube" else 0.0
    rounding = 4.0 * exposure * np.finfo(float).eps * half / x  # twice the estimate above
    assert math.isclose(missed, expected, rel_tol=1e-9 + rounding, abs_tol=1e-300), (missed, expected)


def test_the_inverse_cube_exposure_of_a_leg_is_koopmans():
    """Exposure (W^2 / (8 pi)) int ds / r^3 abreast of a leg from s1 to s2, against the closed
    form (W^2 / (8 pi x^2)) (s2 / R2 - s1 / R1) (Koopman 1946, the integral of k h / r^3
    along the leg), at points where that form does not cancel."""
    search = bg.TrackSearch([(0.0, 0.0, 0.0), (1000.0, 0.0, 10.0)], sweep_width=200.0)
    for x, s in ((50.0, 300.0), (400.0, -200.0), (10.0, 999.0), (1000.0, 500.0)):
        s1, s2 = -s, 1000.0 - s
        expected = 200.0**2 / (8.0 * math.pi * x * x) * (s2 / math.hypot(x, s2) - s1 / math.hypot(x, s1))
        assert math.isclose(float(search.exposure(s, x)), expected, rel_tol=1e-13)


@pytest.mark.parametrize("law", ["inverse_cube", "definite"])
def test_the_lateral_range_curve_integrates_to_the_sweep_width(law):
    """int p(x) dx over the line is W (the definition of the sweep width; quad to 1e-12)."""
    for width in (0.5, 30.0, 2000.0):
        def curve(x):
            return float(lateral_range(x, width, law))

        if law == "inverse_cube":
            half = integrate.quad(curve, 0.0, np.inf, epsabs=0.0, epsrel=1e-12, limit=500)[0]
        else:
            half = integrate.quad(curve, 0.0, width, points=[0.5 * width], epsabs=0.0, epsrel=1e-12)[0]
        assert math.isclose(2.0 * half, width, rel_tol=1e-9)


def test_parallel_sweeps_give_koopmans_inverse_cube_coverage_law():
    """Parallel legs S apart, the target uniform across them: the mean POD is erf(sqrt(pi) W /
    (2 S)) (Koopman 1946; Washburn, Search and Detection, eq. (2-8)), the planning layer's
    inverse-cube law of the coverage W / S. 401 legs, each 2e7 S long: the legs left out beyond
    +-200 S add an exposure below (W / S)^2 / (4 pi 200), so the mean is within 2e-3."""
    spacing = 1000.0
    for width in (300.0, 1000.0, 2500.0):
        x = (np.arange(2000) + 0.5) / 2000 * spacing  # midpoint rule over one gap (smooth, periodic)
        exposure = np.zeros_like(x)
        for k in range(-200, 201):
            leg = bg.TrackSearch([(k * spacing, -1e7 * spacing, 0.0), (k * spacing, 1e7 * spacing, 1.0)],
                                 sweep_width=width)
            exposure += leg.exposure(x, 0.0)
        mean_pod = float(np.mean(-np.expm1(-exposure)))
        assert abs(mean_pod - float(INVERSE_CUBE.pod(np.array([width / spacing]))[0])) < 2e-3


@seed(20261127)
@SWEEP
@given(st.floats(0.0, 50.0))
def test_coverage_is_random_search(coverage):
    """POD from the coverage C is 1 - exp(-C) (random search), as -expm1(-C), and the likelihood
    of nothing found inside is exp(-C) itself (not 1 - POD, which rounds to 0 beyond C = 37)."""
    search = bg.AreaSearch([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)], t=0.0, coverage=coverage)
    assert search.pod == -math.expm1(-coverage)
    assert float(search.likelihood(0.2, 0.2)) == math.exp(-coverage)
    assert float(search.likelihood(2.0, 2.0)) == 1.0


SQUARE = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]
TRACK = [(0.0, 0.0, 0.0), (100.0, 0.0, 10.0)]
RASTER_GRID = bg.Grid(origin=(-10.0, 5.0), dx=10.0, dy=20.0, nx=3, ny=2)


def test_a_raster_search_misses_with_its_cells_pod():
    """1 - POD of the cell holding a point (the cell east / north of an edge between cells),
    exp(-C) from a coverage exactly, 1 off the raster (its east and north edges are off)."""
    pod = np.array([[0.1, 0.2, 0.3], [0.4, 1.0, 0.0]])
    search = bg.RasterSearch(RASTER_GRID, t=(1.0, 2.0), pod=pod)
    x = np.array([-5.0, 0.0, 15.0, 5.0, -10.0, 20.0, -10.1, 5.0, 0.0])
    y = np.array([10.0, 10.0, 30.0, 25.0, 5.0, 10.0, 10.0, 45.0, 4.99])
    want = [0.9, 0.8, 1.0, 0.0, 0.9, 1.0, 1.0, 1.0, 1.0]
    np.testing.assert_array_equal(search.likelihood(x, y), want)
    covered = bg.RasterSearch(RASTER_GRID, t=1.0, coverage=[[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    assert float(covered.likelihood(15.0, 30.0)) == math.exp(-5.0)
    assert search.time_span == (1.0, 2.0) and search.describe()["kind"] == "raster_search"

#: (what, constructor, the message's part). Every message is one line naming the argument.
BAD = [
    ("pod below 0", lambda: bg.AreaSearch(SQUARE, t=0.0, pod=-0.1), r"pod = -0\.1: must be in \[0, 1\]"),
    ("pod above 1", lambda: bg.AreaSearch(SQUARE, t=0.0, pod=1.5), r"pod = 1\.5: must be in \[0, 1\]"),
    ("pod NaN", lambda: bg.AreaSearch(SQUARE, t=0.0, pod=math.nan), r"pod = nan: must be finite"),
    ("pod text", lambda: bg.AreaSearch(SQUARE, t=0.0, pod="0.5"), r"pod = '0\.5': expected a real number"),
    ("coverage < 0", lambda: bg.AreaSearch(SQUARE, t=0.0, coverage=-1.0), r"coverage = -1\.0: must be >= 0"),
    ("coverage inf", lambda: bg.AreaSearch(SQUARE, t=0.0, coverage=math.inf), r"coverage = inf: must be finite"),
    ("pod and coverage", lambda: bg.AreaSearch(SQUARE, t=0.0, pod=0.5, coverage=1.0), r"give exactly one"),
    ("neither", lambda: bg.AreaSearch(SQUARE, t=0.0), r"give exactly one"),
    ("crossing polygon", lambda: bg.AreaSearch([(0, 0), (10, 10), (10, 0), (0, 10)], t=0.0, pod=0.5),
     r"polygon: edges .* cross"),
    ("polygon NaN", lambda: bg.AreaSearch([(0, 0), (10, math.nan), (10, 10)], t=0.0, pod=0.5),
     r"polygon\[1\] = .*must be finite"),
    ("polygon of 2", lambda: bg.AreaSearch([(0, 0), (10, 0)], t=0.0, pod=0.5), r"polygon: 2 distinct vertices"),
    ("polygon on a line", lambda: bg.AreaSearch([(0, 0), (1, 1), (2, 2)], t=0.0, pod=0.5), r"encloses no area"),
    ("time NaN", lambda: bg.AreaSearch(SQUARE, t=math.nan, pod=0.5), r"t = nan: must be finite"),
    ("time inf", lambda: bg.AreaSearch(SQUARE, t=(0.0, math.inf), pod=0.5), r"t\[1\] = inf: must be finite"),
    ("negative time", lambda: bg.AreaSearch(SQUARE, t=-1.0, pod=0.5), r"t = -1\.0: times must be >= 0"),
    ("interval backwards", lambda: bg.AreaSearch(SQUARE, t=(5.0, 3.0), pod=0.5), r"ends before it starts"),
    ("interval of 3", lambda: bg.AreaSearch(SQUARE, t=(1.0, 2.0, 3.0), pod=0.5), r"expected a time .* or a pair"),
    ("sweep width 0", lambda: bg.TrackSearch(TRACK, sweep_width=0.0), r"sweep_width = 0\.0: must be > 0"),
    ("sweep width < 0", lambda: bg.TrackSearch(TRACK, sweep_width=-5.0), r"sweep_width = -5\.0: must be > 0"),
    ("sweep width NaN", lambda: bg.TrackSearch(TRACK, sweep_width=math.nan), r"sweep_width = nan: must be finite"),
    ("times not increasing", lambda: bg.TrackSearch([(0, 0, 5.0), (10, 0, 5.0)], sweep_width=1.0),
     r"track\.times\[1\] = 5\.0: must be later"),
    ("times backwards", lambda: bg.TrackSearch([(0, 0, 5.0), (10, 0, 9.0), (20, 0, 7.0)], sweep_width=1.0),
     r"track\.times\[2\] = 7\.0: must be later"),
    ("track of (x, y)", lambda: bg.TrackSearch([(0, 0), (10, 0)], sweep_width=1.0), r"track = .*expected a list of \(x, y, t\)"),
    ("track of 1", lambda: bg.TrackSearch([(0, 0, 0.0)], sweep_width=1.0), r"track: 1 point given"),
    ("track NaN", lambda: bg.TrackSearch([(0, 0, 0.0), (math.nan, 0, 1.0)], sweep_width=1.0),
     r"track\.positions\[1\] = .*must be finite"),
    ("track inf time", lambda: bg.TrackSearch([(0, 0, 0.0), (1, 0, math.inf)], sweep_width=1.0),
     r"track\.times\[1\] = inf: must be finite"),
    ("track waits", lambda: bg.TrackSearch([(0, 0, 0.0), (0, 0, 1.0)], sweep_width=1.0), r"repeats the position"),
    ("track before the fix", lambda: bg.TrackSearch([(0, 0, -1.0), (1, 0, 1.0)], sweep_width=1.0), r"must be >= 0"),
    ("unknown law", lambda: bg.TrackSearch(TRACK, sweep_width=1.0, law="square"), r"law = 'square': expected one of"),
    ("raster without a grid", lambda: bg.RasterSearch("grid", t=1.0, pod=[[0.5]]), r"grid = 'grid': expected a bananagrid Grid"),
    ("raster of the wrong shape", lambda: bg.RasterSearch(RASTER_GRID, t=1.0, pod=[[0.5, 0.5]]),
     r"pod: shape \(1, 2\); expected the grid's \(ny, nx\) = \(2, 3\)"),
    ("raster pod above 1", lambda: bg.RasterSearch(RASTER_GRID, t=1.0, pod=[[0.5, 0.5, 0.5], [0.5, 1.2, 0.5]]),
     r"pod\[1, 1\] = 1\.2: must be in \[0, 1\]"),
    ("raster pod NaN", lambda: bg.RasterSearch(RASTER_GRID, t=1.0, pod=[[0.5, 0.5, math.nan], [0.5, 0.5, 0.5]]),
     r"pod\[0, 2\] = nan: must be finite"),
    ("raster coverage < 0", lambda: bg.RasterSearch(RASTER_GRID, t=1.0, coverage=[[1.0, 1.0, 1.0], [1.0, 1.0, -2.0]]),
     r"coverage\[1, 2\] = -2\.0: must be >= 0"),
    ("raster pod and coverage", lambda: bg.RasterSearch(RASTER_GRID, t=1.0, pod=np.zeros((2, 3)), coverage=np.ones((2, 3))),
     r"give exactly one"),
    ("raster time backwards", lambda: bg.RasterSearch(RASTER_GRID, t=(3.0, 2.0), pod=np.zeros((2, 3))),
     r"t = \(3\.0, 2\.0\): the search ends before it starts"),
]


@pytest.mark.parametrize("what, build, message", BAD, ids=[b[0] for b in BAD])
def test_bad_search_is_one_line_naming_the_argument(what, build, message):
    with pytest.raises(bg.BananagridError, match=message) as caught:
        build()
    assert "\n" not in str(caught.value)


def test_searches_are_frozen():
    search = bg.AreaSearch(SQUARE, t=(1.0, 2.0), pod=0.5)
    with pytest.raises(AttributeError):
        search.pod = 0.9
    with pytest.raises(ValueError):
        search.polygon[0, 0] = 5.0
    track = bg.TrackSearch(TRACK, sweep_width=3.0)
    with pytest.raises(ValueError):
        track.track[0, 0] = 5.0
    assert search.time_span == (1.0, 2.0) and track.time_span == (0.0, 10.0)


def test_a_searched_track_from_a_gpx_file(tmp_path):
    """A searcher's track as a file has it (GPX: longitude, latitude, UTC): placed in the
    frame's metres and timed from the frame's time, each point where the frame puts it."""
    frame = bg.GeoFrame(lat=60.45, lon=4.40, time="2026-11-24T06:00:00Z")
    points = [(4.38, 60.47, "06:02:00"), (4.42, 60.47, "06:04:00"), (4.42, 60.49, "06:06:30")]
    body = "".join(f'<trkpt lat="{lat}" lon="{lon}"><time>2026-11-24T{when}Z</time></trkpt>' for lon, lat, when in points)
    path = tmp_path / "searcher.gpx"
    path.write_text('<?xml version="1.0"?><gpx version="1.1" creator="test" xmlns="http://www.topografix.com/GPX/1/1">'
                    f"<trk><trkseg>{body}</trkseg></trk></gpx>")
    search = bg.TrackSearch.from_track(bg.read_track(path), frame, sweep_width=500.0)
    x, y = frame.local([p[1] for p in points], [p[0] for p in points])
    np.testing.assert_array_equal(search.track[:, :2], np.column_stack((x, y)))
    np.testing.assert_array_equal(search.track[:, 2], [120.0, 240.0, 390.0])
    with pytest.raises(bg.BananagridError, match="with a time"):
        bg.TrackSearch.from_track(bg.read_track(path), bg.GeoFrame(lat=60.45, lon=4.40), sweep_width=500.0)
    with pytest.raises(bg.BananagridError, match="bg.read_track"):
        bg.TrackSearch.from_track([(0, 0, 0)], frame, sweep_width=500.0)
