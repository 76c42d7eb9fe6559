"""A kept launch (a small grid's or a few points' launch recorded once and replayed with fresh
outputs) computes what a launch made afresh computes, bit for bit, whatever the calls around it:
other models and grids of the same shape, other points of the same count, more grids than are
kept, and several threads replaying the same call at once."""

import math
import threading

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.engine import warp_runtime
from bananagrid.engine.warp_runtime import WarpContext

MODELS = [
    bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54),
    bg.PolarBanana(v0=200.0, t=12.0, sigma_a=1.0, sigma_omega=0.04, sigma_heading=0.05,
                   pose=bg.Pose(origin=(300.0, -200.0), heading=0.4)),
    bg.BearingFix(sensors=[(0.0, 0.0), (4000.0, 0.0)], bearings=[0.6, -0.5], sigmas=[0.01, 0.02]),
    bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54),
    # tiles and work rows made for each call (packed afresh in a kept launch)
    bg.Butterly(mean=(0.0, 500.0), cov=[[1e4, 2e3], [2e3, 2.5e4]], speeds=[1.0, 1.5], weights=[0.5, 0.5], t=600.0),
]
#: Grids of one shape (the launch's dimensions) at different places and steps.
GRIDS = [bg.Grid(origin=(-1500.0 + 37.0 * k, -100.0 + 53.0 * k), dx=60.0 + k, dy=70.0 - k, nx=50, ny=40)
         for k in range(3)]


def _calls(dtype):
    """Interleaved rasterise and pdf calls: every model on every grid, and at two point sets of
    one size, twice over."""
    rng = np.random.default_rng(7)
    points = [rng.uniform(-3000.0, 4000.0, (2, 500)) for _ in range(2)]
    out = []
    for _ in range(2):
        for model in MODELS:
            for grid in GRIDS:
                out.append(bg.rasterise(model, grid, dtype=dtype, threads=1, min_mass=0.0).values)
            for x, y in points:
                out.append(model.pdf(x, y, dtype=dtype))
    return out


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_kept_launches_equal_fresh_launches(dtype, monkeypatch):
    kept = _calls(dtype)
    monkeypatch.setattr(WarpContext, "launch_kept", WarpContext.launch)  # every launch made afresh
    fresh = _calls(dtype)
    assert len(kept) == len(fresh)
    for k, (a, b) in enumerate(zip(kept, fresh)):
        assert a.dtype == b.dtype and np.array_equal(a, b), k
    # two results of the same call are two arrays: a replay never writes into an earlier result
    assert kept[0] is not kept[len(kept) // 2] and np.array_equal(kept[0], kept[len(kept) // 2])


def test_more_grids_than_are_kept(monkeypatch):
    """Grids beyond KEPT_LAUNCHES push the oldest out; each call still gets its own values."""
    model = MODELS[0]
    grids = [bg.Grid(origin=(-1500.0 + 10.0 * k, -100.0), dx=100.0, dy=90.0, nx=30, ny=40)
             for k in range(warp_runtime.KEPT_LAUNCHES + 5)]
    kept = [bg.rasterise(model, g, threads=1).values for g in grids + grids[:3]]
    monkeypatch.setattr(WarpContext, "launch_kept", WarpContext.launch)
    fresh = [bg.rasterise(model, g, threads=1).values for g in grids + grids[:3]]
    assert all(np.array_equal(a, b) for a, b in zip(kept, fresh))


def test_threads_replaying_one_call_at_once():
    """Four threads, each rasterising two models on one grid in turn: a kept launch is taken
    out of the cache while it runs, so no thread writes into another's result."""
    grid = GRIDS[0]
    expected = [bg.rasterise(m, grid, threads=1).values for m in MODELS[:2]]
    wrong, errors = [], []

    def work(seed):
        try:
            for k in range(40):
                which = (k + seed) % 2
                if not np.array_equal(bg.rasterise(MODELS[which], grid, threads=1).values, expected[which]):
                    wrong.append((seed, k))
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    workers = [threading.Thread(target=work, args=(s,)) for s in range(4)]
    for t in workers:
        t.start()
    for t in workers:
        t.join(timeout=120)
    assert not errors and not wrong
