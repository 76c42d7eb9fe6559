"""Kernel consistency: pdf vs rasterise, threads, float32 vs float64, pose, the series switch."""

import math

import numpy as np
import pytest
import warp as wp
from scipy import integrate

import bananagrid as bg
from bananagrid.kernels import common

from cases import FIG1, FIG1_BOUNDS, FOLDING

MODELS = {
    "cat": lambda **p: bg.CAT(**p),
    "rough": lambda **p: bg.PolarBanana(**p, variant="rough"),
    "improved": lambda **p: bg.PolarBanana(**p, variant="improved"),
}
COARSE = bg.Grid.from_bounds(**FIG1_BOUNDS, step=40.0)


@pytest.mark.parametrize("name", MODELS)
def test_pdf_equals_rasterise(name):
    model = MODELS[name](**FIG1)
    raster = bg.rasterise(model, COARSE)
    xx, yy = np.meshgrid(COARSE.x, COARSE.y)
    # same kernel function on the same float64 inputs: bit-identical
    np.testing.assert_array_equal(model.pdf(xx, yy), raster.values)


@pytest.mark.parametrize("name", MODELS)
def test_row_bands_do_not_change_results(name):
    model = MODELS[name](**FOLDING)
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-3000.0, 3000.0), step=50.0)
    one = bg.rasterise(model, grid, threads=1).values
    for threads in (2, 3, 7):
        np.testing.assert_array_equal(bg.rasterise(model, grid, threads=threads).values, one)


# float32 bound inside the 1e-10 contour. The densities are exp(-z^2 / 2) with z up to ~6 there;
# a float32 rounding of r ~ 3e3 m (1.2e-7 relative, 4e-4 m) moves z by 4e-4 / 83 m and the
# density by z dz ~ 3e-5, and the CAT kernel also cancels in F = h x (P - v0 f). Measured on the
# Figure 1 grid at 20 m: CAT 6.0e-5, rough 1.7e-5, improved 2.1e-5; the bounds allow ~3x.
FLOAT32_BOUND = {"cat": 2e-4, "rough": 6e-5, "improved": 6e-5}


@pytest.mark.parametrize("name", MODELS)
def test_float32_agrees_with_float64(name):
    model = MODELS[name](**FIG1)
    grid = bg.Grid.from_bounds(**FIG1_BOUNDS, step=20.0)
    r64 = bg.rasterise(model, grid).values
    r32 = bg.rasterise(model, grid, dtype=np.float32).values
    assert r32.dtype == np.float32
    inside = r64 >= 1e-10
    rel = np.abs(r32[inside] / r64[inside] - 1.0)
    assert rel.max() < FLOAT32_BOUND[name], rel.max()


@pytest.mark.parametrize("name", MODELS)
def test_pose_moves_and_turns_the_map(name):
    heading = math.radians(60.0)
    origin = (1000.0, -500.0)
    posed = MODELS[name](**FIG1, pose=bg.Pose(origin=origin, heading=heading))
    local = MODELS[name](**FIG1)
    rng = np.random.default_rng(3)
    pts = local.sample(2000, rng)
    # world = origin + x * (cos h, -sin h) + y * (sin h, cos h)
    wx = origin[0] + pts[:, 0] * math.cos(heading) + pts[:, 1] * math.sin(heading)
    wy = origin[1] - pts[:, 0] * math.sin(heading) + pts[:, 1] * math.cos(heading)
    np.testing.assert_allclose(posed.pdf(wx, wy), local.pdf(pts[:, 0], pts[:, 1]), rtol=1e-9)
    # and the posed sampler places points where the posed density lives
    world = posed.sample(2000, np.random.default_rng(4))
    assert np.all(posed.pdf(world[:, 0], world[:, 1]) > 0)


@wp.kernel
def _basis_kernel(us: wp.array(dtype=wp.float64), out: wp.array2d(dtype=wp.float64)):
    k = wp.tid()
    a, b, c, d, dc, dd = common.cat_basis(us[k])
    out[k, 0] = a
    out[k, 1] = b
    out[k, 2] = c
    out[k, 3] = d
    out[k, 4] = dc
    out[k, 5] = dd


def _basis_by_quadrature(u):
    """The basis as moments of the path, eq. (1) integrated along it: A = int_0^1 sin(u s) ds,
    B = int cos, C = int s sin, D = int s cos, C' = int s^2 cos, D' = -int s^2 sin."""
    def moment(power, weight):
        # QUADPACK's QAWO rule integrates s^m sin(us) and s^m cos(us) exactly in the weight
        return integrate.quad(lambda s: s**power, 0.0, 1.0, weight=weight, wvar=u, epsabs=1e-14, epsrel=1e-13)[0]

    return [
        moment(0, "sin"), moment(0, "cos"), moment(1, "sin"), moment(1, "cos"),
        moment(2, "cos"), -moment(2, "sin"),
    ]


def test_cat_basis_series_and_closed_forms_against_quadrature():
    us = np.array([0.0, 1e-12, 1e-6, 1e-3, 0.1, 0.5, 0.999999, 1.0, 1.000001, 2.0, 4.4934, 10.0, -0.7, -3.0, 25.0])
    out = wp.zeros((len(us), 6), dtype=wp.float64, device="cpu")
    wp.launch(_basis_kernel, dim=len(us), inputs=[wp.array(us, dtype=wp.float64, device="cpu"), out], device="cpu")
    got = out.numpy()
    for k, u in enumerate(us):
        want = np.array(_basis_by_quadrature(u))
        # absolute scale of each function is O(1) (|integrand| <= 1); series and closed forms
        # agree with quadrature to a few ulps of that scale, 1e-13 allows cancellation at |u|=1.
        np.testing.assert_allclose(got[k], want, rtol=0, atol=1e-13, err_msg=f"u = {u}")


@wp.kernel
def _atan2_kernel(xs: wp.array(dtype=wp.float64), ys: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
    k = wp.tid()
    out[k] = common.atan2_fast(xs[k], ys[k])


def test_atan2_fast_against_numpy():
    rng = np.random.default_rng(5)
    n = 400_000
    # magnitudes over 12 decades and every quadrant, plus the axes and the diagonals
    x = rng.normal(size=n) * 10.0 ** rng.uniform(-8, 4, n)
    y = rng.normal(size=n) * 10.0 ** rng.uniform(-8, 4, n)
    specials = [0.0, -0.0, 1.0, -1.0, 1e-300, 0.66, 1.5]
    sx, sy = np.meshgrid(specials, specials)
    x = np.concatenate([x, sx.ravel()])
    y = np.concatenate([y, sy.ravel()])
    out = wp.zeros(len(x), dtype=wp.float64, device="cpu")
    wp.launch(
        _atan2_kernel, dim=len(x),
        inputs=[wp.array(x, dtype=wp.float64, device="cpu"), wp.array(y, dtype=wp.float64, device="cpu"), out],
        device="cpu",
    )
    got = out.numpy()
    want = np.arctan2(x, y)
    origin = (x == 0) & (y == 0)  # no angle; atan2_fast documents 0 there (numpy: +-0 or +-pi)
    assert np.all(got[origin] == 0.0)
    got, want, x, y = got[~origin], want[~origin], x[~origin], y[~origin]
    zero_sign = (x == 0) & (y < 0)  # atan2(-0, -1) = -pi in numpy, +pi or -pi is the same angle
    err = np.abs(got - want)
    err[zero_sign] = np.abs(np.abs(got[zero_sign]) - np.pi)
    # Cephes' rational approximation is good to ~1 ulp; 2 ulp of pi (4.4e-16) absolute, and
    # 1e-15 relative away from zero where the absolute bound would be loose.
    assert err.max() <= 2 * np.spacing(np.pi)
    nonzero = want != 0
    assert (err[nonzero] / np.abs(want[nonzero])).max() <= 1e-15
