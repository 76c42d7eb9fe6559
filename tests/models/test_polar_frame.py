"""PolarBanana's frame boxes (the world boxes of a batch's grids) are the boxes of the sampled
curves r(b) = v0 t sinc(b) -+ sds s, the bearing within +-min(pi, sds sigma_theta), turned by the
heading and with the origin, as an oracle computes them point by point with NumPy's sin, cos and
sinc: equal within rounding, over hypotheses with and without heading noise, bearings that reach
+-pi, and origins far from the world origin."""

import math

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.models.polar import FRAME_BEARINGS


def _oracle(m, sds):
    """The box of the points (r, b) at FRAME_BEARINGS bearings and of the origin, each point
    turned to the world by its own sine and cosine."""
    v0t = m.v0 * m.t
    spread = 0.5 * m.sigma_a * m.t**2 * (1 + (m.sigma_a * m.t / m.v0) ** 2 / 72) + 0.44 * v0t * m.sigma_bar
    b = min(math.pi, sds * m.sigma_theta) * np.linspace(-1.0, 1.0, FRAME_BEARINGS)
    mean = v0t * np.sinc(b / math.pi)
    r = np.concatenate([np.maximum(0.0, mean - sds * spread), mean + sds * spread, [0.0]])
    b = np.concatenate([b, b, [0.0]])
    lx, ly = r * np.sin(b), r * np.cos(b)
    h, (ox, oy) = m.pose.heading, m.pose.origin
    wx = ox + lx * math.cos(h) + ly * math.sin(h)
    wy = oy - lx * math.sin(h) + ly * math.cos(h)
    return np.array([wx.min(), wx.max(), wy.min(), wy.max()]), float(np.abs(r).max())


HYPOTHESIS = st.builds(
    lambda v0, t, sa, so, sh, h, ox, oy, variant: bg.PolarBanana(
        v0=v0, t=t, sigma_a=sa, sigma_omega=so, sigma_heading=sh, variant=variant,
        pose=bg.Pose(origin=(ox, oy), heading=h)),
    st.floats(1.0, 400.0), st.floats(0.5, 600.0), st.floats(0.05, 5.0), st.floats(1e-4, 0.3),
    st.sampled_from([0.0, 0.01, 0.3, 2.0]), st.floats(-math.pi, math.pi),
    st.floats(-1e6, 1e6), st.floats(-1e6, 1e6), st.sampled_from(["rough", "improved"]),
)


@pytest.mark.filterwarnings("ignore::bananagrid.validate.BananagridWarning")  # wide bananas' notices
@seed(20261127)  # a fixed seed, not derandomize (whose examples depend on the checkout's path)
@settings(max_examples=60, deadline=None, database=None)
@given(models=st.lists(HYPOTHESIS, min_size=1, max_size=300), sds=st.sampled_from([1.0, 4.0, 6.0]))
def test_frame_boxes_are_the_sampled_curves_boxes(models, sds):
    got = type(models[0]).frame_bounds(models, sds)
    assert got.shape == (len(models), 4)
    for k, m in enumerate(models):
        box, reach = _oracle(m, sds)
        # sines and cosines by at most 7 products each (a few ulps of the unit), turned by the
        # heading and added to the origin: well within 1e-13 of the farthest point's distance
        # and of the origin's size
        tol = 1e-13 * (reach + abs(m.pose.origin[0]) + abs(m.pose.origin[1]))
        assert np.all(np.abs(got[k] - box) <= tol), (k, got[k], box)
