"""PolarBanana.density_bound: a proved upper bound of what the grid kernel computes over a world
rectangle (float64 and float32), tight where the density is, and below the model's density floor
a few km from the Figure 1 banana, so that tiled rasterising can skip such tiles."""

import math
import time
import warnings

import numpy as np
import pytest

import bananagrid as bg

from cases import FIG1

CONFIGS = [
    pytest.param(variant, heading, order, id=f"{variant}-heading{heading}-order{order}")
    for variant in ("rough", "improved")
    for heading, order in ((False, 2), (True, 2), (True, 4))
]


def corner_grid(x0, x1, y0, y1, n=17):
    """A grid whose n x n cell centres run from corner to corner of the rectangle, its edges
    included."""
    dx, dy = (x1 - x0) / (n - 1), (y1 - y0) / (n - 1)
    return bg.Grid(origin=(x0 - 0.5 * dx, y0 - 0.5 * dy), dx=dx, dy=dy, nx=n, ny=n)


def kernel_max(model, rect, dtype):
    """The largest value the grid kernel computes on the rectangle's corner grid."""
    return float(bg.rasterise(model, corner_grid(*rect), dtype=dtype).values.max())


def random_model(rng, variant, heading, order):
    near = rng.random() < 0.5  # near the world origin float32 coordinates resolve the model
    spread = 200.0 if near else 5e4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # P_sigma (11) not positive up to pi: the density is 0 there
        return bg.PolarBanana(
            v0=10 ** rng.uniform(0.5, 2.5), t=10 ** rng.uniform(0.3, 1.7), sigma_a=10 ** rng.uniform(-1.0, 0.7),
            sigma_omega=10 ** rng.uniform(-2.5, -0.3), variant=variant,
            sigma_heading=10 ** rng.uniform(-2.0, -0.3) if heading else 0.0, heading_order=order,
            pose=bg.Pose(origin=tuple(rng.uniform(-spread, spread, 2)), heading=rng.uniform(-4.0, 4.0)),
        )


def world_rect(model, local_centre, half_x, half_y):
    x, y = model.pose.to_world(np.asarray([local_centre], dtype=float))[0]
    return (x - half_x, x + half_x, y - half_y, y + half_y)


def random_rects(rng, model, n):
    """Rectangles small and large, near and far, beside the banana, across the heading axis,
    behind the origin and about it."""
    span = model.v0 * model.t
    mean, _ = model.radial_law(0.0)
    rects = [
        world_rect(model, (0.0, float(mean)), 0.05 * span, 0.05 * span),  # across the heading axis
        world_rect(model, (0.0, -0.5 * span), 0.1 * span, 0.1 * span),  # behind: bearings across +-pi
        world_rect(model, (0.0, 0.0), 0.01 * span, 0.02 * span),  # about the origin: no bound
    ]
    for _ in range(n - len(rects)):
        if rng.random() < 0.6:
            bearing = rng.normal(0.0, 2.0 * model.sigma_theta)
        else:
            bearing = rng.uniform(-math.pi, math.pi)
        r = span * rng.uniform(0.0, 2.5)
        size = span * 10 ** rng.uniform(-3.5, -0.3)
        rects.append(world_rect(model, (r * math.sin(bearing), r * math.cos(bearing)),
                                size * rng.uniform(0.2, 1.0), size * rng.uniform(0.2, 1.0)))
    return rects


@pytest.mark.parametrize("variant, heading, order", CONFIGS)
def test_bound_holds_over_random_models_and_rectangles(variant, heading, order):
    """The bound is at least every value the grid kernel computes on the rectangle (its edges
    and corners included), in float64 and in float32."""
    rng = np.random.default_rng([20261125, len(variant), heading, order])
    finite = positive = 0
    for _ in range(5):
        model = random_model(rng, variant, heading, order)
        for rect in random_rects(rng, model, 24):
            bound = model.density_bound(*rect)
            assert bound >= 0.0
            for dtype in (np.float64, np.float32):
                got = kernel_max(model, rect, dtype)
                assert bound >= got, (model, rect, dtype, bound, got)
            finite += math.isfinite(bound)
            positive += 0.0 < bound < math.inf
    assert finite >= 90 and positive >= 50  # the sweep proves something


@pytest.mark.parametrize("variant, heading, order", CONFIGS)
def test_bound_is_tight_on_small_rectangles_where_the_mass_is(variant, heading, order):
    """On rectangles a hundredth of the range SD wide, at points drawn from the model, the bound
    is within a few per cent of the largest value the kernel computes there."""
    rng = np.random.default_rng([7, len(variant), heading, order])
    model = bg.PolarBanana(**FIG1, variant=variant, sigma_heading=0.1 if heading else 0.0, heading_order=order,
                           pose=bg.Pose(origin=(150.0, -80.0), heading=0.4))
    sd = float(model.radial_law(0.0)[1])
    for x, y in model.sample(20, rng):
        rect = (x, x + 0.01 * sd, y, y + 0.01 * sd)
        bound, got = model.density_bound(*rect), kernel_max(model, rect, np.float64)
        assert got <= bound <= 1.05 * got, (rect, bound, got)


def test_bound_is_infinite_about_the_origin_and_for_non_finite_corners():
    model = bg.PolarBanana(**FIG1, pose=bg.Pose(origin=(10.0, 20.0), heading=1.0))
    assert model.density_bound(9.0, 11.0, 19.0, 21.0) == math.inf
    assert model.density_bound(10.0, 11.0, 20.0, 21.0) == math.inf  # origin at a corner
    assert model.density_bound(0.0, math.nan, 0.0, 1.0) == math.inf
    assert 0.0 < model.density_bound(11.0, 12.0, 20.0, 21.0) < math.inf  # 1 m off: finite, large


@pytest.mark.filterwarnings("ignore:P_sigma")
@pytest.mark.parametrize("sigma_heading", [0.0, 0.2])
def test_bound_is_zero_where_the_improved_sd_is_not_positive(sigma_heading):
    """Beyond sigma_positive_limit the improved kernel returns exact zeros, and the bound is 0."""
    model = bg.PolarBanana(v0=10.0, t=10.0, sigma_a=5.0, sigma_omega=0.3, sigma_heading=sigma_heading)
    limit = model.sigma_positive_limit / (model.sigma_phi**2 / model.sigma_theta**2)  # theta_bar (12)
    assert limit < 2.5
    rect = (-30.0, 30.0, -80.0, -60.0)  # behind the origin: |phi| > 2.6
    assert model.density_bound(*rect) == 0.0
    for dtype in (np.float64, np.float32):
        assert not bg.rasterise(model, corner_grid(*rect), dtype=dtype).values.any()


def fig1_rects():
    """Local rectangles a few km from the Figure 1 banana (ranges 2.5-3.1 km about bearings within
    +-0.9 rad): beside it in bearing, beyond it in range, behind the origin."""
    return {
        "left": (-4000.0, -3000.0, 1000.0, 2000.0),
        "right": (3000.0, 4000.0, 0.0, 1000.0),
        "right-behind": (2500.0, 3500.0, -2000.0, -1000.0),
        "beyond": (-500.0, 500.0, 5000.0, 6000.0),
        "beyond-left": (-3000.0, -2000.0, 4000.0, 5000.0),
        "behind": (-500.0, 500.0, -3000.0, -2000.0),
    }


@pytest.mark.parametrize("variant", ["improved", "rough"])
@pytest.mark.parametrize("pose", [bg.Pose(), bg.Pose(origin=(3000.0, -1200.0), heading=-math.pi / 2)],
                         ids=["origin", "moved"])
def test_figure1_rectangles_far_from_the_banana_fall_below_the_floor(variant, pose):
    model = bg.PolarBanana(v0=280, t=10, sigma_a=5 / 3, sigma_omega=math.pi / 54, variant=variant, pose=pose)
    floor = model.density_floor()
    for name, (x0, x1, y0, y1) in fig1_rects().items():
        corners = pose.to_world(np.array([[x0, y0], [x0, y1], [x1, y0], [x1, y1]]))  # a quarter turn
        rect = (corners[:, 0].min(), corners[:, 0].max(), corners[:, 1].min(), corners[:, 1].max())
        bound = model.density_bound(*rect)
        assert bound <= floor, (name, bound, floor)
        assert bound >= kernel_max(model, rect, np.float64)


def test_bound_decays_in_bearing_and_in_range():
    """Along the banana's mean range away from the heading and along the heading beyond the
    banana the bound of a 50 m square falls steadily, down to the floor within 9 SDs of the
    bearing and 13 of the range."""
    model = bg.PolarBanana(**FIG1)
    mean, sd = (float(v) for v in model.radial_law(0.0))
    square = 25.0

    def at(bearing, r):
        x, y = r * math.sin(bearing), r * math.cos(bearing)
        return model.density_bound(x - square, x + square, y - square, y + square)

    beside = [at(k * model.sigma_phi, float(model.radial_law(k * model.sigma_phi)[0])) for k in range(2, 10)]
    beyond = [at(0.0, mean + k * sd) for k in range(2, 14)]
    assert all(b > a for a, b in zip(beside[1:], beside[:-1]))
    assert all(b > a for a, b in zip(beyond[1:], beyond[:-1]))
    assert beside[-1] <= model.density_floor() and beyond[-1] <= model.density_floor()


def test_bound_is_cheap():
    """Pure Python over cached constants: well under a millisecond a rectangle."""
    model = bg.PolarBanana(**FIG1, sigma_heading=0.1, heading_order=4)
    model.density_bound(0.0, 1.0, 10.0, 11.0)
    start = time.perf_counter()
    for k in range(200):
        model.density_bound(100.0 + k, 300.0 + k, 2000.0, 2200.0)
    assert (time.perf_counter() - start) / 200 < 2e-3
