r"""Recording an angular cell map (Pessentheiner): the lattice on the target, the
(azimuth, elevation) table, the room and the mixture's sigma ellipses.

Layout under one ``entity`` (default ``presence``); everything spatial is in world metres in
the array frame (x, y horizontal, z up, the array at the origin, the target plane at z = -h):

- ``entity/plane/cells``: the cells drawn on the plane z = -h (the frustum's mid-depth), a
  ``Mesh3D`` of triangulated cell polygons (each cell in azimuth pieces of at most
  ``MAX_PIECE_DEG`` so that chords stand for arcs), clipped to the room's (x, y) rectangle where
  a region is given, else cut at the radius ``far``; one flat colour per cell from
  :data:`VIRIDIS` on log10 of its probability p(C | S) between ``log10_floor`` and the largest.
  The line geometry (Section 4) draws its cells as coloured segments (``LineStrips3D``) of the
  line y = 0, z = -h (the paper's y = -h of the (x, y) plane is the world's z here).
- ``entity/plane/room``: the room outline, ``LineStrips3D`` (its box when a z range is given,
  else its rectangle on the target plane; the line's room is its x interval and z range).
- ``entity/plane/components``: each Gaussian component's (x, y) marginal 1-, 2- and 3-sigma
  ellipses on the target plane (line: its 1-, 2- and 3-sigma intervals), labelled.
- ``entity/plane/array``: the array, a point at the origin.
- ``entity/plane/colour_scale``: the cells' colour scale, which rerun does not draw for a mesh:
  a strip on the target plane east of the room (``strip``, a ``Mesh3D`` coloured as the cells
  are, from ``log10_floor`` at its south end to the largest at its north end) with a label at
  each whole decade and its title (``ticks``). It lies beside the cells, in the same view and
  perspective as they are, so it is read where the colours are (a separate panel would be
  compared across the screen).
- ``entity/plane/marks``: the labels of the components' ellipses and the regions, placed by one
  :class:`~bananagrid.recording.labels.LabelBoard` for the plane (none over another or over the
  colour scale's; one with no free spot is left off, its line keeps the text for hovering), with
  ``leaders`` to any moved off its point.
- ``entity/table``: the probabilities as a ``DepthImage`` (float32) with the azimuths along the
  columns and the elevations down the rows (row 0 the first elevation, e.g. the horizon, the
  last row the nadir), range (0, largest); the line geometry gives one row.
- ``entity/log10_table``: the same in log10, floored at ``log10_floor``.
- ``entity/summary``: ``AnyValues``: ``total`` (sum of p(C | S)), ``region_probability``
  (p(S)), ``largest_error`` (largest error estimate of a cell), ``cells``, ``peak`` (largest
  cell probability) and the flattened provenance without run-dependent values (timings,
  thread counts), so that two runs give equal recordings.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..domains.region import Region
from ..models.presence import GaussianMixture, UniformPresence
from ..results import CellMap
from ..validate import BananagridError, positive
from ..contours import DEFAULT_MASS_LEVELS, MassRegion, cell_regions
from .core import MASS_COLOURS, entity_path, flatten, strict
from .labels import LabelBoard, log_placed, place_all

__all__ = [
    "log_cell_map", "plane_frame", "seen_on_plane", "scale_colours", "PLANE_PANEL_POINTS", "TABLE_PANEL_POINTS", "presence_blueprint", "cell_colours", "table_image", "log10_probabilities", "summary_values",
    "cell_mesh", "VIRIDIS", "LOG10_FLOOR", "MAX_PIECE_DEG", "RUN_ONLY_PROVENANCE",
]

#: log10 of the smallest probability the colour scale shows (cells below it get its colour).
LOG10_FLOOR = -12.0
#: Cells are drawn in azimuth pieces of at most this many degrees: a chord then departs from
#: its arc by at most r (1 - cos 1 deg) = 1.5e-4 r.
MAX_PIECE_DEG = 2.0
#: viridis sampled at 0, 1/8, ..., 1 (matplotlib's table, rounded to 8 bits); the cells' colours
#: interpolate it linearly (rerun's colormaps are not exposed for meshes). The table images use
#: rerun's own viridis, so both views share one scale.
VIRIDIS = np.array([
    (68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 145, 140),
    (39, 173, 129), (92, 200, 99), (170, 220, 50), (253, 231, 37),
], dtype=float)
#: Provenance keys left out of the recording (they change from run to run).
RUN_ONLY_PROVENANCE = ("seconds", "threads")

#: The plane as seen in its 3D view (what a flat map panel of this size would show it as) and the
#: log10 table's view, in the array layout (:func:`presence_blueprint`) of the reference viewer
#: window (1100 x 680 points for the views). The 3D view is 660 points wide, but :func:`plane_eye`
#: stands back: room_mixture's 6 m x 5 m room measured 397 x 317 points on the screenshot (the
#: tilt shortens north-south), i.e. a panel of 397 x 317 times PANEL_SLACK.
PLANE_PANEL_POINTS = (456.0, 364.0)
TABLE_PANEL_POINTS = (440.0, 310.0)
#: Quads along the colour scale's strip.
SCALE_STEPS = 64

ROOM_COLOUR = (255, 255, 255)
ARRAY_COLOUR = (255, 60, 60)
SIGMA_COLOURS = {1: (255, 255, 255), 2: (255, 200, 0), 3: (255, 0, 255)}
OUTLINE_POINTS = 121


def cell_colours(prob: np.ndarray, log10_floor: float = LOG10_FLOOR) -> tuple[np.ndarray, tuple[float, float]]:
    """RGB (uint8) of each probability on the log10 viridis scale and that scale's range.

    The range is ``(log10_floor, log10(largest))`` (one decade above the floor when nothing
    exceeds it); probabilities at or below ``10**log10_floor``, zeros included, get the floor's
    colour.
    """
    logs = log10_probabilities(prob, log10_floor)
    top = float(np.max(logs, initial=log10_floor))
    top = top if top > log10_floor else log10_floor + 1.0
    return scale_colours(logs, log10_floor, top), (log10_floor, top)


def scale_colours(logs: np.ndarray, lo: float, top: float) -> np.ndarray:
    """RGB (uint8) of log10 values on the viridis scale from ``lo`` to ``top`` (clipped)."""
    s = np.clip((np.asarray(logs, dtype=float) - lo) / (top - lo), 0.0, 1.0) * (len(VIRIDIS) - 1)
    k = np.minimum(np.floor(s).astype(int), len(VIRIDIS) - 2)
    f = (s - k)[..., None]
    rgb = VIRIDIS[k] * (1.0 - f) + VIRIDIS[k + 1] * f
    return np.round(rgb).astype(np.uint8)


def table_image(values: np.ndarray) -> np.ndarray:
    """Per-cell values (``[azimuth, elevation]``, or ``[azimuth]`` for a line) as a float32
    image: columns azimuths, rows elevations (row 0 the first elevation); one row for a line."""
    v = np.asarray(values)
    image = v[None, :] if v.ndim == 1 else v.T
    return np.ascontiguousarray(image, dtype=np.float32)


def log10_probabilities(prob: np.ndarray, log10_floor: float = LOG10_FLOOR) -> np.ndarray:
    """log10 of each probability (float64), ``log10_floor`` at or below ``10**log10_floor``."""
    p = np.asarray(prob, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(p > 10.0**log10_floor, np.log10(np.where(p > 0, p, 1.0)), log10_floor)


def log_cell_map(
    rec: rr.RecordingStream,
    entity: str,
    cell_map: CellMap,
    presence: GaussianMixture | UniformPresence,
    region: Region | None = None,
    *,
    names=None,
    room_z: tuple[float, float] | None = None,
    far: float | None = None,
    log10_floor: float = LOG10_FLOOR,
    mass_levels=DEFAULT_MASS_LEVELS,
) -> list[MassRegion]:
    """Log a cell map, its room and its presence law under ``entity`` (see the module docstring).

    Parameters
    ----------
    rec : rerun.RecordingStream
    entity : str
        Root entity, e.g. ``"presence"``.
    cell_map : CellMap
        From :func:`bananagrid.cell_probabilities`.
    presence : GaussianMixture or UniformPresence
        The law the map was computed from (its components are drawn).
    region : Region, optional
        The room S the map is conditioned on (default ``cell_map.region``); the cells are
        clipped to its (x, y) rectangle (line: its x interval).
    names : sequence of str, optional
        Component names for the ellipse labels (default ``component 0``, ...).
    room_z : (float, float), optional
        The room's z range for the outline when the region has none (plane and line).
    far : float, optional
        m, > 0: radius at which cells are cut when there is no region (default 10 h).
    log10_floor : float
        Bottom of the colour scale (log10 of a probability), < 0.
    mass_levels : iterable of float
        Probability-mass levels in (0, 1): the highest-probability sets of cells holding them
        (:func:`bananagrid.contours.cell_regions`) are outlined on the plane and on the log10
        table, each labelled once (``"90 % · 412 cells"``).

    Returns
    -------
    list of MassRegion
        The regions outlined.
    """
    entity = entity_path(entity)
    if not isinstance(cell_map, CellMap):
        raise BananagridError(f"cell_map = {cell_map!r}: expected a bananagrid CellMap")
    if not hasattr(presence, "region_probability"):
        raise BananagridError(f"presence = {presence!r}: expected a GaussianMixture or a UniformPresence")
    if not (math.isfinite(log10_floor) and log10_floor < 0.0):
        raise BananagridError(f"log10_floor = {log10_floor!r}: must be finite and < 0")
    if not np.all(np.isfinite(cell_map.prob)):
        raise BananagridError("cell_map.prob contains NaN or inf; cannot record it")
    lattice = cell_map.lattice
    region = cell_map.region if region is None else region
    far = 10.0 * lattice.h if far is None else positive("far", far)
    n_comp = getattr(presence, "n_components", 0)  # a uniform law has none
    names = [f"component {i}" for i in range(n_comp)] if names is None else list(names)
    if len(names) != n_comp:
        raise BananagridError(f"names = {names!r}: expected {n_comp} names, one per component")
    colours, (lo, top) = cell_colours(cell_map.prob, log10_floor)
    plane = f"{entity}/plane"
    board = LabelBoard(plane_frame(lattice, region, far), PLANE_PANEL_POINTS)
    board.reserve(seen_on_plane((0.0, 0.0, 0.0), board.frame, lattice.h), "array")
    with strict():
        rec.log(f"{plane}/array", rr.Points3D([(0.0, 0.0, 0.0)], colors=ARRAY_COLOUR,
                                               radii=rr.Radius.ui_points(6.0), labels=["array"]), static=True)
        log_colour_scale(rec, f"{plane}/colour_scale", board, lo, top, -lattice.h)
        if lattice.geometry == "line":
            strips, strip_colours = _line_cells(lattice, region, far, colours)
            rec.log(f"{plane}/cells", rr.LineStrips3D(strips, colors=strip_colours, radii=rr.Radius.ui_points(4.0)))
        else:
            positions, triangles, vertex_colours = cell_mesh(lattice, region, far, colours)
            rec.log(f"{plane}/cells", rr.Mesh3D(vertex_positions=positions, triangle_indices=triangles,
                                                vertex_colors=vertex_colours))
        room = _room_strips(lattice, region, room_z)
        if room:
            rec.log(f"{plane}/room", rr.LineStrips3D(room, colors=ROOM_COLOUR, radii=rr.Radius.ui_points(1.5)))
        regions = cell_regions(cell_map.prob, mass_levels)
        _log_regions(rec, plane, f"{entity}/log10_table/regions", cell_map, regions, region, far, board)
        if n_comp:
            strips, strip_colours, labels = _component_strips(presence, lattice, names)
            rec.log(f"{plane}/components", rr.LineStrips3D(strips, colors=strip_colours, labels=labels,
                                                            radii=rr.Radius.ui_points(1.2), show_labels=False))
            # the widest ellipse of each component first: it has the most room for its label
            order = sorted(range(len(strips)), key=lambda k: -(k % 3))
            placed = place_all(board, [(labels[k], [np.asarray(strips[k], float)[:, :2]]) for k in order])
            log_placed(rec, f"{plane}/marks", placed, three_d_z=-lattice.h)
        peak = float(np.max(cell_map.prob))
        rec.log(f"{entity}/table", rr.DepthImage(table_image(cell_map.prob), meter=1.0, colormap="viridis",
                                                 depth_range=(0.0, peak if peak > 0.0 else 1.0)))
        rec.log(f"{entity}/log10_table", rr.DepthImage(table_image(log10_probabilities(cell_map.prob, log10_floor)),
                                                       meter=1.0, colormap="viridis", depth_range=(lo, top)))
        info = summary_values(cell_map)
        info.update(flatten("regions", {f"{100 * r.probability:g}": r.describe() for r in regions}))
        rec.log(f"{entity}/summary", rr.AnyValues(**info))
    return regions


def region_edges(inside: np.ndarray, wrap: bool) -> tuple[np.ndarray, np.ndarray]:
    """The cell edges between a set of cells and the rest, in lattice indices.

    Parameters
    ----------
    inside : ndarray of bool, shape (n_azimuth, n_elevation)
        The set (line geometry: one elevation column).
    wrap : bool
        Whether azimuth cell ``n_azimuth - 1`` borders cell 0 (a full turn).

    Returns
    -------
    radial : ndarray of int, shape (k, 2)
        ``(a, j)``: the edge at azimuth edge ``a`` (between azimuth cells ``a - 1`` and ``a``)
        along elevation cell ``j``.
    arcs : ndarray of int, shape (m, 2)
        ``(i, e)``: the edge at elevation edge ``e`` (between rings ``e - 1`` and ``e``) along
        azimuth cell ``i``.
    """
    inside = np.asarray(inside, dtype=bool)
    if wrap:
        across = inside != np.roll(inside, 1, axis=0)  # row a: cells a - 1 and a
    else:
        padded = np.pad(inside, ((1, 1), (0, 0)))
        across = padded[1:] != padded[:-1]  # rows 0 .. n: edges 0 .. n
    padded = np.pad(inside, ((0, 0), (1, 1)))
    rings = padded[:, 1:] != padded[:, :-1]  # columns 0 .. n_el: edges 0 .. n_el
    return np.argwhere(across), np.argwhere(rings)


def _log_regions(rec, plane: str, table: str, cell_map: CellMap, regions, region, far: float, board: LabelBoard) -> None:
    """Outline each probability-mass region of cells on the plane (``plane/regions``) and on
    the log10 table (``table``), one colour per level, one label per level (placed on the
    plane's ``board``, and on the table's own)."""
    lattice = cell_map.lattice
    prob = np.asarray(cell_map.prob, dtype=float)
    grid_prob = prob[:, None] if prob.ndim == 1 else prob
    phi = lattice.azimuth_edges
    wrap = lattice.geometry != "line" and abs(phi[-1] - phi[0] - 2.0 * math.pi) < 1e-9
    on_plane, on_table, texts = {}, {}, {}
    for region_k in (r for r in regions if r.reached):
        radial, arcs = region_edges(grid_prob >= region_k.density, wrap)
        key = region_k.probability
        texts[key] = f"{100 * key:g} % · {region_k.cells:,} cells"
        on_table[key] = [np.array([(a, j), (a, j + 1)], float) for a, j in radial] + \
                        [np.array([(i, e), (i + 1, e)], float) for i, e in arcs]
        if lattice.geometry == "line":
            on_plane[key] = _line_runs(lattice, region, far, grid_prob[:, 0] >= region_k.density, len(on_plane))
        else:
            on_plane[key] = _plane_edges(lattice, region, far, radial, arcs)
    colours = {key: MASS_COLOURS[k % len(MASS_COLOURS)] for k, key in enumerate(texts)}
    spots = {}
    for key, pieces in on_plane.items():
        spot = board.place_on_line(texts[key], pieces) if pieces else None
        if spot is not None:
            spots[key] = spot
    rec.log(f"{plane}/regions/lines", rr.LineStrips3D(
        [np.column_stack([piece, np.full(len(piece), -lattice.h)]) for key in on_plane for piece in on_plane[key]],
        colors=[colours[key] for key in on_plane for _ in on_plane[key]], radii=rr.Radius.ui_points(1.5)))
    rec.log(f"{plane}/regions/labels", rr.Points3D(
        [(x, y, -lattice.h) for x, y in spots.values()], labels=[texts[key] for key in spots],
        colors=[(255, 255, 255)] * len(spots), radii=rr.Radius.ui_points(2.5), show_labels=True))
    n_az, n_el = grid_prob.shape
    table_board = LabelBoard((0.0, float(n_az), 0.0, float(n_el)), TABLE_PANEL_POINTS, y_down=True)
    table_spots = {}
    for key, pieces in on_table.items():
        spot = table_board.place_on_line(texts[key], pieces) if pieces else None
        if spot is not None:
            table_spots[key] = spot
    rec.log(f"{table}/lines", rr.LineStrips2D(
        [piece for key in on_table for piece in on_table[key]],
        colors=[colours[key] for key in on_table for _ in on_table[key]], radii=rr.Radius.ui_points(1.0),
        draw_order=30.0))
    rec.log(f"{table}/labels", rr.Points2D(
        list(table_spots.values()), labels=[texts[key] for key in table_spots],
        colors=[(255, 255, 255)] * len(table_spots), radii=rr.Radius.ui_points(2.0), show_labels=True,
        draw_order=31.0))


def _plane_edges(lattice, region, far: float, radial: np.ndarray, arcs: np.ndarray) -> list[np.ndarray]:
    """The region edges of :func:`region_edges` on the plane z = -h as (n, 2) polylines: radial
    edges from a ring's inner to its outer radius, arcs in pieces of at most MAX_PIECE_DEG; cut
    at ``far`` (the horizon ring reaches infinity) and clipped to the room's rectangle."""
    phi = lattice.azimuth_edges
    inner, outer = lattice.radii()
    edges_r = lattice.h * lattice.tau_edges
    rect = None if region is None else np.asarray(region.bounds[:2], dtype=float)
    cap = far if rect is None else 2.0 * float(np.hypot(*np.abs(rect).max(axis=1))) + lattice.h
    pieces = []
    for a, j in radial:
        r0, r1 = inner[j], min(outer[j], cap)
        if r1 > r0:
            angle = phi[a % len(phi)]
            pieces.append(np.array([(r0 * math.cos(angle), r0 * math.sin(angle)), (r1 * math.cos(angle), r1 * math.sin(angle))]))
    for i, e in arcs:
        radius = min(edges_r[e], cap)
        if radius > 0.0:
            n = max(1, math.ceil(math.degrees(phi[i + 1] - phi[i]) / MAX_PIECE_DEG - 1e-9))
            angles = np.linspace(phi[i], phi[i + 1], n + 1)
            pieces.append(np.column_stack([radius * np.cos(angles), radius * np.sin(angles)]))
    if rect is None:
        return pieces
    return [clipped for piece in pieces for clipped in _clip_polyline(piece, rect)]


def _line_runs(lattice, region, far: float, inside: np.ndarray, k: int) -> list[np.ndarray]:
    """A line region's runs of cells as segments beside the line (y = -0.15 (k + 1) h for the
    k-th level, so nested levels stay apart), clipped to the room's x interval (or +-far)."""
    x = lattice.line_edges()
    lo, hi = (region.x if region is not None else (-far, far))
    padded = np.concatenate([[False], inside, [False]])
    starts = np.flatnonzero(~padded[:-1] & padded[1:])
    ends = np.flatnonzero(padded[:-1] & ~padded[1:])
    y = -0.15 * (k + 1) * lattice.h
    out = []
    for a, b in zip(starts, ends):
        x0, x1 = float(np.clip(x[a], lo, hi)), float(np.clip(x[b], lo, hi))
        if x1 > x0:
            out.append(np.array([(x0, y), (x1, y)]))
    return out


def _clip_polyline(line: np.ndarray, rect: np.ndarray) -> list[np.ndarray]:
    """The parts of a polyline inside the rectangle ``rect`` (rows x, y of (low, high)),
    segment by segment (Liang-Barsky)."""
    out, current = [], []
    for p, q in zip(line[:-1], line[1:]):
        d = q - p
        t0, t1 = 0.0, 1.0
        keep = True
        for axis in (0, 1):
            for bound, sign in ((rect[axis, 0], -1.0), (rect[axis, 1], 1.0)):
                num, den = sign * (bound - p[axis]), sign * d[axis]
                if den == 0.0:
                    if num < 0.0:
                        keep = False
                elif den > 0.0:
                    t1 = min(t1, num / den)
                else:
                    t0 = max(t0, num / den)
        if not keep or t0 > t1:
            if len(current) > 1:
                out.append(np.array(current))
            current = []
            continue
        a, b = p + t0 * d, p + t1 * d
        if not current or np.any(current[-1] != a):
            if len(current) > 1:
                out.append(np.array(current))
            current = [a]
        current.append(b)
    if len(current) > 1:
        out.append(np.array(current))
    return out


def summary_values(cell_map: CellMap) -> dict:
    """The numbers logged at ``entity/summary`` (see the module docstring)."""
    err = cell_map.error if cell_map.error is not None else np.zeros_like(cell_map.prob)
    kept = {k: v for k, v in cell_map.provenance.items() if k not in RUN_ONLY_PROVENANCE}
    info = {
        "total": float(np.sum(cell_map.prob)), "region_probability": float(cell_map.region_probability),
        "largest_error": float(np.max(err, initial=0.0)), "cells": float(cell_map.prob.size),
        "peak": float(np.max(cell_map.prob)),
        "region": None if cell_map.region is None else cell_map.region.describe(),
        "provenance": kept,
    }
    return dict(flatten("", info))


def plane_frame(lattice, region, far: float | None) -> tuple[float, float, float, float]:
    """What the plane's view frames (x0, x1, y0, y1, m): the room's rectangle, else a square of
    half-side ``far`` (default 10 h) about the array (a line's room: its x interval, and a
    quarter of it each side of the line)."""
    if region is not None:
        bounds = region.bounds
        x0, x1 = bounds[0]
        y0, y1 = bounds[1] if len(bounds) > 1 else (-0.25 * (x1 - x0), 0.25 * (x1 - x0))  # a line's room: x only
        return float(x0), float(x1), float(y0), float(y1)
    reach = 10.0 * lattice.h if far is None else far
    return -reach, reach, -reach, reach


def _scale_strip(frame: tuple[float, float, float, float]) -> tuple[float, float]:
    """The colour scale's strip east of ``frame``: its west edge and width (m)."""
    x0, x1, y0, y1 = frame
    size = max(x1 - x0, y1 - y0)
    return x1 + 0.05 * size, 0.04 * size


def log_colour_scale(rec: rr.RecordingStream, path: str, board: LabelBoard, lo: float, top: float, z: float) -> None:
    """The cells' colour scale east of ``board``'s frame on the plane at height ``z``: a strip
    coloured as :func:`cell_colours` colours the cells, log10 ``lo`` (south end) to ``top``
    (north end), a label at each whole decade (one that would overlap another is left off) and
    the title; the labels held on ``board``."""
    x0, x1, y0, y1 = board.frame
    west, width = _scale_strip(board.frame)
    ys = np.linspace(y0, y1, SCALE_STEPS + 1)
    rgb = scale_colours(np.linspace(lo, top, SCALE_STEPS + 1), lo, top)
    positions = np.array([(x, y, z) for y in ys for x in (west, west + width)], dtype=np.float32)
    k = 2 * np.arange(SCALE_STEPS)[:, None]
    triangles = np.concatenate([np.hstack([k, k + 1, k + 3]), np.hstack([k, k + 3, k + 2])]).astype(np.uint32)
    rec.log(f"{path}/strip", rr.Mesh3D(vertex_positions=positions, triangle_indices=triangles,
                                       vertex_colors=np.repeat(rgb, 2, axis=0)))
    title = "log10 p(C | S)"
    title_at = (west + 0.5 * width, y1 + 0.06 * (y1 - y0))
    board.reserve(title_at, title)
    decades = np.arange(math.ceil(lo), math.floor(top) + 1)
    ticks, texts = [], []
    for d in decades:
        at = (west + width, y0 + (d - lo) / (top - lo) * (y1 - y0))
        text = f"1e{int(d)}"
        if board.place(text, np.array([at]), inside=False) is not None:
            ticks.append(at)
            texts.append(text)
    rec.log(f"{path}/ticks", rr.Points3D([(x, y, z) for x, y in [*ticks, title_at]], labels=[*texts, title],
                                         colors=[(255, 255, 255)] * (len(ticks) + 1), radii=rr.Radius.ui_points(1.5),
                                         show_labels=True))


def plane_eye(lattice, region, far: float | None) -> rrb.EyeControls3D:
    """A camera looking down on the target plane from above and a little south, so the cells,
    the room and the labels are seen nearly as on a map (north up). It frames the room's
    rectangle, else a disc of radius ``far`` (default 10 h) around the array
    (:func:`plane_frame`), and the colour scale east of it."""
    position, target = _eye(plane_frame(lattice, region, far), lattice.h)
    return rrb.EyeControls3D(position=position, look_target=target, eye_up=(0.0, 0.0, 1.0))


def _eye(frame: tuple[float, float, float, float], h: float) -> tuple[tuple, tuple]:
    """:func:`plane_eye`'s camera position and target for the plane's ``frame`` at z = -h."""
    x0, x1, y0, y1 = frame
    west, width = _scale_strip(frame)
    x1 = west + 2.0 * width  # the strip and its labels
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    size = max(x1 - x0, y1 - y0)
    return (cx, cy - 0.3 * size, -h + 1.5 * size), (cx, cy, -h)


def seen_on_plane(point, frame: tuple[float, float, float, float], h: float) -> tuple[float, float]:
    """Where ``point`` (x, y, z) appears on the plane z = -h from :func:`plane_eye`'s camera: the
    plane's point on the same line of sight (the array, 1.8 m above the plane, appears north of
    its nadir), so that its label is kept apart from the plane's as they are seen."""
    (ex, ey, ez), _ = _eye(frame, h)
    t = (ez + h) / (ez - point[2])
    return ex + t * (point[0] - ex), ey + t * (point[1] - ey)


def presence_blueprint(entity: str = "presence", scene_entity: str = "scene", *,
                       eye: rrb.EyeControls3D | None = None) -> rrb.Blueprint:
    """The target plane in 3D (seen from ``eye``, see :func:`plane_eye`) beside the log10 and
    linear tables, the numbers and the scene."""
    entity = entity_path(entity)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=f"/{entity}/plane", name="cells on the target", eye_controls=eye),
            rrb.Vertical(
                rrb.Tabs(
                    rrb.Spatial2DView(origin=f"/{entity}/log10_table", name="log10 p (azimuth across, elevation down)"),
                    rrb.Spatial2DView(origin=f"/{entity}/table", name="p (azimuth across, elevation down)"),
                ),
                rrb.Tabs(
                    rrb.TextDocumentView(origin=f"/{entity_path(scene_entity)}", name="scene"),
                    rrb.DataframeView(origin=f"/{entity}/summary", name="numbers"),
                ),
                row_shares=[1, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=False,
    )


# --- geometry ---------------------------------------------------------------------------------


def cell_mesh(lattice, region, far: float, colours: np.ndarray):
    """``(positions (n, 3) float32, triangles (m, 3) uint32, colours (n, 3) uint8)`` of the
    cells on the plane z = -h: each cell in azimuth pieces of at most MAX_PIECE_DEG, each piece
    the quadrilateral of its inner and outer radius (cut at ``far``), clipped to the region's
    (x, y) rectangle if given, fan-triangulated, all vertices of a cell in its colour."""
    inner, outer = lattice.radii()
    phi = lattice.azimuth_edges
    rect = None if region is None else np.asarray(region.bounds[:2], dtype=float)
    if rect is not None:
        corners = np.hypot(rect[0][[0, 1, 0, 1]], rect[1][[0, 0, 1, 1]])
        far = 2.0 * float(corners.max()) + lattice.h  # beyond the room: the clip decides
    outer = np.minimum(outer, far)
    rings = np.nonzero(inner < outer)[0]
    # azimuth pieces: (piece start, piece end, owning azimuth index)
    widths = np.degrees(np.diff(phi))
    n_piece = np.maximum(1, np.ceil(widths / MAX_PIECE_DEG - 1e-9).astype(int))
    owner = np.repeat(np.arange(lattice.n_azimuth), n_piece)
    frac = np.concatenate([np.arange(n) / n for n in n_piece])
    step = np.diff(phi)[owner] / n_piece[owner]
    a0 = phi[owner] + frac * np.diff(phi)[owner]
    a1 = a0 + step
    # quads (pieces x rings, 4 corners, xy), counter-clockwise seen from above
    r0, r1 = inner[rings][None, :], outer[rings][None, :]
    c0, s0, c1, s1 = (f(a)[:, None] for f, a in ((np.cos, a0), (np.sin, a0), (np.cos, a1), (np.sin, a1)))
    quads = np.stack([np.stack([r0 * c0, r0 * s0], -1), np.stack([r0 * c1, r0 * s1], -1),
                      np.stack([r1 * c1, r1 * s1], -1), np.stack([r1 * c0, r1 * s0], -1)], axis=2)
    quad_colours = colours[owner[:, None], rings[None, :]]
    quads = quads.reshape(-1, 4, 2)
    quad_colours = quad_colours.reshape(-1, 3)
    polys, poly_colours = [], []
    if rect is None:
        inside = np.ones(len(quads), bool)
    else:
        lo, hi = quads.min(axis=1), quads.max(axis=1)
        outside = (hi[:, 0] < rect[0, 0]) | (lo[:, 0] > rect[0, 1]) | (hi[:, 1] < rect[1, 0]) | (lo[:, 1] > rect[1, 1])
        inside = (lo[:, 0] >= rect[0, 0]) & (hi[:, 0] <= rect[0, 1]) & (lo[:, 1] >= rect[1, 0]) & (hi[:, 1] <= rect[1, 1])
        for q in np.nonzero(~inside & ~outside)[0]:
            poly = _dedupe(_clip(quads[q], rect))
            if len(poly) >= 3:
                polys.append(poly)
                poly_colours.append(quad_colours[q])
    n_in = int(inside.sum())
    xy = [quads[inside].reshape(-1, 2)] + polys
    sizes = [4] * n_in + [len(p) for p in polys]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    triangles = [np.stack([starts[:n_in], starts[:n_in] + k, starts[:n_in] + k + 1], axis=1) for k in (1, 2)]
    for start, n in zip(starts[n_in:], sizes[n_in:]):
        triangles.append(start + np.stack([np.zeros(n - 2, int), np.arange(1, n - 1), np.arange(2, n)], axis=1))
    vcols = [np.repeat(quad_colours[inside], 4, axis=0)] + [np.broadcast_to(c, (n, 3)) for c, n in zip(poly_colours, sizes[n_in:])]
    xy = np.concatenate(xy)
    pos = np.column_stack([xy, np.full(len(xy), -lattice.h)]).astype(np.float32)
    return (pos, np.concatenate(triangles).reshape(-1, 3).astype(np.uint32),
            np.concatenate(vcols).reshape(-1, 3).astype(np.uint8))


def _clip(poly: np.ndarray, rect: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the convex polygon ``poly`` (k, 2) within the rectangle ``rect``
    (rows x, y of (low, high)); an empty (0, 2) array where they do not meet."""
    inside = ((poly[:, 0] >= rect[0, 0]) & (poly[:, 0] <= rect[0, 1])
              & (poly[:, 1] >= rect[1, 0]) & (poly[:, 1] <= rect[1, 1]))
    if inside.all():
        return poly
    pts = list(poly)
    for axis, bound, sign in ((0, rect[0, 0], 1.0), (0, rect[0, 1], -1.0), (1, rect[1, 0], 1.0), (1, rect[1, 1], -1.0)):
        if not pts:
            break
        out = []
        for a, b in zip(pts, pts[1:] + pts[:1]):
            da, db = sign * (a[axis] - bound), sign * (b[axis] - bound)
            if da >= 0.0:
                out.append(a)
            if (da >= 0.0) != (db >= 0.0):
                t = da / (da - db)
                out.append(a + t * (b - a))
        pts = out
    return np.array(pts).reshape(-1, 2)


def _dedupe(poly: np.ndarray) -> np.ndarray:
    """Drop consecutive repeated vertices (the nadir ring's inner radius is 0)."""
    if len(poly) == 0:
        return poly
    nxt = np.roll(poly, -1, axis=0)
    keep = np.any(np.abs(poly - nxt) > 1e-12 * (1.0 + np.abs(poly)), axis=1)
    return poly[keep]


def _line_cells(lattice, region, far: float, colours: np.ndarray):
    """Segments of the line cells (x, 0, -h), clipped to the region's x interval (or +-far)."""
    x = lattice.line_edges()
    lo, hi = (region.x if region is not None else (-far, far))
    x = np.clip(x, lo, hi)
    strips, cols = [], []
    for i in range(lattice.n_azimuth):
        if x[i + 1] > x[i]:
            strips.append([(x[i], 0.0, -lattice.h), (x[i + 1], 0.0, -lattice.h)])
            cols.append(colours[i])
    return strips, np.array(cols, dtype=np.uint8).reshape(-1, 3)


def _room_strips(lattice, region, room_z):
    """The room outline: box edges with a z range, else its rectangle (segment) at z = -h."""
    if region is None:
        return []
    z = region.z if region.z is not None else room_z
    h = lattice.h
    if lattice.geometry == "line":
        x0, x1 = region.x
        if z is None:
            return [[(x0, 0.0, -h), (x1, 0.0, -h)]]
        return [[(x0, 0.0, z[0]), (x1, 0.0, z[0]), (x1, 0.0, z[1]), (x0, 0.0, z[1]), (x0, 0.0, z[0])]]
    (x0, x1), (y0, y1) = region.x, region.y
    ring = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
    if z is None:
        return [[(x, y, -h) for x, y in ring]]
    strips = [[(x, y, z[0]) for x, y in ring], [(x, y, z[1]) for x, y in ring]]
    strips += [[(x, y, z[0]), (x, y, z[1])] for x, y in ring[:4]]
    return strips


def _component_strips(mixture: GaussianMixture, lattice, names):
    """Each component's 1-, 2-, 3-sigma (x, y) marginal ellipses at z = -h (line: intervals of
    x, each k drawn 0.02 k m below the line so that they do not overlap)."""
    strips, cols, labels = [], [], []
    angle = np.linspace(0.0, 2.0 * math.pi, OUTLINE_POINTS)
    circle = np.column_stack([np.cos(angle), np.sin(angle)])
    h = lattice.h
    for name, mu, cov in zip(names, mixture.means, mixture.covs):
        if mixture.dim == 1:
            sd = math.sqrt(cov[0, 0])
            for k in (1, 2, 3):
                strips.append([(mu[0] - k * sd, 0.0, -h - 0.02 * k), (mu[0] + k * sd, 0.0, -h - 0.02 * k)])
                cols.append(SIGMA_COLOURS[k])
                labels.append(f"{name} {k} sigma")
            continue
        values, vectors = np.linalg.eigh(cov[:2, :2])
        for k in (1, 2, 3):
            xy = mu[:2] + (circle * (k * np.sqrt(values))) @ vectors.T
            strips.append(np.column_stack([xy, np.full(len(xy), -h)]))
            cols.append(SIGMA_COLOURS[k])
            labels.append(f"{name} {k} sigma")
    return strips, np.array(cols, dtype=np.uint8), labels
