"""Where a map's labels go: no label over another, each on its own line or beside its point, all
inside the view that opens on the map, for the geometry a fix or a Butterly start draws about one
point (the case where rerun's own placement piles them up).

Boxes are sized here as rerun draws them, from the measured text metrics
(:mod:`bananagrid.recording.labels`: a label centred under its point, 17.5 points high and
6.5 points a character wide, measured on the viewer's screenshots), and turned into metres by the
map's frame and panel, independently of the board's own bookkeeping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader

import bananagrid as bg
from bananagrid import Grid, Raster
from bananagrid.recording import bearing, butterly
from bananagrid.recording.blueprint import map_panel_points, view_bounds
from bananagrid.recording.labels import PANEL_SLACK, LabelBoard, leader
from bananagrid.recording.raster import log_raster_layer
from bananagrid.recording.stream import write_recording
from label_boxes import assert_apart, box, hidden_only_on_hover, shown_labels


def gaussian_about(grid: Grid, mean, cov) -> Raster:
    """A bivariate normal density (m^-2) at ``grid``'s cell centres."""
    x, y = np.meshgrid(grid.x, grid.y)
    d = np.stack([x - mean[0], y - mean[1]], axis=-1)
    inv = np.linalg.inv(cov)
    q = np.einsum("...i,ij,...j->...", d, inv, d)
    values = np.exp(-0.5 * q) / (2.0 * math.pi * math.sqrt(np.linalg.det(cov)))
    return Raster(values=values, grid=grid, mass=float(values.sum() * grid.cell_area), provenance={"model": "test"})


def assert_within(extent, bounds, what: str) -> None:
    x0, x1, y0, y1 = extent
    bx0, bx1, by0, by1 = bounds
    assert bx0 <= x0 and x1 <= bx1 and by0 <= y0 and y1 <= by1, f"{what} {extent} outside the view {bounds}"


def strip_extent(path, entity: str):
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity:
            strips = chunk.to_record_batch().column("LineStrips2D:strips")[0].as_py()
            points = np.concatenate([np.array(s) for s in strips])
            return points[:, 0].min(), points[:, 0].max(), points[:, 1].min(), points[:, 1].max()
    raise AssertionError(f"{entity} not logged")


def record_layer(tmp_path, raster, model, extras, panel):
    """Log ``raster`` as a layer framed to hold ``extras.layer_extent(model)`` and the extras'
    geometry on the same label board, as a scene run does; returns (path, logged)."""
    got = {}

    def build(rec):
        logged = log_raster_layer(rec, "layers/m", raster, include=extras.layer_extent(model), panel=panel)
        extras.log_layer_extras(rec, "layers/m", model, raster, compute=lambda other: raster, board=logged.board)
        got["logged"] = logged

    path = write_recording(tmp_path / "m.rrd", build, recording_id="m")
    return path, got["logged"]


def check_map(path, logged, panel) -> list:
    """The map's labels apart, inside its view, and each shown only by a placed entity."""
    frame = logged.frame
    scale = PANEL_SLACK * max((frame[1] - frame[0]) / panel[0], (frame[3] - frame[2]) / panel[1])
    labels = shown_labels(path, "/layers/m")
    assert_apart(labels, scale)
    bounds = view_bounds(frame, panel)
    for text, anchor, entity in labels:
        if entity.endswith("geometry/labels") and text.startswith("sensor"):
            continue  # a station is often far beyond the map: a zoom-out away (and apart, checked above)
        assert_within(box(anchor, text, scale), bounds, f"label {text!r}")
    hidden_only_on_hover(path, "/layers/m", ("/labels", "/ticks", "/scale"))
    return labels


#: Fix geometries: stations' offsets from the target (m), bearing errors (deg), panel (maps).
@seed(20261127)
@settings(max_examples=12, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
          phases=[Phase.explicit, Phase.generate])
@given(range_km=st.floats(5.0, 40.0), crossing_deg=st.floats(35.0, 145.0), sigma_deg=st.floats(0.3, 3.0),
       ratio=st.floats(0.5, 2.0), n_maps=st.integers(1, 5))
def test_a_fixs_labels_are_apart_and_inside_the_view(tmp_path, range_km, crossing_deg, sigma_deg, ratio, n_maps):
    """Nested circles and an ellipse about one fix, the probability contours about it and the
    legend: every label apart and inside the view, whatever the geometry and the layout."""
    target = np.array([0.0, 1000.0 * range_km])
    half = math.radians(crossing_deg) / 2.0
    sensors = [target + 1000.0 * range_km * np.array([math.sin(a), -math.cos(a)]) for a in (-half, half)]
    bearings = [math.atan2(*(target - s)) for s in sensors]
    fix = bg.BearingFix(sensors=sensors, bearings=bearings,
                        sigmas=[math.radians(sigma_deg), math.radians(sigma_deg * ratio)])
    r95 = float(fix.radius([0.95])[0])
    grid = Grid.from_bounds(x=(fix.fix[0] - 2.5 * r95, fix.fix[0] + 2.5 * r95),
                            y=(fix.fix[1] - 2.5 * r95, fix.fix[1] + 2.5 * r95), step=r95 / 25.0)
    panel = map_panel_points(n_maps)
    path, logged = record_layer(tmp_path, gaussian_about(grid, fix.fix, fix.covariance), fix, bearing, panel)
    labels = check_map(path, logged, panel)
    bounds = view_bounds(logged.frame, panel)
    assert_within(strip_extent(path, "/layers/m/geometry/circles"), bounds, "R50 and R95")
    assert_within(strip_extent(path, "/layers/m/geometry/ellipse"), bounds, "the ellipse")
    assert "fix" in [text for text, _, _ in labels]  # placed first: never dropped


@pytest.mark.parametrize("sigma", [20.0, 300.0, 1500.0])
def test_a_butterly_starts_labels_are_apart_and_inside_the_view(tmp_path, sigma):
    """A start mean and its sigma ellipses (small beside the density, or as large as it), the
    rings and the contours: apart and inside the view; the start mean is labelled."""
    model = bg.Butterly(mean=(0.0, 0.0), cov=[[sigma**2, 0.3 * sigma**2], [0.3 * sigma**2, 0.6 * sigma**2]],
                        speeds=[4.0, 5.0, 6.0], weights=[0.25, 0.5, 0.25], t=300.0)
    grid = Grid.from_bounds(x=(-3000.0, 3000.0), y=(-3000.0, 3000.0), step=50.0)
    panel = map_panel_points(3)
    raster = gaussian_about(grid, (0.0, -400.0), np.array([[600.0**2, 0.0], [0.0, 400.0**2]]) + model.cov)
    path, logged = record_layer(tmp_path, raster, model, butterly, panel)
    labels = check_map(path, logged, panel)
    assert "start mean" in [text for text, _, _ in labels]
    assert_within(strip_extent(path, "/layers/m/geometry/ellipses"), view_bounds(logged.frame, panel), "the ellipses")


def test_a_label_with_no_free_spot_is_dropped_not_drawn_over_another():
    board = LabelBoard((0.0, 100.0, 0.0, 100.0), (300.0, 300.0))
    assert board.place("first label", np.array([[50.0, 50.0]])) == (50.0, 50.0)
    assert board.place("second label", np.array([[50.0, 50.0], [52.0, 49.0]])) is None
    assert board.dropped == ["second label"]
    # outside the frame: refused too (the legend's labels pass inside=False)
    assert board.place("edge", np.array([[99.9, 50.0]])) is None
    assert board.place("edge", np.array([[99.9, 50.0]]), inside=False) == (99.9, 50.0)


def test_a_point_label_moved_off_its_point_gets_a_leader():
    board = LabelBoard((0.0, 100.0, 0.0, 100.0), (300.0, 300.0))
    board.reserve((50.0, 50.0), "taken")
    spot = board.place_at_point("mine", (50.0, 50.0))
    assert spot is not None and spot != (50.0, 50.0)
    line = leader((50.0, 50.0), spot)
    np.testing.assert_array_equal(line, [[50.0, 50.0], list(spot)])
    assert leader((1.0, 2.0), (1.0, 2.0)) is None
