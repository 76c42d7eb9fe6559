"""Memory before work: the stated bytes per cell are upper bounds of what runs take, and work
above the memory allowed is refused in one line before any computing."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from bananagrid import BananagridError, cli
from bananagrid.engine.memory import RASTERISE_BYTES_PER_CELL, available_bytes, check_memory, memory_limit
from bananagrid.scenes.load import load_scene
from bananagrid.scenes.run import RUN_BYTES_PER_CELL

ROOT = Path(__file__).resolve().parents[2]

#: A child process that runs one scene at about ``cells`` cells and prints its peak RSS growth
#: over the same run at a small grid (both in the child, so imports and compiled kernels count
#: once): ``(cells, bytes)``.
RUN_PEAK = """
import json, math, resource, sys, tempfile
from bananagrid.scenes.load import load_scene
from bananagrid.scenes.run import run_scene
scene = load_scene(sys.argv[1])
x0, x1, y0, y1 = scene.grid.extent
def sized(cells):
    return scene.with_step(math.sqrt((x1 - x0) * (y1 - y0) / cells))
with tempfile.TemporaryDirectory() as out:
    run_scene(sized(10_000), out)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    big = sized(float(sys.argv[2]))
    run_scene(big, out)
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps([big.grid.nx * big.grid.ny, (after - before) * 1024]))
"""

RASTERISE_PEAK = """
import json, math, resource, sys
import numpy as np
import bananagrid as bg
model = bg.CAT(v0=8.0, t=60.0, sigma_a=0.02, sigma_omega=math.radians(0.5))
dtype = np.dtype(sys.argv[1])
bg.rasterise(model, bg.Grid.from_bounds((-400.0, 800.0), (-400.0, 800.0), 12.0), dtype=dtype)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
grid = bg.Grid.from_bounds((-400.0, 800.0), (-400.0, 800.0), 0.6)
bg.rasterise(model, grid, dtype=dtype)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps([grid.nx * grid.ny, (after - before) * 1024]))
"""


def peak(script: str, *args: str) -> tuple[int, float]:
    run = subprocess.run([sys.executable, "-c", script, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    cells, grown = json.loads(run.stdout.strip().splitlines()[-1])
    return cells, grown


@pytest.mark.parametrize("scene", ["rice_isotropic", "ship_heading"])
def test_a_runs_peak_memory_stays_under_the_stated_bytes_per_cell(scene):
    """The two scenes that measured highest per cell (a Butterly; a heading CAT, a CAT and a
    polar layer): at 2 million cells the growth of the peak over a 10,000-cell run is under
    RUN_BYTES_PER_CELL per cell."""
    cells, grown = peak(RUN_PEAK, f"scenes/{scene}.toml", "2e6")
    assert cells > 1_500_000
    assert grown / cells < RUN_BYTES_PER_CELL, grown / cells


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_rasterises_peak_memory_stays_under_the_stated_bytes_per_cell(dtype):
    cells, grown = peak(RASTERISE_PEAK, dtype)
    assert cells == 2000 * 2000
    assert grown / cells < RASTERISE_BYTES_PER_CELL, grown / cells


def test_check_memory_refuses_in_one_line_with_both_figures():
    assert check_memory(1000, 100.0, "work", limit=1e6) == 1e5
    with pytest.raises(BananagridError) as info:
        check_memory(10_000_000, 96.0, "demo: a grid of 1 x 10,000,000 cells", limit=5e8, option="--max-memory GB")
    assert str(info.value) == (
        "demo: a grid of 1 x 10,000,000 cells needs about 960 MB (96 bytes per cell), more than the 500 MB "
        "allowed: use coarser cells or a smaller grid, or --max-memory GB to allow more"
    )


def test_the_system_says_how_much_memory_is_available():
    available = available_bytes()
    assert available is not None and 1e8 < available < 1e14  # Linux: MemAvailable


@pytest.mark.parametrize("bad", ["lots", -1.0, 0.0, math.inf, math.nan])
def test_a_bad_memory_limit_is_refused(bad):
    with pytest.raises(BananagridError, match="--max-memory = .*: expected a"):
        memory_limit(bad)


def test_run_refuses_a_scene_above_the_limit_before_computing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "run_scene", lambda *a, **k: pytest.fail("run_scene was called"))
    out = tmp_path / "out"
    code = cli.main(["run", "scenes/figure1.toml", "--out", str(out), "--max-memory", "0.05"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "bananagrid: error: scenes/figure1.toml: a grid of 1500 x 900 = 1,350,000 cells needs about 130 MB "
        "(96 bytes per cell), more than the 50 MB allowed: use coarser cells or a smaller grid, or "
        "--max-memory GB to allow more"
    ]
    assert not out.exists()


def test_the_estimate_grows_with_the_maps_kept_for_map_files(tmp_path):
    scene = load_scene(ROOT / "scenes" / "figure1.toml")
    plain = cli.check_run_memory(scene, limit=1e12)
    kept = cli.check_run_memory(scene, exports=True, limit=1e12)
    assert kept - plain == pytest.approx(scene.grid.nx * scene.grid.ny * 24 * len(scene.jobs()))
