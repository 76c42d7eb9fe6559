"""bg.plan_periods: plans over several periods for a CAT or Butterly target, each period's map
carried through the model's kernels given the other periods' searches. Checked against a Monte
Carlo simulation of the model's own paths (tests/support/path_oracle.py, independent of the
kernels), the stationary target's known answer, and each period's own single-period plan."""

from __future__ import annotations

import math

import numpy as np
import pytest

import bananagrid as bg
from path_oracle import butterly_paths, cat_paths, detection_probability

#: Monte Carlo draws: sigma of a POS near 0.5 is 5e-4 at 10^6 paths.
DRAWS = 10**6
#: Convergence of the plans here: a sweep's gain below 1e-6 is far below the Monte Carlo sigma
#: (and halves the sweeps of the default 1e-9).
TOL = 1e-6

CAT_KW = dict(v0=3.0, sigma_a=0.002, sigma_omega=0.001)
BUTTERLY_KW = dict(mean=(0.0, 0.0), cov=[[4e5, 1e5], [1e5, 2e5]], speeds=[0.5, 1.5], weights=[0.4, 0.6])
# grids holding all but 1e-4 of each target at every period's time
CASES = {
    "cat": (lambda t: bg.CAT(t=t, **CAT_KW), bg.Grid.from_bounds(x=(-2000.0, 2000.0), y=(-200.0, 3200.0), step=100.0),
            lambda n, times, rng: cat_paths(n, times, rng, **CAT_KW), (200.0, 400.0, 600.0), (5e4, 8e4, 1e5)),
    "butterly": (lambda t: bg.Butterly(t=t, **BUTTERLY_KW),
                 bg.Grid.from_bounds(x=(-3500.0, 3500.0), y=(-3500.0, 3500.0), step=250.0),
                 lambda n, times, rng: butterly_paths(n, times, rng, **BUTTERLY_KW), (300.0, 600.0, 900.0),
                 (1e6, 1e6, 1e6)),
}
CAT_GRID, BUTTERLY_GRID = CASES["cat"][1], CASES["butterly"][1]


@pytest.mark.parametrize("name", sorted(CASES))
def test_plan_pos_is_the_monte_carlo_detection_frequency_within_4_sigma(name):
    """The plan flown against 10^6 paths of the model's own generative story (drawn here, not by
    the kernels): the mean of each path's detection probability, 1 - prod_k (1 - POD_k at its
    cell at t_k), is within 4 sigma of the plan's POS; the plan is never below any period's own
    single-period plan, and the history never decreases."""
    model, grid, paths, times, efforts = CASES[name]
    plan = bg.plan_periods(model(times[0]), grid, times, efforts, tol=TOL)
    assert plan.converged
    assert np.all(np.diff(plan.history) >= -1e-13)  # rounding of sums over 900-1600 cells
    found = detection_probability(paths(DRAWS, times, np.random.default_rng(7)), grid,
                                  [a.pod for a in plan.allocations])
    sigma = found.std(ddof=1) / math.sqrt(found.size)
    assert abs(found.mean() - plan.pos) <= 4.0 * sigma, (found.mean(), plan.pos, sigma)
    for t, z in zip(times, efforts):
        own = bg.allocate(bg.rasterise(model(t), grid, quantity="probability"), z)
        assert plan.pos >= own.pos - 1e-13
    assert math.fsum(plan.period_pos) == pytest.approx(plan.pos, abs=1e-12)
    # the POS kept by the updates' increments, from maps of every sweep, agrees with the final
    # maps' to their accuracy (measured 6e-6 and 3e-5)
    assert abs(plan.history[-1] - plan.pos) <= 2e-4


def test_stationary_target_is_one_period_with_the_summed_effort():
    """A Butterly target of speed 0 stays where it started: for random search K periods
    combine as exp(-sum e_k), so the plan's POS is the single-period optimum for the summed
    effort on the same map (Stone: the exponential law's plans are uniformly optimal), to 1e-9."""
    model = bg.Butterly(mean=(100.0, -50.0), cov=[[6e5, 2e5], [2e5, 3e5]], speeds=[0.0], t=1.0)
    times, efforts = (1.0, 2.0, 3.0), (2e6, 5e5, 3e6)
    plan = bg.plan_periods(model, BUTTERLY_GRID, times, efforts)
    single = bg.allocate(bg.rasterise(model, BUTTERLY_GRID, quantity="probability"), sum(efforts))
    assert plan.pos == pytest.approx(single.pos, rel=1e-9)


def test_bad_input_is_one_line_naming_it():
    cat = bg.CAT(t=300.0, **CAT_KW)
    polar = bg.PolarBanana(t=300.0, variant="improved", **CAT_KW)
    mixture = bg.GaussianMixture(weights=[1.0], means=[(0.0, 0.0)], covs=[np.eye(2)])
    cases = [
        (dict(prior=polar), "prior = PolarBanana: .*use bg.CAT"),
        (dict(prior=mixture), "prior = GaussianMixture: .*bg.CAT, bg.Butterly"),
        (dict(times=(300.0, 300.0)), r"times\[1\] = 300.0: not after times\[0\] = 300.0"),
        (dict(times=(600.0, 300.0)), r"times\[1\] = 300.0: not after"),
        (dict(times=(300.0, math.nan)), r"times\[1\] = nan: expected a finite time"),
        (dict(times=()), r"times = \[\]"),
        (dict(times=(-5.0, 300.0)), r"times\[0\] = -5.0: CAT refuses it"),
        (dict(efforts=(1e6, -1.0)), r"efforts\[1\] = -1.0: expected a positive finite effort"),
        (dict(efforts=(1e6, 0.0)), r"efforts\[1\] = 0.0"),
        (dict(efforts=(1e6,)), "efforts: 1 values for 2 times"),
        (dict(grid=(0.0, 1.0)), r"grid = \(0.0, 1.0\): expected a bananagrid Grid"),
        (dict(tol=-1.0), "tol = -1.0"),
        (dict(law="sure"), "law = 'sure'"),
    ]
    for kwargs, message in cases:
        args = {**dict(prior=cat, grid=CAT_GRID, times=(300.0, 600.0), efforts=(1e6, 1e6)), **kwargs}
        with pytest.raises(bg.BananagridError, match="^" + message) as err:
            bg.plan_periods(args.pop("prior"), args.pop("grid"), args.pop("times"), args.pop("efforts"), **args)
        assert "\n" not in str(err.value)


def test_a_first_look_changes_the_cost_not_the_plan():
    """The first sweeps on 4 x 4 sub-cells of every cell, then refined ones from their plan, reach
    the plan of refined sweeps alone: the same optimum (random search: the POS is concave in the
    coverages), each to within its last sweeps' gains. The default makes the first look where
    its sub-cells are within a quarter of the model's smallest feature (here 62.5 m sub-cells,
    the start's 398 m SD); its history is the refined sweeps', from the first look's plan."""
    model, grid, _, times, efforts = CASES["butterly"]
    progress = []
    looked = bg.plan_periods(model(times[0]), grid, times, efforts, tol=TOL,
                             progress=lambda *heard: progress.append(heard))
    plain = bg.plan_periods(model(times[0]), grid, times, efforts, tol=TOL, first_look=False)
    first = looked.provenance["period_plan"]["first_look_sweeps"]
    assert first >= 1 and looked.sweeps > first and plain.provenance["period_plan"]["first_look_sweeps"] == 0
    assert [stage for _, _, stage in progress] == ["first look"] * first + ["refined"] * (looked.sweeps - first)
    assert [sweep for sweep, _, _ in progress] == list(range(1, looked.sweeps + 1))
    assert len(looked.history) == 3 * (looked.sweeps - first) and np.all(np.diff(looked.history) >= -1e-13)
    # both stop on a sweep gaining under TOL = 1e-6 (their gains shrink by about half a sweep,
    # so each is within ~1e-6 of the optimum): 2e-6; measured 2.7e-8 apart (the first look: 9
    # cheap sweeps and 2 refined, 3.7 s of CPU; refined alone 9 sweeps, 6.1 s)
    assert looked.pos == pytest.approx(plain.pos, abs=2e-6)
    assert math.fsum(looked.period_pos) == pytest.approx(looked.pos, abs=1e-12)
