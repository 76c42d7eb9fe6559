"""The plan's picture (bananagrid.recording.plan): the coverage's colour over the probability's
grey, grey exactly where no effort goes; the summary's numbers; the POS curve through the
plan's own effort."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.recording.plan import (
    OVERLAY_ALPHA, POS_CURVE_SPAN, POS_CURVE_STEPS, overlay_image, plan_markdown, plan_values, pos_curve_efforts,
)


@seed(20261127)
@settings(max_examples=40, deadline=None, database=None)
@given(rng_seed=st.integers(0, 2**32 - 1), zeros=st.floats(0.0, 0.95), spread=st.floats(0.0, 30.0))
def test_the_overlay_is_grey_where_no_effort_goes_and_coloured_where_it_does(rng_seed, zeros, spread):
    rng = np.random.default_rng(rng_seed)
    p = 10.0 ** (-spread * rng.random((12, 17)))
    coverage = np.where(rng.random(p.shape) < zeros, 0.0, rng.random(p.shape) * 3.0)
    image = np.flipud(overlay_image(p, coverage)).astype(int)  # back to grid rows
    assert image.shape == (12, 17, 3)
    grey = np.round(255.0 * p / p.max()).astype(int)
    bare = coverage == 0.0
    for channel in range(3):  # no effort: the probability's grey, exactly
        np.testing.assert_array_equal(image[..., channel][bare], grey[bare])
    covered = ~bare
    # effort: red leads blue by at least the ramp's least lead (195 - 60) times its weight
    lead = image[..., 0][covered] - image[..., 2][covered]
    assert np.all(lead >= np.floor(OVERLAY_ALPHA * 135.0) - 1)  # -1: rounding of both channels


def test_the_summary_states_pos_effort_and_each_area():
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=200.0)
    fig1 = dict(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)  # the paper's Figure 1
    cells = bg.rasterise(bg.PolarBanana(**fig1, variant="improved"), grid, quantity="probability")
    allocation = bg.allocate(cells, 2.0e5)
    bands = bg.search_regions(allocation, 2, sweep_width=50.0)
    values = plan_values(allocation, bands=bands, layer="banana", t=10.0)
    text = plan_markdown(values)
    assert f"**Ideal POS** {allocation.pos:.4f}" in text
    assert f"**POS of the bands** {bands.pos:.4f}" in text and "0.2 km²" in text
    for k, band in enumerate(r for r in bands.regions if r.coverage > 0):
        assert f"| B{k + 1} | {band.probability:.4f} | {band.pod:.4f} |" in text


@seed(20261127)
@settings(max_examples=200, deadline=None, database=None)
@given(effort=st.floats(1e-300, 1e300))
def test_the_pos_curve_passes_through_the_plans_own_effort(effort):
    """The marked bar sits on one of the curve's: the plan's effort is a point of the curve,
    exactly, whatever its size."""
    efforts = pos_curve_efforts(effort)
    assert efforts[POS_CURVE_STEPS] == effort
    assert efforts[0] == 0.0 and np.all(np.diff(efforts) > 0)
    assert efforts[-1] == pytest.approx(POS_CURVE_SPAN * effort, rel=1e-15)  # one rounding
