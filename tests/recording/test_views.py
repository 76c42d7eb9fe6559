"""What the views open on, without a viewer: the legend inside each map's view bounds, the
captured-mass plot on 0 to 1, one colour range for maps side by side, a UTC timeline for a
geographic scene, and the colour scale beside an array's cells."""

from __future__ import annotations

import math
from pathlib import Path
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from bananagrid import Grid, Raster
from bananagrid.recording.blueprint import (
    SHARED_NOTE,
    ColourRange,
    default_blueprint,
    map_panel_points,
    mass_axis,
    view_bounds,
)
from bananagrid.recording.labels import PANEL_SLACK
from bananagrid.recording.layers import SHARED_LEGEND
from bananagrid.recording.legend import SHARED_TITLE
from bananagrid.recording.presence import PLANE_PANEL_POINTS, plane_frame, scale_colours, seen_on_plane
from bananagrid.recording.raster import log_raster_layer
from bananagrid.recording.stream import write_recording
from bananagrid.recording.timeline import UTC, utc_nanos
from bananagrid.scenes.load import load_scene, parse_scene
from bananagrid.scenes.run import run_scene
from label_boxes import assert_apart, shown_labels

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def rows(path, entity: str) -> list:
    """(record batch) of every chunk of ``entity``."""
    return [c.to_record_batch() for c in RrdReader(path).stream() if c.entity_path == entity]


def first(batches, column: str):
    for batch in batches:
        if column in batch.schema.names:
            return batch.column(column)[0].as_py()
    raise AssertionError(f"{column} not logged")


def elongated(grid: Grid, sx: float, sy: float) -> Raster:
    x, y = np.meshgrid(grid.x, grid.y)
    values = np.exp(-0.5 * ((x / sx) ** 2 + (y / sy) ** 2)) / (2.0 * math.pi * sx * sy)
    return Raster(values=values, grid=grid, mass=float(values.sum() * grid.cell_area), provenance={"model": "test"})


@pytest.mark.parametrize("n_maps", [1, 2, 3, 5])
@pytest.mark.parametrize("sx, sy", [(100.0, 100.0), (30.0, 300.0), (300.0, 30.0)])
def test_the_legend_lies_inside_the_maps_view(tmp_path, n_maps, sx, sy):
    """A map's view (its blueprint bounds) holds its frame, the colour bar and the scale bar
    beside it, and their labels' boxes, for round, tall and wide maps in every layout (a narrow
    panel once clipped the labels and the circles)."""
    grid = Grid.from_bounds(x=(-1500.0, 1500.0), y=(-1500.0, 1500.0), step=20.0)
    panel = map_panel_points(n_maps)
    got = {}
    path = write_recording(tmp_path / "l.rrd", lambda rec: got.setdefault(
        "logged", log_raster_layer(rec, "layers/m", elongated(grid, sx, sy), panel=panel)), recording_id="l")
    frame = got["logged"].frame
    bounds = view_bounds(frame, panel)
    west, east, south, north = bounds
    assert west <= frame[0] and frame[1] <= east and south <= frame[2] and frame[3] <= north
    # the colour bar: its image's pixels placed by its transform (row 0 at the top)
    legend = rows(path, "/layers/m/legend/colour_bar")
    (tx, ty, _), (scale_x, scale_y, _) = first(legend, "Transform3D:translation")[0], first(legend, "Transform3D:scale")[0]
    height_px = 256  # COLOUR_BAR_PIXELS rows, one column
    bar = (tx, tx + scale_x, ty + scale_y * height_px, ty)
    assert west <= bar[0] and bar[1] <= east and south <= bar[2] and bar[3] <= north
    # every label of the legend, as rerun draws it (centred under its point, in screen points)
    pt = PANEL_SLACK * max((frame[1] - frame[0]) / panel[0], (frame[3] - frame[2]) / panel[1])
    ticks = rows(path, "/layers/m/legend/ticks")
    scale_bar = np.array(first(rows(path, "/layers/m/legend/scale"), "LineStrips2D:strips")[0])
    spots = list(zip(first(ticks, "Points2D:labels"), first(ticks, "Points2D:positions")))
    spots.append((first(rows(path, "/layers/m/legend/scale"), "LineStrips2D:labels")[0], scale_bar.mean(axis=0)))
    for text, (x, y) in spots:
        half = 0.5 * (6.5 * len(text) + 8.0) * pt  # the measured text metrics (labels module)
        assert west <= x - half and x + half <= east, f"{text!r} beyond the view's east or west edge"
        assert south <= y - 21.0 * pt and y + 3.0 * pt <= north, f"{text!r} beyond the view's north or south edge"


def test_the_blueprint_opens_each_map_on_its_view_bounds():
    frame = (0.0, 1000.0, -200.0, 3000.0)
    blueprint = default_blueprint(["layers/a"], summary_entity="summary", frames={"layers/a": frame})
    view = blueprint.root_container.contents[0].contents[0]
    got = view.properties["VisualBounds2D"].range.as_arrow_array().to_pylist()[0]
    west, east, south, north = view_bounds(frame, map_panel_points(1))
    np.testing.assert_allclose([got["x_range"], got["y_range"]], [[west, east], [-north, -south]])


@pytest.mark.parametrize("top, expected", [(0.2, (0.0, 1.05)), (1.0, (0.0, 1.05)), (1.3, (0.0, 1.365)),
                                           (math.nan, (0.0, 1.05))])
def test_the_captured_mass_plot_shows_zero_to_one(top, expected):
    """Masses near 1 are drawn near the top of a 0-to-1 axis, not zoomed onto a sliver; a mass
    above 1 (cells too coarse) stays in view."""
    assert mass_axis(top) == pytest.approx(expected)
    blueprint = default_blueprint(["layers/a"], summary_entity="summary", several_times=True, mass_top=top)
    plot = blueprint.root_container.contents[-1].contents[1]
    assert isinstance(plot, rrb.TimeSeriesView)
    got = plot.properties["ScalarAxis"].range.as_arrow_array().to_pylist()[0]
    assert got == pytest.approx(list(expected))


def test_maps_side_by_side_share_one_colour_range_and_say_so():
    colours = ColourRange.shared([(-10.0, -6.0, 1e-6), (-9.5, -6.5, 4e-7)])
    assert colours == ColourRange((-9.5, -6.0), 1e-6)  # the higher floor, the higher top
    blueprint = default_blueprint(["layers/a", "layers/b"], summary_entity="summary", colours=colours)
    for tabs, layer in zip(blueprint.root_container.contents[:2], "ab"):
        log10, density = tabs.contents[:2]
        for view, image, shown in ((log10, "log10_density", [-9.5, -6.0]), (density, "density", [0.0, 1e-6])):
            assert SHARED_NOTE in view.name
            override = view.visualizer_overrides[f"/layers/{layer}/{image}"]
            assert override.depth_range.as_arrow_array().to_pylist()[0] == pytest.approx(shown)
        # the shared bar in place of the map's own
        assert f"/layers/{layer}/{SHARED_LEGEND}/**" in str(log10.contents)
        assert f"/layers/{layer}/legend/**" not in str(log10.contents)
    one = default_blueprint(["layers/a"], summary_entity="summary", colours=colours)
    assert SHARED_NOTE not in one.root_container.contents[0].contents[0].name


GEO = """\
[scene]
name = "g"
times = [60.0, 150.0]

[geo]
origin_latlon = [60.45, 4.60]
time = "2026-11-24T05:40:00Z"

[grid]
x = [-1500.0, 1500.0]
y = [-200.0, 2000.0]
step = 20.0

[layers.a]
model = "cat"
v0 = 5.0
sigma_a = 0.01
sigma_omega_deg = 0.5

[layers.b]
model = "cat"
v0 = 6.0
sigma_a = 0.01
sigma_omega_deg = 0.5
"""


def test_a_geographic_scene_has_a_utc_timeline_and_one_shared_colour_bar(tmp_path):
    run_scene(parse_scene(GEO, source="g.toml"), tmp_path)
    path = tmp_path / "g.rrd"
    fix = datetime(2026, 11, 24, 5, 40, tzinfo=timezone.utc)
    for layer in "ab":
        batches = rows(path, f"/layers/{layer}/mass")
        utc = [v for b in batches for v in b.column(UTC).cast("int64").to_pylist()]
        assert utc == [utc_nanos(fix + timedelta(seconds=t)) for t in (60.0, 150.0)]
        assert utc_nanos(fix + timedelta(seconds=60.0)) == 1_795_498_860 * 10**9  # 2026-11-24T05:41:00Z (date -d)
        bar = rows(path, f"/layers/{layer}/{SHARED_LEGEND}/ticks")
        assert first(bar, "Points2D:labels")[-1] == SHARED_TITLE


@pytest.mark.parametrize("name", ["room_mixture", "room_uniform"])
def test_an_array_scene_draws_its_colour_scale_beside_the_cells(tmp_path, name):
    """rerun has no colour bar for a mesh: the cells' scale is a strip east of the room, coloured
    as the cells are (log10 p from the floor at its south end to the largest at its north end),
    with its decades labelled at their heights; the plane's labels (the scale's, the regions',
    the components') lie apart."""
    scene = load_scene(SCENES / f"{name}.toml")
    run_scene(scene, tmp_path)
    path = tmp_path / f"{name}.rrd"
    peak = first(rows(path, "/presence/summary"), "peak")
    lo, top = scene.log10_floor, math.log10(peak[0] if isinstance(peak, list) else peak)
    x0, x1, y0, y1 = plane_frame(scene.domain, scene.region, scene.far)
    strip = rows(path, "/presence/plane/colour_scale/strip")
    positions = np.array(first(strip, "Mesh3D:vertex_positions"))
    packed = np.array(first(strip, "Mesh3D:vertex_colors"), dtype=np.uint64)
    rgb = np.stack([(packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255], axis=1)
    assert positions[:, 0].min() > x1  # east of the room, beside it
    assert positions[:, 1].min() == pytest.approx(y0) and positions[:, 1].max() == pytest.approx(y1)
    np.testing.assert_allclose(positions[:, 2], -scene.domain.h)  # on the target plane
    expected = scale_colours(lo + (positions[:, 1] - y0) / (y1 - y0) * (top - lo), lo, top)
    np.testing.assert_array_equal(rgb, expected)
    ticks = rows(path, "/presence/plane/colour_scale/ticks")
    texts, spots = first(ticks, "Points3D:labels"), first(ticks, "Points3D:positions")
    decades = [t for t in texts if t.startswith("1e")]
    assert len(decades) >= 3  # the rooms' cells span 1e-12 to 1e-3 or 1e-4: most decades labelled
    for text, (_, y, _) in zip(texts, spots):
        if text.startswith("1e"):
            assert y == pytest.approx(y0 + (int(text[2:]) - lo) / (top - lo) * (y1 - y0), rel=1e-6)
    scale = PANEL_SLACK * max((x1 - x0) / PLANE_PANEL_POINTS[0], (y1 - y0) / PLANE_PANEL_POINTS[1])
    # the array hangs 1.8 m above the plane: its label is seen where its line of sight meets it
    array = seen_on_plane((0.0, 0.0, 0.0), (x0, x1, y0, y1), scene.domain.h)
    assert array[1] > 0.0  # north of its nadir, seen from the south
    labels = shown_labels(path, "/presence/plane") + [("array", array, "/presence/plane/array")]
    assert any(text.startswith("50 % · ") for text, _, _ in labels)
    assert_apart(labels, scale)


def test_a_comparison_shows_both_maps_in_one_colour_range(tmp_path):
    """``bananagrid compare`` puts the reference and the model side by side: one colour range,
    one shared colour bar under each, and the blueprint (sent last) names it."""
    from bananagrid.analysis.compare import compare
    from bananagrid.recording.compare import write_compare_recording

    grid = Grid.from_bounds(x=(-1500.0, 1500.0), y=(-1500.0, 1500.0), step=30.0)
    reference, model = elongated(grid, 200.0, 300.0), elongated(grid, 250.0, 280.0)
    path = tmp_path / "c.rrd"
    write_compare_recording(path, recording_id="c", scene_text="", names=("ref", "mod"), rasters=(reference, model),
                            comparison=compare(reference, model), levels=(1e-7, 1e-8))
    titles = [first(rows(path, f"/layers/{n}/{SHARED_LEGEND}/ticks"), "Points2D:labels")[-1] for n in ("ref", "mod")]
    assert titles == [SHARED_TITLE, SHARED_TITLE]
    ranges = [first(rows(path, f"/layers/{n}/{SHARED_LEGEND}/colour_bar"), "DepthImage:depth_range") for n in ("ref", "mod")]
    assert ranges[0] == ranges[1]
