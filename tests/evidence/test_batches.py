"""Many hypotheses after the same evidence (bananagrid.evidence.batches): each hypothesis's map,
POS and normaliser are bg.posterior's on its grid, a hypothesis the evidence rules out is flagged
without stopping the batch, and shards on Dask give the single process's batch."""

from __future__ import annotations

import math

import dask
import numpy as np
import pytest

import bananagrid as bg
from bananagrid.bench.runner import batch_hypotheses
from bananagrid.evidence.batches import posterior_batch, posterior_batch_shards
from cases import FIG1

#: The same cells' rules and the same sums as bg.posterior, on one thread instead of several
#: (rasterise's values do not depend on the threads): equal to rounding, held at 1e-13 of the
#: largest cell (and absolute for POS, the normaliser, POD).
TOL = 1e-13


def _searches(t):
    return [bg.AreaSearch([(-2000.0, -500.0), (1500.0, -1200.0), (2500.0, 3000.0), (-1000.0, 2500.0)], t=t, pod=0.6),
            bg.TrackSearch([(-6000.0, 1000.0, t - 5.0), (6000.0, 1800.0, t + 5.0)], sweep_width=600.0)]


def _check_each(batch, models, evidence):
    for h, (model, grid) in enumerate(zip(models, batch.grids)):
        ref = bg.posterior(model, grid, evidence)
        assert np.max(np.abs(batch.values[h] - ref.values)) <= TOL * ref.values.max()
        assert np.max(np.abs(batch.prior[h] - ref.prior)) <= TOL * ref.prior.max()
        assert np.max(np.abs(batch.pod[h] - ref.pod)) <= TOL
        assert batch.pos[h] == pytest.approx(ref.pos, abs=TOL)
        assert batch.normaliser[h] == pytest.approx(ref.normaliser, abs=TOL)
        assert np.allclose(batch.search_pos[h], ref.search_pos, rtol=0.0, atol=TOL)
        assert not batch.ruled_out[h]


def test_framed_polar_hypotheses_each_get_their_posterior():
    """Polar hypotheses spread over 20 km, each framed about itself (the batch kind's frames),
    after an area search and a track: each hypothesis's posterior is bg.posterior's."""
    models = batch_hypotheses(6, seed=3)
    # a box about each of the first two hypotheses' fixes
    evidence = [bg.AreaSearch([(m.pose.origin[0] - 2000.0, m.pose.origin[1] - 2000.0),
                               (m.pose.origin[0] + 2000.0, m.pose.origin[1] - 2000.0),
                               (m.pose.origin[0] + 2000.0, m.pose.origin[1] + 2000.0),
                               (m.pose.origin[0] - 2000.0, m.pose.origin[1] + 2000.0)], t=10.0, coverage=0.5)
                for m in models[:2]]
    batch = posterior_batch(models, evidence, shape=(24, 24), threads=2)
    assert batch.values.shape == (6, 24, 24) and batch.search_pos.shape == (6, 2)
    _check_each(batch, models, evidence)
    assert np.allclose(batch.values.sum(axis=(1, 2)), 1.0, rtol=0.0, atol=1e-12)


def test_given_grids_and_a_hypothesis_ruled_out():
    """Two CAT hypotheses 20 km apart, each on its own given grid, after a search of POD 1 over
    the whole of the second's grid and a track: the second is ruled out (normaliser 0, flagged,
    map at 0; bg.posterior refuses it) without stopping the batch; the first gets bg.posterior's
    map."""
    models = [bg.CAT(**FIG1, pose=bg.Pose(origin=(x, 0.0), heading=0.0)) for x in (0.0, 20000.0)]
    grids = [bg.Grid.from_bounds(x=(x - 3000.0, x + 3000.0), y=(-200.0, 3400.0), step=200.0) for x in (0.0, 20000.0)]
    x0, x1, y0, y1 = grids[1].extent
    sure = bg.AreaSearch([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], t=10.0, pod=1.0)
    evidence = [sure, _searches(10.0)[1]]
    with pytest.raises(bg.BananagridError, match="contradicts the prior"):
        bg.posterior(models[1], grids[1], evidence)
    batch = posterior_batch(models, evidence, grids=grids, threads=2)
    assert list(batch.ruled_out) == [False, True]
    assert np.all(batch.values[1] == 0.0) and batch.normaliser[1] == 0.0
    one = posterior_batch(models[:1], evidence, grids=grids[:1])
    assert np.array_equal(one.values[0], batch.values[0]) and one.normaliser[0] == batch.normaliser[0]
    _check_each(one, models[:1], evidence)


def test_shards_on_dask_are_the_single_process_batch():
    models = batch_hypotheses(5, seed=4)
    evidence = [bg.PositionReport(models[0].pose.origin, t=10.0, sigma=30000.0)]
    single = posterior_batch(models, evidence, shape=(16, 16), threads=1)
    with dask.config.set(scheduler="threads"):
        sharded = posterior_batch_shards(models, evidence, shape=(16, 16), shard=2)
    for name in ("values", "prior", "pod", "normaliser", "pos", "search_pos", "ruled_out"):
        assert np.array_equal(getattr(sharded, name), getattr(single, name)), name
    assert sharded.grids == single.grids


@pytest.mark.parametrize("call, message", [
    (lambda m: posterior_batch([], []), "models: expected at least one hypothesis"),
    (lambda m: posterior_batch(m, [], grids=[bg.Grid.from_bounds(x=(0, 10), y=(0, 10), step=1.0)]),
     "grids: 1 grids for 3 hypotheses"),
    (lambda m: posterior_batch(m[:2] + [bg.CAT(**{**FIG1, "t": 5.0})], [bg.PositionReport((0, 0), t=10.0, sigma=1.0)],
                               grids=[bg.Grid.from_bounds(x=(0, 10), y=(0, 10), step=1.0)] * 3),
     "models[2]: evidence[0].t = 10.0: after the map's time t = 5.0"),
    (lambda m: posterior_batch(m, [], threads=0), "threads"),
    (lambda m: posterior_batch_shards(m, [], shard=0), "shard"),
])
def test_bad_input_is_one_line_naming_it(call, message):
    models = batch_hypotheses(3, seed=5)
    with pytest.raises(bg.BananagridError) as err:
        call(models)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_hypotheses_carry_earlier_evidence():
    """CAT hypotheses in two headings after a search at 4 s and a report at 6 s, carried along
    their paths by the kernels: each one's posterior, POS and normaliser are bg.posterior's."""
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=300.0)
    models = [bg.CAT(**FIG1, pose=bg.Pose(origin=(0.0, 0.0), heading=h)) for h in (0.0, 0.15)]
    evidence = [bg.AreaSearch([(-400.0, 900.0), (150.0, 950.0), (250.0, 1400.0), (-300.0, 1350.0)], t=4.0, pod=0.8),
                bg.PositionReport((300.0, 1700.0), t=6.0, sigma=400.0)]
    batch = posterior_batch(models, evidence, grids=[grid, grid], threads=2)
    assert np.all(batch.search_pos[:, 0] > 0.05)  # the search reached both
    _check_each(batch, models, evidence)
