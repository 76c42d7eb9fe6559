"""The bench's peers (Numba and JAX implementations of the polar density): they compute what
rasterise computes, the check that guards the timing can fail, and the timing runs on one core."""

import json
import math
import os

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.bench import peers
from bananagrid.bench import runner as bench
from bananagrid.validate import BananagridError

pytest.importorskip("numba")  # both are in the test extra: a missing one is a broken install, so
pytest.importorskip("jax")  # these skips are only for a user running the suite without them


def _case(variant):
    # rotated and moved off the origin, so that the peers' frame change is checked too
    model = bg.PolarBanana(v0=120.0, t=20.0, sigma_a=1.5, sigma_omega=0.04, variant=variant,
                           pose=bg.Pose(origin=(350.0, -1200.0), heading=0.7))
    grid = bg.Grid.from_bounds(x=(-2000.0, 3000.0), y=(-3500.0, 1500.0), step=25.0)
    return model, grid


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("variant", ["rough", "improved"])
@pytest.mark.parametrize("name", ["numba", "jax"])
def test_each_peer_computes_the_density_rasterise_computes(name, variant, dtype):
    model, grid = _case(variant)
    reference = bg.rasterise(model, grid, dtype=dtype, threads=1).values
    values = peers.PEERS[name](model, grid, dtype)()
    assert values.dtype == np.dtype(dtype)
    rel = peers.check_equal(name, values, reference)
    assert rel <= peers.AGREE_RTOL[np.dtype(dtype)]
    # and against an independent float64 evaluation of (8) and (11) at a few cells, where the peer
    # and rasterise could share a mistake of the grid's frame
    for i, j in [(100, 120), (150, 80), (60, 140)]:
        x, y = grid.x[j], grid.y[i]
        truth = float(model.pdf(np.array([x]), np.array([y]))[0])
        if truth > 1e-8 * reference.max():
            assert values[i, j] == pytest.approx(truth, rel=10 * peers.AGREE_RTOL[np.dtype(dtype)])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_numba_peer_is_what_a_skilled_user_writes(dtype):
    """Branch-free (no ``if`` statement in the loop: selects only), no libm call for atan2, exp,
    sin or cos, and the loop vectorised by LLVM (vector types in its IR), in both dtypes: the
    peer is the fast kernel, not one that calls libm per cell."""
    import re

    source = peers.skilled_polar_source(dtype)
    body = source.split("for j in range", 1)[1]
    assert not re.search(r"^\s*if\b", body, flags=re.M)
    assert not re.search(r"\b(math|np)\.(atan2|arctan2|exp|sin|cos)\b", body)
    model, grid = _case("improved")
    peer = peers.NumbaPolar(model, grid, dtype)
    llvm = "".join(peer.kernel.inspect_llvm().values())
    lanes = {int(n) for n in re.findall(r"<(\d+) x (?:double|float)>", llvm)}
    assert lanes and max(lanes) >= 2, lanes
    # its polynomials' accuracy (float64 fit: 6.7e-16 measured; bound 1e-15)
    a = np.linspace(0.0, peers.TAN_PI_8, 100001)[1:]
    c = peers.atan_coefficients(peers.ATAN_TERMS[np.dtype(np.float64)])
    assert np.max(np.abs(a * np.polyval(c[::-1], a * a) / np.arctan(a) - 1.0)) < 1e-15


def test_the_equality_check_refuses_a_wrong_peer():
    model, grid = _case("improved")
    reference = bg.rasterise(model, grid, threads=1).values
    wrong = reference.copy()
    i, j = np.unravel_index(np.argmax(reference), reference.shape)
    wrong[i, j] *= 1 + 1e-9  # 1e-9 relative at the peak: 1000x the float64 bound
    with pytest.raises(BananagridError, match="disagrees with rasterise"):
        peers.check_equal("numba", wrong, reference)
    nan = reference.copy()
    nan[0, 0] = np.nan
    with pytest.raises(BananagridError, match="disagrees"):
        peers.check_equal("jax", nan, reference)
    with pytest.raises(BananagridError, match="expected float64"):
        peers.check_equal("jax", reference.astype(np.float32), reference)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs Linux's CPU affinity")
def test_compare_pins_one_core_and_alternates_every_row():
    model, grid = _case("improved")
    before = os.sched_getaffinity(0)
    records = peers.compare(model, grid, np.float32, repeat=3)
    assert os.sched_getaffinity(0) == before  # the pin is undone
    assert [r["implementation"] for r in records] == ["bananagrid", "numpy", "numba", "jax"]
    for r in records:
        assert r["best_seconds"] <= r["median_seconds"] <= r["worst_seconds"]
        assert r["spread"] == pytest.approx(r["worst_seconds"] / r["best_seconds"] - 1)
        assert r["mcells_per_s"] == pytest.approx(grid.nx * grid.ny / r["best_seconds"] / 1e6)
        # one core: the process cannot use more CPU seconds than wall seconds (10 % for the two
        # clocks' granularity on runs of a few milliseconds)
        assert r["cpu_per_wall"] <= 1.1, r
    assert records[0]["bananagrid_speedup"] == 1.0


def test_bench_prints_the_peers_table(tmp_path, capsys):
    out = tmp_path / "bench.json"
    argv = ["--kernels", "polar-rough", "--step", "100", "--repeat", "2", "--threads", "1", "--no-memory",
            "--json", str(out)]
    assert bench.main(argv) == 0
    text = capsys.readouterr().out
    assert "peers on one core" in text and "-bit vectors (" in text  # the machine line names the width
    rows = [line.split() for line in text.splitlines() if line.startswith("polar-rough") and len(line.split()) == 10]
    assert {(r[1], r[2]) for r in rows} == {(d, i) for d in ("float64", "float32")
                                          for i in ("bananagrid", "numpy", "numba", "jax")}
    records = json.loads(out.read_text())["peers"]
    assert len(records) == 8 and all(math.isfinite(r["best_seconds"]) for r in records)
    assert bench.main(argv[:-2] + ["--no-peers"]) == 0
    assert "peers on one core" not in capsys.readouterr().out
