"""BearingFix.density_bound: a proved upper bound of what the grid kernel computes over a
rectangle, in float32 and float64, for both variants; and tight enough that tiled rasterising
skips the tiles far from the fix and off the bearing lines."""

import math
import time
import warnings

import numpy as np
import pytest

import bananagrid as bg
from bananagrid import BananagridError
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.models.bearing import MAP_VARIANTS, BearingFix, bearing_to

pytestmark = pytest.mark.filterwarnings("ignore:bearings cross at")  # poor random crossings are fine here

#: The bearing_three_stations scene (scenes/bearing_three_stations.toml).
THREE_SENSORS = np.array([[0.0, 0.0], [20000.0, 0.0], [35000.0, 12000.0]])
THREE_BEARINGS = np.radians([15.13, -22.40, -56.0])
THREE_SIGMAS = np.radians([0.573, 1.146, 0.573])

#: Points per side of the direct kernel evaluations (the rectangle's edges included).
SIDE = 33


def kernel_values(model, xs, ys, dtype) -> np.ndarray:
    """The grid kernel at (xs[j], ys[i]) in ``dtype``, launched directly: no float64 fallback
    far from the world origin (``working_dtype``), so float32 rounding is fully exercised."""
    ctx = WarpContext(dtype, "cpu", threads=1)
    binding = model.bind(ctx, None, grid=True)
    ctx.load(binding.kernels.grid)
    out = ctx.zeros((len(ys), len(xs)))
    # a whole row per thread
    ctx.launch(binding.kernels.grid, dim=(len(ys), 1), inputs=[ctx.array(xs), ctx.array(ys), 0, len(xs), binding.params,
                                                                out])
    return ctx.numpy(out).astype(np.float64)


def computed_max(model, rect) -> float:
    """The largest density the grid kernel computes at points of ``rect``: directly on a lattice
    that includes its edges and corners (float32 and float64), and through ``rasterise`` at the
    cell centres of a grid covering it (as the engine picks its dtype)."""
    x0, x1, y0, y1 = rect
    xs, ys = np.linspace(x0, x1, SIDE), np.linspace(y0, y1, SIDE)
    xs, ys = np.clip(xs, x0, x1), np.clip(ys, y0, y1)
    best = max(float(kernel_values(model, xs, ys, dt).max()) for dt in (np.float32, np.float64))
    grid = bg.Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / 16, dy=(y1 - y0) / 16)
    assert grid.x[-1] <= x1 and grid.y[-1] <= y1
    for dt in (np.float32, np.float64):
        best = max(best, float(bg.rasterise(model, grid, dtype=dt, threads=1).values.max()))
    return best


def random_model(rng) -> BearingFix:
    """2-4 stations around a contact, at scales from 10 m to 100 km, near or far from the world
    origin, with bearing SDs from 0.02 to 11 degrees (mixed within a model)."""
    while True:
        n = int(rng.integers(2, 5))
        scale = 10.0 ** rng.uniform(1.0, 5.0)
        origin = rng.normal(size=2) * (0.0 if rng.uniform() < 0.5 else 10.0 ** rng.uniform(3.0, 6.0))
        target = origin + rng.normal(size=2) * scale
        angles = rng.uniform(0.0, 2.0 * np.pi) + np.sort(rng.uniform(0.0, 2.0 * np.pi, n))
        ranges = scale * 10.0 ** rng.uniform(-0.5, 0.5, n)
        sensors = target + ranges[:, None] * np.column_stack((np.sin(angles), np.cos(angles)))
        sigmas = 10.0 ** rng.uniform(-3.5, -0.7, n)
        bearings = bearing_to(sensors, target) + sigmas * rng.normal(size=n)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return BearingFix(sensors, bearings, sigmas, variant=str(rng.choice(MAP_VARIANTS)))
        except BananagridError:  # lines too parallel, crossing behind a station: draw again
            continue


def random_rectangles(model, rng) -> list[tuple[float, float, float, float]]:
    """Small and large rectangles, near and far: about the fix, across the whole scene, holding
    a sensor, with a sensor on an edge or a corner, across a bearing line near and far along
    it, beside a sensor, and far away."""
    fix = model.fix
    feature = model.feature_scale()
    sensors = model.sensors
    span = float(np.max(np.hypot(*(sensors - fix).T)))
    out = []

    def around(centre, half_x, half_y):
        out.append((centre[0] - half_x, centre[0] + half_x, centre[1] - half_y, centre[1] + half_y))

    for _ in range(2):
        around(fix + feature * rng.normal(size=2) * 2.0, *(feature * 10.0 ** rng.uniform(-2.0, 1.0, 2)))
    around(fix + span * rng.normal(size=2), *(span * 10.0 ** rng.uniform(-1.0, 0.5, 2)))
    i = int(rng.integers(len(sensors)))
    half = span * 10.0 ** rng.uniform(-3.0, -0.5, 2)
    around(sensors[i] + half * rng.uniform(-0.9, 0.9, 2), *half)
    sx, sy = sensors[i]
    out.append((sx, sx + half[0], sy - half[1], sy))  # the sensor on an edge's corner
    out.append((sx - half[0], sx + half[0], sy, sy + half[1]))  # on an edge
    direction = np.array([math.sin(model.bearings[i]), math.cos(model.bearings[i])])
    for reach in (0.02, 1.0, 3.0):
        along = sensors[i] + reach * span * direction
        around(along + feature * rng.normal(size=2), *(feature * 10.0 ** rng.uniform(-1.5, 1.0, 2)))
    around(sensors[i] + span * 0.01 * rng.normal(size=2), *(span * 10.0 ** rng.uniform(-4.0, -2.5, 2)))
    around(fix + span * 10.0 ** rng.uniform(0.5, 1.5) * rng.normal(size=2), *(span * 10.0 ** rng.uniform(-2.0, 0.0, 2)))
    return [r for r in out if r[1] > r[0] and r[3] > r[2]]


@pytest.mark.parametrize("seed", range(4))
def test_bound_holds_for_random_models_and_rectangles(seed):
    """Both variants of each random model, every rectangle: the bound is at least every value
    the grid kernel computes there in float32 and float64; on rectangles far smaller than the
    fix's narrowest SD it is within 20 % of the computed maximum (it is tight)."""
    rng = np.random.default_rng(1000 + seed)
    for _ in range(8):
        first = random_model(rng)
        rectangles = random_rectangles(first, rng)
        for variant in MAP_VARIANTS:
            model = first.with_variant(variant)
            feature = model.feature_scale()
            for rect in rectangles:
                bound = model.density_bound(*rect)
                got = computed_max(model, rect)
                assert bound >= got, (variant, rect, bound, got, model.parameters())
                assert math.isfinite(bound)
                tiny = max(rect[1] - rect[0], rect[3] - rect[2]) < 1e-3 * feature
                far_from_origin = max(map(abs, rect)) > 1e3 * feature  # float32 widening shows
                if tiny and not far_from_origin:
                    assert bound <= 1.2 * got + 1e-40, (variant, rect, bound, got)


def test_bound_holds_at_and_around_every_sensor():
    """Rectangles shrinking onto each sensor of the scene, and the sensor on their edge: the
    kernel's atan2 at a zero offset is 0, and the bound holds and stays finite."""
    base = BearingFix(THREE_SENSORS, THREE_BEARINGS, THREE_SIGMAS)
    for variant in MAP_VARIANTS:
        model = base.with_variant(variant)
        peak = model.density_bound(-math.inf, math.inf, -math.inf, math.inf)
        for sx, sy in THREE_SENSORS:
            for half in (1e-3, 1.0, 100.0, 5000.0):
                for rect in ((sx - half, sx + half, sy - half, sy + half), (sx, sx + half, sy, sy + half),
                             (sx - half, sx, sy - half, sy + half)):
                    bound = model.density_bound(*rect)
                    assert computed_max(model, rect) <= bound <= peak


def test_bound_over_the_whole_plane_and_bad_rectangles():
    for variant in MAP_VARIANTS:
        model = BearingFix(THREE_SENSORS, THREE_BEARINGS, THREE_SIGMAS, variant=variant)
        whole = model.density_bound(-math.inf, math.inf, -math.inf, math.inf)
        assert model.peak_lower_bound() <= whole < math.inf
        fx, fy = model.fix
        assert model.density_bound(fx, fx, fy, fy) >= model.peak_lower_bound()  # a single point
        assert model.density_bound(fx - 1e9, fx + 1e9, fy - 1e9, fy + 1e9) <= whole
        with pytest.raises(BananagridError):
            model.density_bound(1.0, 0.0, 0.0, 1.0)
        with pytest.raises(BananagridError):
            model.density_bound(0.0, 1.0, math.nan, 1.0)


def _distance_to_ray(points, sensor, bearing) -> np.ndarray:
    """Distance from each point to the bearing line drawn from ``sensor`` (a half-line)."""
    u = np.array([math.sin(bearing), math.cos(bearing)])
    d = points - sensor
    along = np.clip(d @ u, 0.0, None)
    return np.hypot(*(d - along[:, None] * u).T)


@pytest.mark.parametrize("variant", MAP_VARIANTS)
def test_far_tiles_of_the_three_station_scene_are_skipped(variant):
    """bearing_three_stations: every 1 km tile of a 70 km square whose every point lies more
    than 4 km off every bearing line (13 cross-range SDs at the fix's 30 km) and 4 km from the
    fix gets a bound at most the density floor, so tiled rasterising leaves it at 0; the tiles
    holding the fix or on the lines near it are kept."""
    model = BearingFix(THREE_SENSORS, THREE_BEARINGS, THREE_SIGMAS, variant=variant)
    floor = model.density_floor()
    edges = np.arange(-20000.0, 50001.0, 1000.0)
    half_diagonal = math.hypot(500.0, 500.0)
    far, skipped, total = 0, 0, 0
    for x0 in edges[:-1]:
        centres = np.column_stack((np.full(len(edges) - 1, x0 + 500.0), edges[:-1] + 500.0))
        clear = np.hypot(*(centres - model.fix).T) - half_diagonal
        for sensor, bearing in zip(THREE_SENSORS, THREE_BEARINGS):
            clear = np.minimum(clear, _distance_to_ray(centres, sensor, bearing) - half_diagonal)
        for (cx, cy), margin in zip(centres, clear):
            bound = model.density_bound(cx - 500.0, cx + 500.0, cy - 500.0, cy + 500.0)
            total += 1
            skipped += bound <= floor
            if margin > 4000.0:
                far += 1
                assert bound <= floor, (variant, cx, cy, bound, floor)
    assert far > 0.6 * total  # the test is about most of the square
    assert skipped > 0.98 * total  # the lines' far reaches too (99.3 % skipped): near the fix only
    fx, fy = model.fix
    assert model.density_bound(fx - 500.0, fx + 500.0, fy - 500.0, fy + 500.0) >= model.peak_lower_bound()
    for sensor, bearing in zip(THREE_SENSORS, THREE_BEARINGS):  # on each line 1 km short of the fix
        ux, uy = math.sin(bearing), math.cos(bearing)
        reach = math.hypot(*(model.fix - sensor)) - 1000.0
        px, py = sensor[0] + reach * ux, sensor[1] + reach * uy
        assert model.density_bound(px - 100.0, px + 100.0, py - 100.0, py + 100.0) > floor


def test_a_call_is_cheap():
    """Well under a millisecond a rectangle (5 ms allowed on a busy machine)."""
    model = BearingFix(THREE_SENSORS, THREE_BEARINGS, THREE_SIGMAS)
    model.density_bound(0.0, 1.0, 0.0, 1.0)  # the cached terms
    start = time.perf_counter()
    for k in range(200):
        model.density_bound(1000.0 * k, 1000.0 * k + 500.0, 3000.0, 3500.0)
    assert (time.perf_counter() - start) / 200 < 5e-3
