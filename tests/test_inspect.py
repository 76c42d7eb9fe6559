"""bananagrid inspect answers where the target is: per layer and time the captured mass, the peak
and its place, the probability-mass regions; whole numbers printed whole; --json for scripts;
quiet when its reader leaves."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bananagrid import Raster, cli, rasterise
from bananagrid.analysis.coverage import peak_location
from bananagrid.contours import mass_regions
from bananagrid.scenes.load import parse_scene

from cases import small_scene

BIN = Path(sys.executable).parent
TEXT = small_scene("where", '[layers.a]\nmodel = "cat"\n').replace("t = 5.0\n", "").replace(
    'name = "where"', 'name = "where"\ntimes = [2.0, 5.0]')


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("inspect")
    (out / "where.toml").write_text(TEXT)
    assert cli.main(["run", str(out / "where.toml"), "--out", str(out), "--quiet"]) == 0
    return out / "where.rrd"


def expected(t: float) -> Raster:
    """The layer as the API computes it, as the recording stores it (float32 image)."""
    scene = parse_scene(TEXT)
    raster = rasterise(scene.layers[0].model(t), scene.grid).normalise()
    stored = raster.values.astype(np.float32).astype(np.float64)
    return Raster(values=stored, grid=raster.grid, mass=raster.mass, normalised=True)


def test_json_layers_match_the_api(recording, capsys):
    assert cli.main(["inspect", "--json", str(recording)]) == 0
    (info,) = json.loads(capsys.readouterr().out)
    layers = info["layers"]
    assert [(item["layer"], item["t"]) for item in layers] == [("a", 2.0), ("a", 5.0)]
    for item in layers:
        raster = expected(item["t"])
        assert item["mass"] == raster.mass  # the raw captured mass, recorded as float64
        assert (item["peak_x"], item["peak_y"]) == peak_location(raster)
        assert item["peak"] == raster.peak
        # the regions of the stored float32 values, exactly
        assert item["regions"] == [r.describe() for r in mass_regions(raster)]
        assert all(isinstance(r["cells"], int) for r in item["regions"])


def test_text_report_says_where_and_prints_whole_numbers_whole(recording, capsys):
    assert cli.main(["inspect", "--mass-levels", "0.5,0.9", str(recording)]) == 0
    text = capsys.readouterr().out
    raster = expected(5.0)
    x, y = peak_location(raster)
    assert f"a at t = 5 s: captured mass {raster.mass:.6f}, peak {raster.peak:.4g} m^-2 at (x, y) = ({x:.6g}, {y:.6g}) m" in text
    half = mass_regions(raster, [0.5])[0]
    assert "50 % region: " in text and f"{half.cells:,} cells, holds {half.enclosed:.6f}" in text
    assert "99 % region" not in text
    assert "grid.nx = 20" in text and "grid.nx = 20.0" not in text


def test_quiet_on_a_closed_pipe(recording):
    run = subprocess.run(f"'{BIN / 'bananagrid'}' inspect '{recording}' | head -1", shell=True,
                         capture_output=True, text=True, timeout=300)
    assert run.stdout.startswith("recording") and run.stderr == ""


def test_array_recordings_have_no_layers(tmp_path, capsys):
    root = Path(__file__).resolve().parents[1]
    assert cli.main(["run", str(root / "scenes" / "line_section4.toml"), "--out", str(tmp_path), "--quiet"]) == 0
    capsys.readouterr()
    assert cli.main(["inspect", "--json", str(tmp_path / "line_section4.rrd")]) == 0
    (info,) = json.loads(capsys.readouterr().out)
    assert info["layers"] == [] and "/presence/summary" in info["entities"]
