"""Recordings: what is written reads back exactly, in the right place, and deterministically."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from bananagrid import BananagridError, Grid, Raster
from bananagrid.contours import contour_lines, mass_inside, mass_regions
from bananagrid.recording.inspect import format_inspection, inspect_recording, read_depth_image
from bananagrid.recording import stream as stream_module
from bananagrid.recording.core import (
    default_blueprint,
    log_raster,
    log_scene_text,
    set_elapsed,
    verify_recording,
    write_recording,
)

RERUN = Path(sys.executable).parent / "rerun"
GRID = Grid.from_bounds(x=(-100.0, 100.0), y=(0.0, 150.0), step=5.0)
# Centre of the asymmetric test density, north-east of the grid centre (0, 75).
CENTRE = (30.0, 100.0)


def gaussian(grid: Grid, centre, sx: float, sy: float, rho: float = 0.0, scale: float = 1.0):
    """A bivariate normal density (per m^2) sampled at the cell centres of ``grid``."""
    x, y = np.meshgrid(grid.x, grid.y)
    u, v = (x - centre[0]) / sx, (y - centre[1]) / sy
    q = (u * u - 2.0 * rho * u * v + v * v) / (1.0 - rho * rho)
    values = scale * np.exp(-0.5 * q) / (2.0 * math.pi * sx * sy * math.sqrt(1.0 - rho * rho))
    return Raster(
        values=values,
        grid=grid,
        mass=float(values.sum() * grid.cell_area),
        provenance={"model": "test"},
    )


@pytest.fixture
def raster() -> Raster:
    # Off-centre, elongated east-west and tilted: any flip or transpose changes the array.
    return gaussian(GRID, CENTRE, sx=25.0, sy=12.0, rho=0.4)


def write(path: Path, rasters: dict[float, Raster], entity: str = "cat") -> Path:
    """Write ``{elapsed: raster}`` as one layer with the scene text and default blueprint."""

    def build(rec):
        log_scene_text(rec, 'model = "test"\n')
        for t, r in rasters.items():
            set_elapsed(rec, t)
            log_raster(rec, entity, r)

    blueprint = default_blueprint([entity])
    return write_recording(path, build, recording_id="test-recording", blueprint=blueprint)


def rerun_cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([str(RERUN), *map(str, args)], capture_output=True, text=True, timeout=120)


def first_cell(path: Path, entity: str, component: str) -> pa.Scalar:
    """The first logged cell of one component, read straight from the chunks."""
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if component in batch.schema.names:
                return batch.column(component)[0]
    raise AssertionError(f"{component} not logged at {entity}")


# --- round trip and orientation ---------------------------------------------------------------


def test_density_reads_back_exactly_in_grid_orientation(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster})
    back = read_depth_image(path, "cat/density")
    expected = raster.values.astype(np.float32)
    assert back.shape == GRID.shape and back.dtype == np.float32
    assert np.array_equal(back, expected)
    # A north-south flip of the asymmetric density would not pass the check above.
    assert not np.array_equal(np.flipud(back), expected)
    i, j = np.unravel_index(np.argmax(back), back.shape)
    assert abs(GRID.x[j] - CENTRE[0]) <= GRID.dx and abs(GRID.y[i] - CENTRE[1]) <= GRID.dy


def test_log10_density_is_floored_log(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster})
    back = read_depth_image(path, "/cat/log10_density")
    # two decades below the lowest contour drawn: the 99 % region's boundary density
    floor = math.log10(mass_regions(raster)[-1].density) - 2.0
    with np.errstate(divide="ignore"):
        expected = np.maximum(np.log10(raster.values), floor)
    np.testing.assert_allclose(back, expected, rtol=1e-6)  # float32 storage
    assert back.min() == pytest.approx(floor)


def test_image_pixels_land_on_cell_centres(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster})
    entity = "/cat/density"
    tx, ty, _ = first_cell(path, entity, "Transform3D:translation").as_py()[0]
    sx, sy, _ = first_cell(path, entity, "Transform3D:scale").as_py()[0]
    fmt = first_cell(path, entity, "DepthImage:format").as_py()[0]
    raw = np.frombuffer(bytes(first_cell(path, entity, "DepthImage:buffer").as_py()[0]), np.float32)
    image = raw.reshape(fmt["height"], fmt["width"])
    ny, nx = GRID.shape
    # Pixel (u, v) centre is (u + 1/2, v + 1/2); values[i, j] is stored at u = j, v = ny-1-i.
    u, v = np.arange(nx) + 0.5, ny - 1 - np.arange(ny) + 0.5
    np.testing.assert_allclose(tx + sx * u, GRID.x, atol=1e-9)
    np.testing.assert_allclose(ty + sy * v, GRID.y, atol=1e-9)
    # The stored image's top row is the northern row, as any image viewer expects.
    assert np.array_equal(image[0], raster.values[-1].astype(np.float32))


# --- files ------------------------------------------------------------------------------------


def test_rerun_verifies_the_file(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster, 2.0: raster})
    result = rerun_cli("rrd", "verify", path)
    assert result.returncode == 0, result.stderr


def test_same_content_compares_equal_and_other_content_does_not(tmp_path, raster):
    a = write(tmp_path / "a.rrd", {1.0: raster})
    b = write(tmp_path / "b.rrd", {1.0: raster})
    other = gaussian(GRID, CENTRE, sx=25.0, sy=12.0, rho=0.4, scale=2.0)
    c = write(tmp_path / "c.rrd", {1.0: other})
    same = rerun_cli("rrd", "compare", a, b)
    assert same.returncode == 0, same.stdout[-2000:] + same.stderr[-2000:]
    assert rerun_cli("rrd", "compare", a, c).returncode != 0


def test_failed_build_leaves_no_file(tmp_path, raster):
    path = tmp_path / "a.rrd"

    def build(rec):
        log_raster(rec, "cat", raster)
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        write_recording(path, build, recording_id="x")
    assert list(tmp_path.iterdir()) == []


def test_failed_build_keeps_the_previous_file(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster})
    before = path.read_bytes()

    def build(rec):
        raise KeyError("late")

    with pytest.raises(KeyError):
        write_recording(path, build, recording_id="x")
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.rrd"]


@pytest.mark.parametrize("name", ["missing.rrd", "text.rrd"])
def test_bad_file_is_one_line_error_naming_it(tmp_path, name):
    (tmp_path / "text.rrd").write_text("not a recording\n")
    with pytest.raises(BananagridError) as info:
        inspect_recording(tmp_path / name)
    message = str(info.value)
    assert name in message and "\n" not in message


# --- inspection -------------------------------------------------------------------------------


def test_inspect_reports_entities_and_value_range(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster})
    info = inspect_recording(path)
    density = info["entities"]["/cat/density"]
    assert "DepthImage" in density["archetypes"] and "Transform3D" in density["archetypes"]
    assert density["image_shapes"] == [GRID.shape]
    values = raster.values.astype(np.float32)
    assert density["value_range"] == (float(values.min()), float(values.max()))
    assert info["entities"]["/cat/contours/lines"]["archetypes"] == ["LineStrips2D"]
    assert info["entities"]["/cat/contours/labels"]["archetypes"] == ["Points2D"]
    assert info["entities"]["/scene"]["archetypes"] == ["TextDocument"]
    mass = info["entities"]["/cat/mass"]["scalars"]
    assert mass == [{"times": {"elapsed": 1.0}, "values": raster.mass}]
    fields = info["entities"]["/cat/info"]["values"][-1]["values"]
    assert fields["provenance.model"] == "test"
    assert (fields["grid.nx"], fields["grid.ny"]) == (GRID.nx, GRID.ny)
    assert fields["mass"] == raster.mass and fields["normalised"] == "false"
    assert info["blueprint"] and info["recording_id"] == "test-recording"
    text = format_inspection(info)
    assert "/cat/density" in text and "elapsed" in text


def test_elapsed_timeline_holds_both_times(tmp_path, raster):
    later = gaussian(GRID, (-20.0, 60.0), sx=30.0, sy=18.0, rho=-0.3)
    path = write(tmp_path / "a.rrd", {1.0: raster, 2.5: later})
    info = inspect_recording(path)
    # Only the elapsed timeline: no wall-clock log_time.
    assert set(info["timelines"]) == {"elapsed"}
    elapsed = info["timelines"]["elapsed"]
    assert elapsed["kind"] == "duration" and elapsed["values"] == [1.0, 2.5]
    masses = info["entities"]["/cat/mass"]["scalars"]
    assert [(s["times"]["elapsed"], s["values"]) for s in masses] == [
        (1.0, raster.mass),
        (2.5, later.mass),
    ]
    first, second = raster.values.astype(np.float32), later.values.astype(np.float32)
    assert np.array_equal(read_depth_image(path, "cat/density", elapsed=1.0), first)
    assert np.array_equal(read_depth_image(path, "cat/density", elapsed=2.5), second)
    assert np.array_equal(read_depth_image(path, "cat/density"), second)  # latest
    with pytest.raises(BananagridError, match="elapsed"):
        read_depth_image(path, "cat/density", elapsed=3.0)


# --- contours ---------------------------------------------------------------------------------


def test_contour_of_round_gaussian_is_circle_of_analytic_radius():
    sigma, centre = 20.0, (10.0, 70.0)
    raster = gaussian(GRID, centre, sx=sigma, sy=sigma)
    peak = 1.0 / (2.0 * math.pi * sigma**2)
    radius = 2.0 * sigma
    level = peak * math.exp(-0.5 * (radius / sigma) ** 2)
    (line,) = contour_lines(raster, [level])[level]
    assert line.dtype == np.float64 and line.shape[1] == 2
    assert np.array_equal(line[0], line[-1])  # closed
    r = np.hypot(line[:, 0] - centre[0], line[:, 1] - centre[1])
    # Marching squares puts each vertex where the linear interpolant between two centres h
    # apart crosses the level; that misplaces it radially by at most
    # h^2/8 * |f''/f'| = h^2/8 * (r^2/sigma^2 - 1)/r = 25/8 * 3/40 = 0.23 m at r = 2 sigma
    # (h = 5 m). 0.3 m allows for the neglected higher-order terms.
    assert np.max(np.abs(r - radius)) < 0.3


def test_contour_level_outside_range_is_empty(raster):
    assert contour_lines(raster, [1.0]) == {1.0: []}


def test_mass_inside_is_midpoint_sum_above_level(raster):
    assert mass_inside(raster, 0.0) == pytest.approx(raster.mass, rel=1e-12)
    assert mass_inside(raster, 2.0 * raster.peak) == 0.0
    level = 0.5 * raster.peak
    expected = raster.values[raster.values >= level].sum() * GRID.cell_area
    assert mass_inside(raster, level) == pytest.approx(expected, rel=1e-12)


def test_inspect_counts_non_finite_pixels_instead_of_a_nan_range(tmp_path):
    """A recording from elsewhere (bananagrid never logs NaN) with 3 NaN and 1 inf in an image:
    the range covers the finite pixels and the counts are reported."""
    image = np.arange(20, dtype=np.float32).reshape(4, 5)
    image[0, :3] = np.nan
    image[3, 4] = np.inf
    path = tmp_path / "foreign.rrd"

    def build(rec):
        rec.log("img", rr.DepthImage(image))

    write_recording(path, build, recording_id="foreign")
    summary = inspect_recording(path)["entities"]["/img"]
    assert summary["value_range"] == (3.0, 18.0)
    assert summary["non_finite"] == {"nan": 3, "inf": 1}
    text = format_inspection(inspect_recording(path))
    assert "values 3 .. 18 (finite ones); 3 NaN, 1 infinite" in text


def test_a_recording_cut_short_is_refused_before_it_is_named(tmp_path, raster, monkeypatch):
    """The file is read back before the rename: cut to half after rerun closes it (a full disk
    or a dying writer), it raises one line and leaves neither the file nor its temporary."""
    real_close = stream_module._close

    def close_then_cut(rec, shown, partial, **kwargs):
        real_close(rec, shown, partial, **kwargs)
        with open(partial, "r+b") as f:
            f.truncate(partial.stat().st_size // 2)

    monkeypatch.setattr(stream_module, "_close", close_then_cut)
    with pytest.raises(BananagridError, match=r"a\.rrd: the recording written does not read back") as info:
        write(tmp_path / "a.rrd", {1.0: raster})
    assert "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_verify_recording_accepts_what_write_recording_wrote(tmp_path, raster):
    path = write(tmp_path / "a.rrd", {1.0: raster})
    verify_recording(path, "test-recording")
    with pytest.raises(BananagridError, match="does not hold recording 'other' alone"):
        verify_recording(path, "other")
