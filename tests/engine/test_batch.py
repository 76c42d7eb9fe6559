"""Many hypotheses at once: batch rasters and the points-by-hypotheses score matrix equal the
one-at-a-time results bit for bit (they run the same device function)."""

import math

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.engine.batch import frame, pdf_batch, rasterise_batch


@pytest.fixture(scope="module")
def hypotheses():
    rng = np.random.default_rng(11)
    out = []
    for k in range(40):
        out.append(bg.PolarBanana(
            v0=rng.uniform(150.0, 300.0), t=10.0, sigma_a=rng.uniform(0.5, 2.0), sigma_omega=rng.uniform(0.02, 0.06),
            variant="rough" if k % 3 == 0 else "improved", sigma_heading=0.05 if k % 4 == 0 else 0.0,
            heading_order=4 if k % 8 == 0 else 2,
            pose=bg.Pose(origin=tuple(rng.uniform(-5e3, 5e3, 2)), heading=float(rng.uniform(-math.pi, math.pi))),
        ))
    return out


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_batch_equals_one_at_a_time(hypotheses, dtype):
    batch = rasterise_batch(hypotheses, dtype=dtype, threads=2)
    assert batch.values.shape == (len(hypotheses), 64, 64)
    for k, (model, grid) in enumerate(zip(hypotheses, batch.grids)):
        one = bg.rasterise(model, grid, dtype=dtype, threads=1)
        assert np.array_equal(batch.values[k], one.values), k
        assert batch.mass[k] == pytest.approx(one.mass, rel=1e-12)


def test_frames_hold_the_banana(hypotheses):
    """Each framed 64 x 64 grid holds the banana to 4 SDs: the captured mass is within the
    midpoint rule's error of 1 (coarse cells: a few per range SD)."""
    batch = rasterise_batch(hypotheses)
    assert np.all(np.abs(batch.mass - 1.0) < 0.01)
    assert all(g.shape == (64, 64) for g in frame(hypotheses[:3]))


def test_pdf_batch_equals_pdf(hypotheses):
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-8e3, 8e3, 300), rng.uniform(-8e3, 8e3, 300)
    scores = pdf_batch(hypotheses, x, y)
    assert scores.shape == (len(hypotheses), 300)
    for k, model in enumerate(hypotheses):
        assert np.array_equal(scores[k], model.pdf(x, y)), k


def test_batch_bad_input(hypotheses):
    with pytest.raises(bg.BananagridError, match="models: expected at least one hypothesis"):
        rasterise_batch([])
    with pytest.raises(bg.BananagridError, match=r"models\[1\] = CAT: batches take PolarBanana"):
        rasterise_batch([hypotheses[0], bg.CAT(v0=100.0, t=10.0, sigma_a=1.0, sigma_omega=0.05)])
    grids = frame(hypotheses[:2])
    with pytest.raises(bg.BananagridError, match="grids: 2 grids for 3 hypotheses"):
        rasterise_batch(hypotheses[:3], grids)
    odd = bg.Grid.from_bounds(x=(0.0, 10.0), y=(0.0, 10.0), step=1.0)
    with pytest.raises(bg.BananagridError, match=r"grids\[1\]: shape \(10, 10\), but grids\[0\] has \(64, 64\)"):
        rasterise_batch(hypotheses[:2], [grids[0], odd])
    with pytest.raises(bg.BananagridError, match="x, y: points must be finite"):
        pdf_batch(hypotheses[:2], [0.0, math.nan], [0.0, 0.0])


@pytest.mark.parametrize("dtype, itemsize", [(np.float64, 8), (np.float32, 4)])
def test_a_batch_larger_than_memory_is_refused_before_anything_is_made(hypotheses, dtype, itemsize, monkeypatch):
    """Values that cannot fit are refused with the bytes, before the points or the values are
    made (a broadcast of 10^12 points allocates nothing until then); the limit is the memory
    available, here set to 1 GB."""
    monkeypatch.setattr("bananagrid.engine.memory.available_bytes", lambda: 10**9)
    with pytest.raises(bg.BananagridError) as info:
        pdf_batch(hypotheses, np.broadcast_to(0.0, (10**12,)), 0.0, dtype=dtype)
    assert f"a batch of {len(hypotheses)} hypotheses x 1,000,000,000,000 cells needs about" in str(info.value)
    assert f"({itemsize} bytes per cell), more than the 1 GB available" in str(info.value)
    with pytest.raises(bg.BananagridError, match=f"hypotheses x 400,000,000 cells needs .* more than the 1 GB"):
        rasterise_batch(hypotheses, shape=(20000, 20000), dtype=dtype)
    # a batch that fits runs
    assert pdf_batch(hypotheses, [0.0, 10.0], [100.0, 120.0], dtype=dtype).shape == (len(hypotheses), 2)
