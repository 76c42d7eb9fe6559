"""bananagrid inspect answers where the target is: per layer and time the captured mass, the peak
and its place, the probability-mass regions (checked against the API's own raster); per angular
cell map the peak cell probability and its cell; whole numbers printed whole; --json for
scripts; quiet when its reader leaves; damaged files a one-line error. Also the read-back of a
recording's layers as rasters (``read_rasters``), which ``plot`` shares."""

from __future__ import annotations

import json
import os
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from bananagrid import BananagridError, Raster, cli, rasterise
from bananagrid.analysis.coverage import peak_location
from bananagrid.contours import mass_regions
from bananagrid.recording.core import set_elapsed, write_recording
from bananagrid.recording.inspect import json_ready
from bananagrid.recording.readback import read_cell_maps, read_layers, read_rasters
from bananagrid.scenes.load import parse_scene

from cases import small_scene

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
#: A slow target at 2 and 5 s on a 20 x 20 grid of 10 m cells (milliseconds to compute).
TEXT = small_scene("where", '[layers.a]\nmodel = "cat"\n').replace("t = 5.0\n", "").replace(
    'name = "where"', 'name = "where"\ntimes = [2.0, 5.0]')
#: The same on a grid whose origin and step are not float32 numbers (the transform is float32).
ODD = TEXT.replace('name = "where"', 'name = "odd"').replace(
    "x = [-100.0, 100.0]\ny = [0.0, 200.0]\nstep = 10.0", "x = [-100.1, 99.9]\ny = [0.3, 200.3]\nstep = 9.7")
#: float32's unit roundoff: storing a float64 in float32 changes it by at most this, relatively.
F32 = 2.0**-24


def run(tmp_path: Path, text: str, name: str) -> Path:
    (tmp_path / f"{name}.toml").write_text(text)
    assert cli.main(["run", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path), "--quiet"]) == 0
    return tmp_path / f"{name}.rrd"


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return run(tmp_path_factory.mktemp("inspect"), TEXT, "where")


@pytest.fixture(scope="module")
def arrays(tmp_path_factory) -> dict[str, Path]:
    """An array scene's recordings: the 1-D line and the plane (cell maps, no density layer)."""
    out = tmp_path_factory.mktemp("arrays")
    assert cli.main(["run", str(ROOT / "scenes" / "line_section4.toml"), str(ROOT / "scenes" / "room_mixture.toml"),
                     "--out", str(out), "--quiet"]) == 0
    return {name: out / f"{name}.rrd" for name in ("line_section4", "room_mixture")}


def api_raster(text: str, t: float) -> Raster:
    """The layer as the API computes it: float64, normalised (as ``run`` does by default)."""
    scene = parse_scene(text)
    return rasterise(scene.layers[0].model(t), scene.grid).normalise()


def as_stored(raster: Raster) -> Raster:
    """``raster`` as the recording stores it: its values rounded to float32."""
    stored = raster.values.astype(np.float32).astype(np.float64)
    return Raster(values=stored, grid=raster.grid, mass=raster.mass, normalised=True)


def inspect_json(capsys, *argv: str) -> list[dict]:
    assert cli.main(["inspect", "--json", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def bare_layer(path: Path, values: np.ndarray) -> Path:
    """A recording of one layer ``bare`` at 1.5 s: only its density image (``values`` rows south
    first) and the pixel-to-world transform of 2.5 m x 1.5 m cells whose north-west corner is
    (100, 54.5) m."""
    def build(rec):
        set_elapsed(rec, 1.5)
        rec.log("layers/bare/density", rr.DepthImage(np.flipud(values).astype(np.float32)),
                rr.Transform3D(translation=(100.0, 54.5, 0.0), scale=(2.5, -1.5, 1.0)))

    return write_recording(path, build, recording_id="bare")


# --- reading layers back ----------------------------------------------------------------------


@pytest.mark.parametrize("text", [TEXT, ODD], ids=["grid", "odd-grid"])
def test_read_rasters_gives_back_the_api_raster(tmp_path, text):
    name = parse_scene(text).name
    found = read_rasters(run(tmp_path, text, name))
    assert [(item.layer, item.entity, item.t) for item in found] == [("a", "layers/a", 2.0), ("a", "layers/a", 5.0)]
    for item in found:
        raster = api_raster(text, item.t)
        # The grid comes back exactly (float64 from the layer's info), not to float32 precision.
        assert item.raster.grid == raster.grid
        assert item.raster.values.dtype == np.float64 and item.raster.values.shape == raster.grid.shape
        np.testing.assert_array_equal(item.raster.values, as_stored(raster).values)  # rows south first
        assert item.raster.mass == raster.mass and item.raster.normalised and item.raster.quantity == "density"
        assert item.raster.provenance["model"] == "CAT" and item.raster.provenance["t"] == item.t


def test_a_layer_without_info_is_placed_by_its_transform(tmp_path):
    """Only the image and its pixel-to-world transform (float32): the grid to float32 precision."""
    values = np.arange(12.0).reshape(3, 4)
    (item,) = read_rasters(bare_layer(tmp_path / "bare.rrd", values))
    assert (item.layer, item.t) == ("bare", 1.5)
    grid = item.raster.grid
    assert (grid.nx, grid.ny, grid.dx, grid.dy) == (4, 3, 2.5, 1.5) and grid.origin == (100.0, 50.0)
    np.testing.assert_array_equal(item.raster.values, values)
    assert math.isnan(item.raster.mass) and not item.raster.normalised


def test_array_recordings_have_cell_maps_not_layers(arrays, capsys):
    with pytest.raises(BananagridError, match="no density layers"):
        read_rasters(arrays["line_section4"])
    assert read_layers(arrays["line_section4"]) == []
    (cells,) = read_cell_maps(arrays["line_section4"])
    assert cells.entity == "presence" and cells.lattice.geometry == "line" and cells.prob.shape == (181,)
    (info,) = inspect_json(capsys, str(arrays["line_section4"]))
    assert info["layers"] == [] and "/presence/summary" in info["entities"]


# --- where the target is ----------------------------------------------------------------------


def test_json_layers_match_the_api(recording, capsys):
    (info,) = inspect_json(capsys, str(recording))
    layers = info["layers"]
    assert [(item["layer"], item["t"]) for item in layers] == [("a", 2.0), ("a", 5.0)]
    for item in layers:
        raster = api_raster(TEXT, item["t"])
        stored = as_stored(raster)
        assert item["mass"] == raster.mass  # the raw captured mass, recorded in float64
        # Exactly what the recorded float32 values give:
        assert (item["peak_x"], item["peak_y"]) == peak_location(stored)
        assert item["peak"] == stored.peak
        regions = [r.describe() for r in mass_regions(stored)]
        for r in regions:
            r["area_km2"] = r["area"] / 1e6
        assert item["regions"] == regions
        # Against the float64 raster: float32 moves each value by at most F32 relatively, so the
        # peak (a clear maximum here) stays in its cell and changes by at most F32 of itself.
        assert (item["peak_x"], item["peak_y"]) == peak_location(raster)
        assert item["peak"] == pytest.approx(raster.peak, rel=F32, abs=0)
        # A region's running sum of cell probabilities moves by at most F32 (they sum to 1),
        # so its boundary moves by at most the cells holding F32 + one boundary cell's
        # probability: here under one cell, and what it holds moves by one cell's probability.
        for got, exact in zip(item["regions"], mass_regions(raster)):
            cell = exact.density * raster.grid.cell_area  # the boundary cell's probability
            slack = 1 + math.ceil(2 * F32 / cell)
            assert got["reached"] and got["probability"] == exact.probability
            assert abs(got["cells"] - exact.cells) <= slack
            assert abs(got["area"] - exact.area) <= slack * raster.grid.cell_area
            assert got["enclosed"] == pytest.approx(exact.enclosed, abs=slack * cell + 2 * F32)


def test_json_numbers_are_typed_and_null_for_nan(recording, capsys):
    (info,) = inspect_json(capsys, "--mass-levels", "0.9,0.5", str(recording))
    item = info["layers"][-1]
    assert [r["probability"] for r in item["regions"]] == [0.5, 0.9]  # sorted
    grid = item["grid"]
    assert all(type(grid[key]) is int for key in ("nx", "ny")) and (grid["nx"], grid["ny"]) == (20, 20)
    assert all(type(r["cells"]) is int for r in item["regions"])
    assert type(item["mass"]) is float and type(item["peak_x"]) is float and type(item["normalised"]) is bool
    # Recorded numbers are floats in the file; whole ones come back as integers.
    fields = info["entities"]["/layers/a/info"]["values"][-1]["values"]
    assert type(fields["grid.nx"]) is int and fields["grid.nx"] == 20 and type(fields["mass"]) is float
    assert type(info["timelines"]["elapsed"]["count"]) is int
    assert json_ready({"a": math.nan, "b": (1, np.float32(2.5), -math.inf), "c": np.int64(3), "d": {4}}) == {
        "a": None, "b": [1, 2.5, None], "c": 3, "d": [4]}


def test_text_report_says_where_first_and_prints_whole_numbers_whole(recording, capsys):
    assert cli.main(["inspect", "--mass-levels", "0.5,0.9", str(recording)]) == 0
    text = capsys.readouterr().out
    stored = as_stored(api_raster(TEXT, 5.0))
    x, y = peak_location(stored)
    lines = text.splitlines()
    assert lines[0] == f"recording  {recording}"
    assert lines[3] == "where the target is (density layers; from the recorded float32 images)"
    assert text.index("where the target is") < text.index("timelines") < text.index("entities")
    assert "  a at t = 5 s\n" in text
    assert f"    captured mass          {stored.mass:.6f} (" in text
    place = f"x = {x:,.0f} m, y = {y:,.0f} m (east, north)"  # 10 m cells: whole metres
    assert f"peak density           {stored.peak:.6g} m^-2 in the cell centred on {place}" in text
    half = mass_regions(stored, [0.5])[0]
    rows = [line.split() for line in lines if line.startswith("    50 %")]
    assert rows[-1][3:] == [f"{half.area:,.0f}", f"{half.cells:,}", f"{half.enclosed:.6f}"]  # after the km²
    assert "region  area [km²]  area [m²]" in text and "99 %" not in text
    assert "grid.nx = 20\n" in text and "grid.nx = 20.0" not in text
    assert f"mass = {stored.mass:.8g}\n" in text  # recorded floats to 8 significant digits


def test_cell_maps_say_cell_probability_not_density(arrays, capsys):
    assert cli.main(["inspect", str(arrays["room_mixture"])]) == 0
    text = capsys.readouterr().out
    where = text[text.index("where the target is"):text.index("timelines")]
    assert where.startswith("where the target is (angular cell maps; cell probabilities p(C | S), not densities)")
    assert "    peak cell probability  " in where and "m^-2" not in where and "km²" not in where
    (info,) = inspect_json(capsys, str(arrays["room_mixture"]))
    (item,) = info["cell_maps"]
    summary = info["entities"]["/presence/summary"]["values"][-1]["values"]
    assert (item["geometry"], item["cells"]) == ("plane", 360 * 91) and type(item["cells"]) is int
    assert item["peak"] == float(np.float32(summary["peak"]))  # the float32 table's largest cell
    # The heaviest component (weight 0.5) sits at (-1.8, 1.5) on the plane 1.8 m below: the peak
    # cell is the one around it (cells there are about 0.04 m by 0.07 m).
    assert math.hypot(item["peak_x"] + 1.8, item["peak_y"] - 1.5) < 0.15 and item["peak_z"] == -1.8
    assert item["peak_azimuth_deg"] == pytest.approx(math.degrees(math.atan2(item["peak_y"], item["peak_x"])), abs=0.5)
    rho = math.hypot(item["peak_x"], item["peak_y"])
    assert item["peak_elevation_deg"] == pytest.approx(180.0 - math.degrees(math.atan2(rho, 1.8)), abs=0.5)
    for region in item["regions"]:  # as the run found them in float64, to a cell
        key = f"regions.{100 * region['probability']:g}"
        assert abs(region["cells"] - summary[f"{key}.cells"]) <= 1
        assert region["enclosed"] == pytest.approx(summary[f"{key}.enclosed"], abs=2 * summary[f"{key}.density"])


def test_line_cell_map_has_no_elevation(arrays, capsys):
    (info,) = inspect_json(capsys, str(arrays["line_section4"]))
    (item,) = info["cell_maps"]
    assert item["geometry"] == "line" and item["peak_elevation_deg"] is None
    assert (item["peak_y"], item["peak_z"]) == (0.0, -1.8)


# --- the command line -------------------------------------------------------------------------


@pytest.mark.parametrize("option", ["", "--json"])
def test_quiet_on_a_closed_pipe(recording, option):
    """``| head -1``: no "Broken pipe" message, and bananagrid's own status 0 (pipefail). The
    file is named 60 times so that the report (about 5 kB each) overflows the pipe's buffer
    (64 kB) and the writes after head left do fail."""
    files = " ".join([f"'{recording}'"] * 60)
    command = f"set -o pipefail; '{BIN / 'bananagrid'}' inspect {option} {files} | head -1"
    done = subprocess.run(["bash", "-c", command], capture_output=True, text=True, timeout=300)
    assert done.stderr == "" and done.returncode == 0
    assert done.stdout.startswith("recording" if not option else "[")


@pytest.mark.parametrize("damage", ["text", "truncated", "nan"])
def test_damaged_files_are_one_line_errors(recording, tmp_path, capsys, damage):
    bad = tmp_path / "bad.rrd"
    if damage == "text":
        bad.write_text("not a recording\n")
    elif damage == "truncated":
        data = recording.read_bytes()
        bad.write_bytes(data[: len(data) // 2])
    else:  # run never logs a NaN density
        bare_layer(bad, np.array([[0.0, 1.0], [np.nan, 2.0]]))
    assert cli.main(["inspect", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"bananagrid: error: {bad}: ") and err.count("\n") == 1


def test_bad_mass_levels(recording, capsys):
    assert cli.main(["inspect", "--mass-levels", "0.5,1.5", str(recording)]) == 2
    assert capsys.readouterr().err == (
        "bananagrid: error: --mass-levels[1] = 1.5: a probability-mass level must lie in (0, 1)\n")


def test_an_unnormalised_map_says_so(tmp_path, capsys):
    text = TEXT.replace('name = "where"', 'name = "raw"') + "\n[output]\nnormalise = false\n"
    path = run(tmp_path, text, "raw")
    assert cli.main(["inspect", "--mass-levels", "0.5", str(path)]) == 0
    mass = api_raster(text, 5.0).mass
    assert f"captured mass          {mass:.6f} ({1 - mass:.3g} missing; the map is not normalised)" in capsys.readouterr().out


def test_what_reruns_reader_complains_of_is_damage(recording, monkeypatch, tmp_path):
    """A recording whose rows decode but whose chunk metadata rerun's reader complains of on
    stderr (a damaged schema version, say: "ERROR re_sorbet::migrations: ... could not parse")
    is refused as damaged in one line, not read with rerun's log lines on stderr. The complaint
    is simulated here (a byte of the real one is hard to hit on purpose: the chunks are
    compressed); tests/test_damaged_inputs.py meets real ones among its random damages."""
    import bananagrid.recording.readback as readback

    whole = readback.recording_rows

    def complaining(reader, store):
        os.write(2, b"\x1b[31mERROR\x1b[0m re_sorbet::migrations: could not parse 'sorbet:version: 0.!.4'\n")
        yield from whole(reader, store)

    monkeypatch.setattr(readback, "recording_rows", complaining)
    copy = tmp_path / "copy.rrd"
    copy.write_bytes(recording.read_bytes())
    with pytest.raises(BananagridError, match=r"copy\.rrd: damaged \(rerun's reader: could not parse 'sorbet:"):
        readback._read_whole(copy)
    monkeypatch.setattr(readback, "recording_rows", whole)
    readback._read_whole(copy)  # the same file without the complaint reads
