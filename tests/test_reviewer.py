"""What a reviewer sees: probability-mass (highest-density) regions and their contours, labels
placed once per level, the warnings that catch a grid missing the target or degrees typed as
radians, the run summary, and the default view (log10 first, no empty cell, last time)."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

import bananagrid as bg
from bananagrid import BananagridError, BananagridWarning, Raster
from bananagrid import cli
from bananagrid.analysis.coverage import MASS_EXCESS, coverage_warnings, leaking_edges, peak_location
from bananagrid.contours import (
    DEFAULT_MASS_LEVELS,
    cell_regions,
    contour_lines,
    format_area,
    format_level,
    label_positions,
    mass_levels,
    mass_regions,
)
from bananagrid.domains.grid import Grid
from bananagrid.recording.core import default_blueprint, focus_extent, log_raster, write_recording
from bananagrid.recording.inspect import inspect_recording
from bananagrid.recording.presence import region_edges
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run import run_scene

from cases import FIG1_BOUNDS, small_scene


def gaussian(grid: Grid, sx: float, sy: float, rho: float, centre=(10.0, -5.0)) -> Raster:
    """A bivariate normal density (m^-2) at the cell centres: an independent oracle with
    closed-form highest-density regions."""
    x, y = np.meshgrid(grid.x, grid.y)
    u, v = (x - centre[0]) / sx, (y - centre[1]) / sy
    q = (u * u - 2.0 * rho * u * v + v * v) / (1.0 - rho * rho)
    values = np.exp(-0.5 * q) / (2.0 * math.pi * sx * sy * math.sqrt(1.0 - rho * rho))
    return Raster(values=values, grid=grid, mass=float(values.sum() * grid.cell_area))


FINE = Grid.from_bounds(x=(-190.0, 210.0), y=(-155.0, 145.0), step=0.5)


# --- probability-mass regions -----------------------------------------------------------------


@pytest.mark.parametrize("sx, sy, rho", [(25.0, 12.0, 0.4), (20.0, 20.0, 0.0), (40.0, 8.0, -0.7)])
def test_regions_of_a_gaussian_match_its_ellipses(sx, sy, rho):
    # For a bivariate normal the region holding p is the ellipse q <= c, c = -2 ln(1 - p):
    # boundary density peak (1 - p), area pi c sx sy sqrt(1 - rho^2).
    raster = gaussian(FINE, sx, sy, rho)
    peak = 1.0 / (2.0 * math.pi * sx * sy * math.sqrt(1.0 - rho * rho))
    for region in mass_regions(raster, DEFAULT_MASS_LEVELS):
        p = region.probability
        c = -2.0 * math.log(1.0 - p)
        area = math.pi * c * sx * sy * math.sqrt(1.0 - rho * rho)
        # The region counts whole cells: it differs from the ellipse by cells its boundary
        # crosses, a band of the perimeter times at most a cell diagonal (h sqrt 2); the
        # perimeter is below 2 pi times the larger semi-axis sqrt(c) max(sx, sy).
        band = 2.0 * math.pi * math.sqrt(c) * max(sx, sy) * FINE.dx * math.sqrt(2.0)
        assert region.reached and abs(region.area - area) <= band
        assert region.cells * FINE.cell_area == region.area
        # The probability above density f is P(f) = 1 - f / peak. Counting whole cells moves
        # it by at most the probability in that band, about f * band, so the threshold f_d
        # where the cell count reaches p obeys |f_d / peak - (1 - p)| <= f band: a relative
        # error of at most peak * band (twice that for the density's variation across the band).
        assert region.density == pytest.approx(peak * (1.0 - p), rel=2.0 * band * peak)
        # It stops at the first cell that reaches p, taking the cells tied with it: the grid is
        # mirror-symmetric about the centre in x and y (and in x = y when sx = sy, rho = 0), so
        # at most 8 cells share a value.
        assert p <= region.enclosed <= p + 8 * region.density * FINE.cell_area


def test_region_is_the_smallest_set_holding_the_level():
    raster = gaussian(Grid.from_bounds(x=(-100.0, 100.0), y=(-80.0, 80.0), step=4.0), 25.0, 12.0, 0.4)
    values = raster.values
    for region in mass_regions(raster, (0.3, 0.5, 0.9, 0.99)):
        inside = values >= region.density
        assert inside.sum() == region.cells
        assert values[inside].sum() * raster.grid.cell_area == pytest.approx(region.enclosed, rel=1e-12)
        # every cell inside is denser than every cell outside, and without the boundary
        # cells the region holds less than the level
        assert values[inside].min() >= values[~inside].max()
        without = values[values > region.density].sum() * raster.grid.cell_area
        assert without < region.probability <= region.enclosed


def test_ties_at_the_boundary_are_all_inside():
    grid = Grid.from_bounds(x=(0.0, 4.0), y=(0.0, 1.0), step=1.0)
    raster = Raster(values=np.array([[0.4, 0.2, 0.2, 0.2]]), grid=grid, mass=1.0)
    (region,) = mass_regions(raster, [0.5])
    assert region.cells == 4 and region.enclosed == pytest.approx(1.0) and region.density == 0.2


def test_levels_above_the_grids_mass_are_not_reached():
    raster = gaussian(Grid.from_bounds(x=(10.0, 200.0), y=(-100.0, 100.0), step=5.0), 25.0, 12.0, 0.0)
    assert 0.45 < raster.mass < 0.55  # half the Gaussian is west of x = 10
    low, high = mass_regions(raster, (0.25, 0.9))
    assert low.reached and not high.reached and math.isnan(high.density)
    assert high.enclosed == pytest.approx(raster.mass, rel=1e-12)
    (message,) = coverage_warnings(raster, [low, high], where="demo")
    assert "captured 0.5" in message and "west edge" in message and "90 % probability-mass contour is not drawn" in message


@pytest.mark.parametrize("bad, match", [
    ([0.5, 1.0], r"mass_levels\[1\] = 1\.0: a probability-mass level must lie in \(0, 1\)"),
    ([0.0], r"mass_levels\[0\] = 0\.0"),
    (["a"], r'mass_levels\[0\] = "a": expected a probability'),
    ([True], r"mass_levels\[0\] = true"),
    (5, r"mass_levels = 5: expected a list"),
])
def test_bad_mass_levels_are_refused(bad, match):
    with pytest.raises(BananagridError, match=match):
        mass_levels(bad)


def test_format_area_and_level():
    assert format_area(293_440.0) == "0.293 km²"
    assert format_area(1.88e6) == "1.88 km²"
    assert format_area(2.5e10) == "25,000 km²"
    assert format_area(9_999.0) == "10,000 m²"
    assert format_area(1.5) == "1.50 m²"
    region = mass_regions(gaussian(FINE, 25.0, 12.0, 0.4), [0.9])[0]
    assert re.fullmatch(r"90 % · \d\.\d\d km²|90 % · [\d,]+ m²", format_level(region))


# --- labels -----------------------------------------------------------------------------------


def distance_to_polyline(point, line: np.ndarray) -> float:
    a, b = line[:-1], line[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", np.asarray(point) - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0, 1)
    nearest = a + t[:, None] * d
    return float(np.min(np.hypot(*(nearest - point).T)))


def test_one_label_per_level_on_its_own_line_and_apart():
    raster = gaussian(Grid.from_bounds(x=(-100.0, 120.0), y=(-80.0, 80.0), step=2.0), 25.0, 12.0, 0.4)
    regions = mass_regions(raster)
    lines = contour_lines(raster, [r.density for r in regions])
    spots = label_positions(lines)
    assert list(spots) == list(lines)  # one per level, in order
    for level, point in spots.items():
        assert min(distance_to_polyline(point, piece) for piece in lines[level]) < 1e-9
    points = np.array(list(spots.values()))
    gaps = [np.hypot(*(points[i] - points[j])) for i in range(len(points)) for j in range(i)]
    # Nested ellipses 2 cells apart at the closest: spread labels are far further apart.
    assert min(gaps) > 10.0 * raster.grid.dx
    assert label_positions(lines) == spots  # deterministic
    # labels of another set keep their distance from these
    again = label_positions(lines, avoid=list(spots.values()))
    assert all(min(np.hypot(*(np.array(p) - points).T)) > 0.0 for p in again.values())


def test_label_positions_skip_levels_without_lines():
    out = label_positions({1.0: [], 2.0: [np.array([[0.0, 0.0], [1.0, 0.0]])]})
    assert list(out) == [2.0]


# --- the recording ----------------------------------------------------------------------------


def cells(path: Path, entity: str, component: str) -> list:
    """Every logged value of one component of ``entity``, in log order."""
    out = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if component in batch.schema.names:
                out += [v.as_py() for v in batch.column(component) if v.is_valid]
    return out


def test_recording_draws_the_regions_labelled_once_per_level(tmp_path):
    raster = gaussian(Grid.from_bounds(x=(-100.0, 120.0), y=(-80.0, 80.0), step=2.0), 25.0, 12.0, 0.4)
    got = {}

    def build(rec):
        got["regions"] = log_raster(rec, "layers/g", raster)

    path = write_recording(tmp_path / "g.rrd", build, recording_id="g")
    regions = got["regions"]
    assert regions == mass_regions(raster, DEFAULT_MASS_LEVELS)
    (strips,) = cells(path, "/layers/g/contours/lines", "LineStrips2D:strips")
    expected = [piece for pieces in contour_lines(raster, [r.density for r in regions]).values() for piece in pieces]
    assert len(strips) == len(expected)
    for strip, piece in zip(strips, expected):
        np.testing.assert_allclose(np.array(strip), piece, rtol=1e-6)  # float32 storage
    (labels,) = cells(path, "/layers/g/contours/labels", "Points2D:labels")
    assert labels == [format_level(r) for r in regions]
    fields = inspect_recording(path)["entities"]["/layers/g/info"]["values"][-1]["values"]
    for r in regions:
        key = f"regions.{100 * r.probability:g}"
        assert fields[f"{key}.area"] == r.area and fields[f"{key}.density"] == r.density
        assert fields[f"{key}.enclosed"] == r.enclosed
    # the colour bar spans the log10 image's range: two decades below the 99 % boundary
    ((low, high),) = cells(path, "/layers/g/legend/colour_bar", "DepthImage:depth_range")[0]
    assert low == pytest.approx(math.log10(regions[-1].density) - 2.0) and high == pytest.approx(math.log10(raster.peak))


def test_focus_is_the_outer_region_padded_and_inside_the_grid():
    grid = Grid.from_bounds(x=(-400.0, 400.0), y=(-400.0, 400.0), step=2.0)
    raster = gaussian(grid, 10.0, 10.0, 0.0, centre=(0.0, 0.0))
    regions = mass_regions(raster)
    x0, x1, y0, y1 = focus_extent(raster, regions)
    radius = 10.0 * math.sqrt(-2.0 * math.log(0.01))  # the 99 % circle, 30.3 m
    # the cells of the 99 % region reach the circle to within a cell; 15 % padding each side
    assert x1 == pytest.approx(1.3 * radius + 0.3, abs=0.3 * 2.0 + 2.0) and x0 == pytest.approx(-x1)
    assert y0 == pytest.approx(x0) and y1 == pytest.approx(x1)
    edge = gaussian(grid, 10.0, 10.0, 0.0, centre=(390.0, 0.0))
    assert focus_extent(edge, mass_regions(edge))[1] == 400.0  # clipped to the grid


# --- warnings ---------------------------------------------------------------------------------


FIG1_EAST = f"""\
[scene]
name = "east"

[grid]
x = {list(FIG1_BOUNDS["x"])}
y = {list(FIG1_BOUNDS["y"])}
step = 8.0

[defaults]
v0 = 280.0
t = 10.0
sigma_a = 1.6666666666666667

[layers.cat]
model = "cat"
sigma_omega_deg = 3.3333333333333335
heading_deg = 90.0
"""


def run_with_warnings(text: str, tmp_path: Path) -> tuple[list[dict], list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = run_scene(parse_scene(text), tmp_path)
    return rows, [str(w.message) for w in caught if issubclass(w.category, BananagridWarning)]


def test_figure1_pointed_east_warns_with_its_mass_and_the_leaking_edges(tmp_path):
    rows, messages = run_with_warnings(FIG1_EAST, tmp_path)
    (row,) = rows
    (message,) = messages
    # The mass a user would check: 0.596 of the banana lies in the Figure 1 frame.
    assert row["mass"] == pytest.approx(0.5955, abs=5e-4)
    assert f"captured {row['mass']:.3g} of the probability (below 0.99)" in message
    assert "east" in message and "layer cat at t = 10 s" in message and "normalised" in message
    # and the recording's summary says the same
    ((text,),) = cells(tmp_path / "east.rrd", "/summary", "TextDocument:text")
    assert message in text


def test_the_threshold_is_a_scene_key(tmp_path):
    relaxed = FIG1_EAST.replace("[defaults]", "[output]\nmin_mass = 0.5\n\n[defaults]")
    _, messages = run_with_warnings(relaxed, tmp_path)
    assert messages == []
    with pytest.raises(BananagridError, match=r"output\.min_mass = 1\.5: must be in \[0, 1\]"):
        parse_scene(FIG1_EAST.replace("[defaults]", "[output]\nmin_mass = 1.5\n\n[defaults]"))
    with pytest.raises(BananagridError, match=r"output\.mass_levels\[0\] = 2: a probability-mass level"):
        parse_scene(FIG1_EAST.replace("[defaults]", "[output]\nmass_levels = [2]\n\n[defaults]"))


def test_leak_edges_and_coarse_cells_are_told_apart():
    grid = Grid.from_bounds(x=(0.0, 100.0), y=(0.0, 100.0), step=1.0)
    east = gaussian(grid, 10.0, 10.0, 0.0, centre=(100.0, 50.0))
    assert leaking_edges(east) == ["east"]
    corner = gaussian(grid, 10.0, 10.0, 0.0, centre=(100.0, 100.0))
    assert leaking_edges(corner) == ["north", "east"]
    # a density far narrower than the cells: mass missed, nothing at the edges
    coarse = Grid.from_bounds(x=(-50.0, 50.0), y=(-50.0, 50.0), step=10.0)
    narrow = gaussian(coarse, 0.5, 0.5, 0.0, centre=(3.0, 3.0))
    assert narrow.mass < 0.1 and leaking_edges(narrow) == []
    (message,) = coverage_warnings(narrow, mass_regions(narrow), where="narrow")
    assert "too coarse" in message and "refine the grid" in message


def test_degrees_typed_as_radians_warn_and_name_the_deg_key():
    text = small_scene("rad", '[layers.a]\nmodel = "cat"\nsigma_omega = 3.33\nheading = 90.0\n')
    text = text.replace("sigma_omega_deg = 10.0\n", "")
    with pytest.warns(BananagridWarning) as caught:
        scene = parse_scene(text)
    messages = [str(w.message) for w in caught]
    assert any("layers.a.sigma_omega = 3.33 rad/s" in m and "sigma_omega_deg" in m for m in messages)
    assert any("layers.a.heading = 90.0 rad is more than a full turn" in m and "heading_deg" in m for m in messages)
    assert len(scene.warnings) == 2
    # plausible radians and the _deg keys are quiet
    quiet = small_scene("ok", '[layers.a]\nmodel = "cat"\nheading = 1.5\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error", BananagridWarning)
        assert parse_scene(quiet).warnings == ()


def test_a_turn_rate_is_judged_over_the_latest_time():
    # 0.02 rad/s: 0.2 rad in 10 s, but 2 full turns in 720 s
    text = small_scene("late", '[layers.a]\nmodel = "cat"\nsigma_omega = 0.02\n').replace("sigma_omega_deg = 10.0\n", "")
    with warnings.catch_warnings():
        warnings.simplefilter("error", BananagridWarning)
        parse_scene(text)
    later = text.replace("t = 5.0\n", "").replace('name = "late"', 'name = "late"\ntimes = [10.0, 720.0]')
    with pytest.warns(BananagridWarning, match=r"t = 720 s"):
        parse_scene(later)


def test_contour_levels_outside_the_maps_range_warn(tmp_path):
    text = small_scene("levels", '[output]\ncontour_levels = [1.0, 1e-5]\n\n[layers.a]\nmodel = "cat"\n')
    text = text.replace('[output]\ncontour_levels = [1.0, 1e-5]\n\n', "").replace("[defaults]", '[output]\ncontour_levels = [1.0, 1e-5]\n\n[defaults]')
    rows, messages = run_with_warnings(text, tmp_path)
    assert any("contour level 1 m^-2 outside the map's range" in m for m in messages)
    assert not any("1e-05" in m for m in messages)  # inside the range: drawn


# --- the run summary and the command line -----------------------------------------------------


def test_rows_carry_the_peak_location_and_the_regions(tmp_path):
    text = small_scene("rows", '[layers.a]\nmodel = "cat"\n').replace("[defaults]", "[output]\nmass_levels = [0.8, 0.5]\n\n[defaults]")
    rows, _ = run_with_warnings(text, tmp_path)
    (row,) = rows
    scene = parse_scene(text)
    from bananagrid import rasterise

    raster = rasterise(scene.layers[0].model(5.0), scene.grid).normalise()
    assert (row["peak_x"], row["peak_y"]) == peak_location(raster)
    assert row["regions"] == mass_regions(raster, (0.5, 0.8))
    table = cli.format_summary(rows)
    assert "50 % area" in table and "80 % area" in table and "m^-2" in table


def test_cli_prints_warnings_on_their_own_lines(tmp_path, capsys):
    scene = tmp_path / "east.toml"
    scene.write_text(FIG1_EAST)
    assert cli.main(["run", str(scene), "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err.splitlines()
    warning_lines = [line for line in err if line.startswith("bananagrid: warning:")]
    assert len(warning_lines) == 1 and "east" in warning_lines[0]
    progress = [line for line in err if line.startswith("[")]
    # the progress line is restated after the warning and ends with its time
    assert progress[-1].startswith("[1/1] east: cat t=10 s ...") and progress[-1].endswith(" s")


# --- the default view -------------------------------------------------------------------------


def panels(container) -> list:
    """The panels of the maps-and-text area, row by row."""
    if isinstance(container, rrb.Horizontal):
        return [list(container.contents)]
    return [list(row.contents) for row in container.contents]


@pytest.mark.parametrize("n", range(1, 8))
def test_no_empty_cell_and_log10_first(n):
    layers = [f"layers/l{k}" for k in range(n)]
    blueprint = default_blueprint(layers, summary_entity="summary")
    rows = panels(blueprint.root_container)
    flat = [p for row in rows for p in row]
    assert len(flat) == n + 1 and all(1 <= len(row) <= 3 for row in rows)
    assert max(map(len, rows)) - min(map(len, rows)) <= 1
    for tabs, layer in zip(flat, layers):
        assert tabs.contents[0].name.startswith(f"{layer.removeprefix('layers/')} · log10 density")
        assert tabs.active_tab is None  # the first tab is shown
    side = flat[-1]
    assert isinstance(side, rrb.Tabs) and side.contents[0].name == "summary"


def test_mass_plot_and_last_time_only_for_several_times():
    one = default_blueprint(["layers/a"], summary_entity="summary")
    several = default_blueprint(["layers/a"], summary_entity="summary", several_times=True)
    assert getattr(one, "time_panel", None) is None
    assert not isinstance(panels(one.root_container)[0][-1], rrb.Vertical)
    side = panels(several.root_container)[0][-1]
    assert isinstance(side, rrb.Vertical) and isinstance(side.contents[1], rrb.TimeSeriesView)
    # the cursor follows the data to its end: the last time (checked in the viewer too)
    assert "following" in str(several.time_panel.play_state).lower()


# --- cells of an array ------------------------------------------------------------------------


def test_cell_regions_are_the_most_probable_cells():
    prob = np.array([[0.4, 0.1], [0.3, 0.2]])
    half, most = cell_regions(prob, (0.5, 0.85))
    assert (half.cells, half.enclosed, half.density) == (2, pytest.approx(0.7), 0.3)
    assert (most.cells, most.enclosed, most.density) == (3, pytest.approx(0.9), 0.2)
    assert math.isnan(half.area) and half.describe()["area"] is None  # recordings hold no NaN


def test_region_edges_are_its_perimeter_in_lattice_steps():
    inside = np.zeros((6, 4), bool)
    inside[1:3, 1:3] = True  # a 2 x 2 block: 4 edges across azimuth, 4 across elevation
    radial, arcs = region_edges(inside, wrap=True)
    assert sorted(map(tuple, radial)) == [(1, 1), (1, 2), (3, 1), (3, 2)]
    assert sorted(map(tuple, arcs)) == [(1, 1), (1, 3), (2, 1), (2, 3)]
    # a full ring of azimuths has no azimuth edge when the lattice wraps, two when it does not
    ring = np.zeros((6, 4), bool)
    ring[:, 2] = True
    assert len(region_edges(ring, wrap=True)[0]) == 0 and len(region_edges(ring, wrap=False)[0]) == 2
    assert len(region_edges(ring, wrap=True)[1]) == 12  # above and below, along every azimuth


def test_array_scene_outlines_and_warns_about_levels_above_its_total(tmp_path):
    from bananagrid.scenes.load import load_scene

    root = Path(__file__).resolve().parents[1] / "scenes"
    text = (root / "room_frustum.toml").read_text()
    scene = parse_scene(text.replace("mass_levels = [0.25, 0.5, 0.75]", "mass_levels = [0.5, 0.9]"))
    rows, messages = [], []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = run_scene(scene, tmp_path)
    messages = [str(w.message) for w in caught if issubclass(w.category, BananagridWarning)]
    (row,) = rows
    half, most = row["regions"]
    assert half.reached and not most.reached and most.enclosed == pytest.approx(row["mass"])
    assert any("90 % probability-mass outlines are not drawn" in m for m in messages)
    (labels,) = cells(tmp_path / "room_frustum.rrd", "/presence/plane/regions/labels", "Points3D:labels")
    assert labels == [f"50 % · {half.cells:,} cells"]
    assert load_scene(root / "room_frustum.toml").mass_levels == (0.25, 0.5, 0.75)


def test_a_mass_above_one_says_the_cells_are_too_coarse():
    """A Butterly start of 100 m SD on 500 m cells: the midpoint sum over the centre densities
    overcounts (a probability cannot exceed 1); a fine grid of the same start does not warn."""
    start = bg.Butterly(mean=(0.0, 0.0), cov=np.diag([100.0**2, 100.0**2]), speeds=[0.0], t=1.0)
    coarse = bg.rasterise(start, Grid.from_bounds((-2250.0, 2250.0), (-2250.0, 2250.0), 500.0))
    assert coarse.mass > 1.0 + MASS_EXCESS
    (message,) = coverage_warnings(coarse, mass_regions(coarse), where="coarse")
    assert f"gives a mass of {coarse.mass:.4g}, above 1 + 0.001" in message and "refine the grid" in message
    fine = bg.rasterise(start, Grid.from_bounds((-1000.0, 1000.0), (-1000.0, 1000.0), 20.0))
    assert abs(fine.mass - 1.0) < MASS_EXCESS
    assert coverage_warnings(fine, mass_regions(fine), where="fine") == []
