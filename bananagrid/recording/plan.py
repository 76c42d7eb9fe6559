"""A search plan in a recording: where to look next on one layer's map at one time.

Under ``plan`` (north up, world metres):

- ``plan/probability``: the map's cell probabilities (the map searched); ``plan/coverage``: the
  coverage (m^2 swept per m^2), both as numbers (read back by ``bananagrid inspect``);
- ``plan/overlay``: the two in one picture, the coverage's colour (yellow to red) over the
  probability's grey, grey alone where no effort goes (:func:`overlay_image`);
- ``plan/rectangles`` and ``plan/bands``: the areas' outlines, ``.../tracks``: the sweep legs,
  ``.../labels``: each area's name (as in the summary) and POD;
- ``plan/pos_curve/ideal``: the ideal POS against the total effort (km^2), the curve a planner
  reads to decide how much to send, and ``plan/pos_curve/this_plan``: the plan's own effort;
- ``plan/summary``: a markdown summary (POS, ideal POS, effort, marginal gain, each area), and
  ``plan/values``: the same numbers as ``AnyValues`` (what ``bananagrid inspect`` reports,
  :func:`plan_values`).

A plan over several periods logs the above once per period at the period's time (its map is
the target the other periods miss, its POS curve what more effort in it would add), and under
``plan/periods`` (:func:`log_plan_periods`): ``pos_by_sweep``, the total POS after each update
of the iteration; ``first_detection``, each period's probability of first detecting the
target; ``summary`` and ``values`` (:func:`periods_values`'s flat numbers).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..results import Raster
from .blueprint import HOVER_NOTE
from .entities import entity_path, strict
from .images import image_from_values, log_north_up, pixel_to_world

__all__ = ["PLAN_ENTITY", "PERIODS_ENTITY", "POS_CURVE_POINTS", "POS_CURVE_SPAN", "POS_CURVE_STEPS", "log_plan",
           "plan_values", "plan_markdown", "plan_view", "plan_extent", "pos_curve_efforts", "overlay_image",
           "periods_values", "periods_markdown", "log_plan_periods"]

#: Where a scene's plan is recorded.
PLAN_ENTITY = "plan"
#: Where a plan over several periods records its totals, under :data:`PLAN_ENTITY`.
PERIODS_ENTITY = "periods"
#: The recorded POS curve: from no effort to :data:`POS_CURVE_SPAN` times the plan's, in steps
#: of the plan's effort over :data:`POS_CURVE_STEPS`.
POS_CURVE_SPAN = 3
POS_CURVE_STEPS = 15
POS_CURVE_POINTS = POS_CURVE_SPAN * POS_CURVE_STEPS + 1
#: Weight of the coverage's colour over the grey probability map: enough to read both.
OVERLAY_ALPHA = 0.65
#: Outline colours: rectangles cyan, bands magenta (both stand out on grey and on the
#: yellow-to-red coverage); tracks white.
RECTANGLE_COLOUR = (0, 220, 255)
BAND_COLOUR = (255, 80, 255)
TRACK_COLOUR = (255, 255, 255)


def pos_curve_efforts(effort: float) -> np.ndarray:
    """The total efforts (m^2) at which the POS curve is recorded: 0 to ``POS_CURVE_SPAN`` times
    ``effort`` in steps of ``effort / POS_CURVE_STEPS`` (so the plan's own effort is one of
    them, exactly)."""
    return effort * (np.arange(POS_CURVE_POINTS) / POS_CURVE_STEPS)


def plan_values(allocation, rectangles=None, bands=None, *, layer: str = "", t: float = 0.0) -> dict:
    """The plan's numbers, flat (``AnyValues`` and the summaries): ``layer``, ``t`` (s),
    ``law``, ``effort_m2``, ``pos`` (the ideal allocation's), ``marginal_gain`` (POS per m^2),
    ``map_mass`` (the map's probability: the POS of searching it perfectly), and per kind of
    areas (``rectangles``, ``bands``) its ``*_pos``, ``*_effort_m2``, ``sweep_width_m`` and
    lists, one item per area: ``*_probability``, ``*_pod``, ``*_track_spacing_m``."""
    values = {
        "layer": layer, "t": float(t), "law": allocation.law.name, "effort_m2": float(allocation.total_effort),
        "pos": float(allocation.pos), "marginal_gain": float(allocation.marginal_gain),
        "map_mass": float(np.sum(allocation.cells)),
    }
    for name, plan, items in (("rectangles", rectangles, "rectangles"), ("bands", bands, "regions")):
        if plan is None:
            continue
        areas = [a for a in getattr(plan, items) if a.coverage > 0.0]
        values["sweep_width_m"] = float(plan.sweep_width)
        values[f"{name}_pos"] = float(plan.pos)
        values[f"{name}_effort_m2"] = float(plan.effort)
        values[f"{name}_probability"] = [float(a.probability) for a in areas]
        values[f"{name}_pod"] = [float(a.pod) for a in areas]
        values[f"{name}_track_spacing_m"] = [float(a.track_spacing) for a in areas]
    return values


def plan_markdown(values: dict) -> str:
    """:func:`plan_values` as the plan's markdown summary."""
    head = f"## Search plan: layer {values['layer']} at t = {values['t']:g} s"
    if "period" in values:
        head = (f"## Search plan, period {values['period']} of {values['periods']}: layer {values['layer']} at "
                f"t = {values['t']:g} s")
    out = [
        head, "",
        f"- **Effort** {values['effort_m2'] / 1e6:.6g} km² ({values['effort_m2']:.6g} m²: sweep width × track "
        f"length), detection law `{values['law']}`",
        f"- **Ideal POS** {values['pos']:.4f}: the effort spread cell by cell at the optimum (of the whole "
        f"target; the map holds {values['map_mass']:.6f})",
        f"- **Marginal gain** {values['marginal_gain'] * 1e6:.4g} POS per km² of further effort "
        f"({values['marginal_gain']:.4g} per m²)",
    ]
    if "period" in values:
        out[2:4] = [
            out[2],
            f"- **POS of this period** {values['pos']:.4f}: that it finds the target the other periods miss (its map "
            f"holds {values['map_mass']:.6f}); it detects the target first with probability "
            f"{values['first_detection']:.4f}, and the plan's total POS is {values['plan_pos']:.4f}",
        ]
    for name in ("rectangles", "bands"):
        if f"{name}_pos" not in values:
            continue
        loss = values["pos"] - values[f"{name}_pos"]
        out.append(f"- **POS of the {name}** {values[f'{name}_pos']:.4f} ({loss:.4f} below the ideal), effort flown "
                   f"{values[f'{name}_effort_m2'] / 1e6:.6g} km² at sweep width {values['sweep_width_m']:g} m")
    for name in ("rectangles", "bands"):
        if f"{name}_pos" not in values:
            continue
        out += ["", f"| {name[:-1]} | probability | POD | POS | track spacing [m] |", "|---|---|---|---|---|"]
        for k, (p, pod, spacing) in enumerate(zip(values[f"{name}_probability"], values[f"{name}_pod"],
                                                  values[f"{name}_track_spacing_m"])):
            out.append(f"| {_label(name, k)} | {p:.4f} | {pod:.4f} | {p * pod:.4f} | {spacing:,.0f} |")
    out += ["", "**Reading the plan.** The grey map is the probability of each cell; the colour over it is the "
            "coverage (m² swept per m², yellow low, red high); the map stays grey where no effort goes. The "
            "outlines are the areas a crew can fly (rectangles cyan, bands magenta, each in its own tab), each "
            "labelled with its name in the tables above and its POD, the white lines their sweep legs. The POS curve "
            f"is the ideal POS against the total effort (km²), up to {POS_CURVE_SPAN:g} times this plan's (its own "
            f"effort in cyan). North is up; \"{HOVER_NOTE}\"."]
    return "\n".join(out) + "\n"


def _label(name: str, k: int) -> str:
    return f"{'R' if name == 'rectangles' else 'B'}{k + 1}"


def log_plan(rec: rr.RecordingStream, cells: Raster, allocation, rectangles=None, bands=None, *,
             layer: str = "", t: float = 0.0, entity: str = PLAN_ENTITY, extra: dict | None = None) -> dict:
    """Log a plan under ``entity`` (see the module) at the recording's current time; returns
    :func:`plan_values`.

    Parameters
    ----------
    cells : Raster
        The map searched: cell probabilities (``quantity == "probability"``).
    allocation : Allocation
        ``bg.allocate(cells, ...)``.
    rectangles : SearchPlan, optional
        ``bg.search_rectangles(allocation, ...)``.
    bands : RegionPlan, optional
        ``bg.search_regions(allocation, ...)``.
    layer, t : str, float
        Which layer's map at which time (s), for the summary.
    extra : dict, optional
        Further numbers of the plan (a period's of a plan over several: ``period``,
        ``periods``, ``first_detection``, ``plan_pos``), into the summary and the values.
    """
    root = entity_path(entity)
    values = {**plan_values(allocation, rectangles, bands, layer=layer, t=t), **(extra or {})}
    coverage = np.asarray(allocation.effort.values, dtype=np.float64)
    top = float(coverage.max())
    peak = float(np.max(cells.values))
    log_north_up(rec, root)
    with strict():
        rec.log(f"{root}/probability",
                rr.DepthImage(image_from_values(cells.values), meter=1.0, colormap="grayscale",
                              depth_range=(0.0, peak if peak > 0.0 else 1.0)),
                pixel_to_world(cells))
        rec.log(f"{root}/coverage",
                rr.DepthImage(image_from_values(coverage), meter=1.0, colormap="inferno",
                              depth_range=(0.0, top if top > 0.0 else 1.0)),
                pixel_to_world(cells))
        rec.log(f"{root}/overlay", rr.Image(overlay_image(cells.values, coverage), color_model="RGB"),
                pixel_to_world(cells))
        if rectangles is not None:
            flown = [r for r in rectangles.rectangles if r.coverage > 0.0]
            _log_areas(rec, f"{root}/rectangles", "rectangles", [([r.corners], [r.track], r.centre) for r in flown],
                       values, RECTANGLE_COLOUR)
        if bands is not None:
            flown = [r for r in bands.regions if r.coverage > 0.0]
            _log_areas(rec, f"{root}/bands", "bands",
                       [(_outline(r.polygon), list(r.tracks), _anchor(r.polygon, k)) for k, r in enumerate(flown)], values, BAND_COLOUR)
        efforts = pos_curve_efforts(allocation.total_effort)
        km2 = efforts / 1e6
        widths = np.full(len(km2), km2[1] - km2[0])
        rec.log(f"{root}/pos_curve/ideal",
                rr.BarChart(allocation.pos_curve(efforts), abscissa=km2, widths=widths, color=(255, 140, 0)))
        rec.log(f"{root}/pos_curve/this_plan",  # the plan's own effort, marked
                rr.BarChart([allocation.pos], abscissa=[allocation.total_effort / 1e6], widths=widths[:1],
                            color=RECTANGLE_COLOUR))
        rec.log(f"{root}/summary", rr.TextDocument(plan_markdown(values), media_type=rr.MediaType.MARKDOWN))
        rec.log(f"{root}/values", rr.AnyValues(**values))
    return values


def periods_values(plan, period_values: Sequence[dict] = (), *, layer: str = "") -> dict:
    """A plan over several periods' numbers (``bg.plan_periods``'s :class:`PeriodPlan`):
    ``layer``, ``law``, ``periods``, ``times_s``, ``efforts_m2``, ``effort_m2`` (their sum),
    ``pos`` (the total POS), ``first_detection`` (each period's first detections, summing to
    ``pos``), ``period_pos`` (each period's POS of the target the others miss), ``sweeps``,
    ``converged``, ``tol``, ``pos_by_sweep`` (the total POS after each update), ``t`` (the last
    period's time), and ``period_plans``: each period's :func:`plan_values` (``period_values``)."""
    return {
        "layer": layer, "law": plan.law.name, "periods": len(plan.times), "times_s": [float(t) for t in plan.times],
        "t": float(plan.times[-1]), "efforts_m2": [float(z) for z in plan.efforts],
        "effort_m2": float(sum(plan.efforts)), "pos": float(plan.pos),
        "first_detection": [float(p) for p in plan.period_pos],
        "period_pos": [float(a.pos) for a in plan.allocations], "sweeps": int(plan.sweeps),
        "converged": bool(plan.converged), "tol": float(plan.tol), "pos_by_sweep": [float(p) for p in plan.history],
        "period_plans": [dict(v) for v in period_values],
    }


def periods_markdown(values: dict) -> str:
    """:func:`periods_values` as a markdown summary: the total POS and each period's numbers."""
    out = [f"## Search plan over {values['periods']} periods: layer {values['layer']}", "",
           f"- **Total POS** {values['pos']:.4f}: that some period detects the target (detection law "
           f"`{values['law']}`), with the effort {' + '.join(f'{z / 1e6:.6g}' for z in values['efforts_m2'])} km² "
           f"at t = {', '.join(f'{t:g}' for t in values['times_s'])} s",
           f"- **Iteration** {values['sweeps']} sweeps over the periods (Brown's forward-and-backward), "
           f"{'converged' if values['converged'] else 'NOT converged'} to {values['tol']:g} of POS per sweep", "",
           "| period | t [s] | effort [km²] | first detection | POS of the target the others miss |",
           "|---|---|---|---|---|"]
    for k, (t, z, first, pos) in enumerate(zip(values["times_s"], values["efforts_m2"], values["first_detection"],
                                               values["period_pos"])):
        out.append(f"| {k + 1} | {t:g} | {z / 1e6:.6g} | {first:.4f} | {pos:.4f} |")
    out += ["", "**Reading the plan.** Each period is on the timeline at its time: its map is where the target is "
            "then if the other periods miss it, the colour the effort spread over it. The first detections sum to "
            "the total POS; the POS by sweep is the total after each update of one period's effort."]
    return "\n".join(out) + "\n"


def log_plan_periods(rec: rr.RecordingStream, plan, values: dict, *, entity: str = PLAN_ENTITY) -> None:
    """Log a plan over several periods' totals under ``entity``/:data:`PERIODS_ENTITY` at the
    recording's current time (see the module): ``values`` from :func:`periods_values`."""
    root = f"{entity_path(entity)}/{PERIODS_ENTITY}"
    flat = {key: value for key, value in values.items() if key != "period_plans"}
    history = np.asarray(plan.history, dtype=np.float64)
    with strict():
        rec.log(f"{root}/pos_by_sweep", rr.BarChart(history, abscissa=np.arange(1, history.size + 1) / len(plan.times),
                                                    color=(255, 140, 0)))
        rec.log(f"{root}/first_detection", rr.BarChart(np.asarray(plan.period_pos, dtype=np.float64),
                                                       abscissa=np.arange(1, len(plan.times) + 1),
                                                       color=RECTANGLE_COLOUR))
        rec.log(f"{root}/summary", rr.TextDocument(periods_markdown(values), media_type=rr.MediaType.MARKDOWN))
        rec.log(f"{root}/values", rr.AnyValues(**flat))


def overlay_image(probability: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """The coverage over the probability map as one RGB image (rows as
    :func:`image_from_values`'s): the cell probabilities in grey (black 0, white the largest),
    and where effort goes the coverage's colour, yellow (least) to red (most), blended
    :data:`OVERLAY_ALPHA` over the grey; cells without effort stay grey, exactly."""
    p = np.asarray(probability, dtype=np.float64)
    peak = float(p.max())
    grey = np.clip(p / peak, 0.0, 1.0) if peak > 0.0 else np.zeros_like(p)
    top = float(coverage.max())
    share = np.clip(coverage / top, 0.0, 1.0) if top > 0.0 else np.zeros_like(coverage)
    ramp = np.stack([255.0 - 55.0 * share, 235.0 * (1.0 - share), 60.0 * (1.0 - share)], axis=-1)
    rgb = np.repeat(255.0 * grey[..., None], 3, axis=-1)
    covered = coverage > 0.0
    rgb[covered] = (1.0 - OVERLAY_ALPHA) * rgb[covered] + OVERLAY_ALPHA * ramp[covered]
    return np.ascontiguousarray(np.flipud(np.round(rgb).astype(np.uint8)))


def _outline(polygon) -> list[np.ndarray]:
    """Every ring of a shapely (Multi)Polygon, as closed (n, 2) polylines."""
    parts = getattr(polygon, "geoms", [polygon])
    rings = []
    for part in parts:
        rings.append(np.asarray(part.exterior.coords))
        rings += [np.asarray(ring.coords) for ring in part.interiors]
    return rings


def _anchor(polygon, k: int) -> tuple[float, float]:
    """Where band ``k``'s label goes: the west end of its outline for even ``k``, the east end
    for odd. Bands are nested rings about the densest one, so their ends lie apart (and
    alternate sides keep neighbours' labels apart) where points inside them would not."""
    ring = max(_outline(polygon), key=len)
    end = ring[np.argmin(ring[:, 0]) if k % 2 == 0 else np.argmax(ring[:, 0])]
    return (float(end[0]), float(end[1]))


def _log_areas(rec: rr.RecordingStream, path: str, name: str, areas: Sequence, values: dict, colour) -> None:
    """Outlines, sweep legs and labels (its name, R1 or B1 as in the summary's tables, and its
    POD; each at its area's anchor point) of one kind of areas."""
    strips, tracks, anchors, labels = [], [], [], []
    for k, (rings, legs, anchor) in enumerate(areas):
        for ring in rings:
            ring = np.asarray(ring, dtype=np.float64)
            strips.append(ring if np.array_equal(ring[0], ring[-1]) else np.vstack([ring, ring[:1]]))
        tracks += [np.asarray(leg, dtype=np.float64) for leg in legs if len(leg) > 1]
        anchors.append(anchor)
        # short: neighbouring areas' labels must not run into each other; the summary has the rest
        labels.append(f"{_label(name, k)} · POD {values[f'{name}_pod'][k]:.2f}")
    rec.log(path, rr.LineStrips2D(strips, colors=[colour], radii=rr.Radius.ui_points(2.0), draw_order=40.0))
    rec.log(f"{path}/tracks", rr.LineStrips2D(tracks, colors=[TRACK_COLOUR], radii=rr.Radius.ui_points(0.75),
                                              draw_order=35.0))
    rec.log(f"{path}/labels", rr.Points2D(anchors, colors=[colour], radii=rr.Radius.ui_points(3.0), labels=labels,
                                          show_labels=True, draw_order=45.0))


def plan_extent(allocation, rectangles=None, bands=None, margin: float = 0.15) -> tuple[float, float, float, float]:
    """Where the plan's view opens (x0, x1, y0, y1, m): the cells with effort and the areas,
    with ``margin`` of their size around them."""
    grid = allocation.effort.grid
    rows, columns = np.nonzero(np.asarray(allocation.effort.values) > 0.0)
    xs = [grid.x[columns] - 0.5 * grid.dx, grid.x[columns] + 0.5 * grid.dx]
    ys = [grid.y[rows] - 0.5 * grid.dy, grid.y[rows] + 0.5 * grid.dy]
    for r in () if rectangles is None else rectangles.rectangles:
        xs.append(r.corners[:, 0])
        ys.append(r.corners[:, 1])
    for r in () if bands is None else bands.regions:
        x0, y0, x1, y1 = r.polygon.bounds
        xs.append(np.array([x0, x1]))
        ys.append(np.array([y0, y1]))
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    x0, x1, y0, y1 = float(x.min()), float(x.max()), float(y.min()), float(y.max())
    pad = margin * max(x1 - x0, y1 - y0, grid.dx)
    return (x0 - pad, x1 + pad, y0 - pad, y1 + pad)


def plan_view(extent: tuple[float, float, float, float] | None = None, entity: str = PLAN_ENTITY, *,
              rectangles: bool = True, bands: bool = False, periods: bool = False) -> rrb.Tabs:
    """The plan's panel: the coverage over the probability map with the rectangles (the active
    tab, opened on ``extent``) and, in a tab of their own, the bands (each with their tracks and
    labels; one tab each keeps the labels apart), the coverage alone, the map searched, the POS
    curve and the summary; with ``periods`` (a plan over several), the POS by sweep, each
    period's first detections and the plan's summary."""
    root = entity_path(entity)
    bounds = None
    if extent is not None:  # the view's y axis points down (north up): world y maps to -y
        x0, x1, y0, y1 = extent
        bounds = rrb.VisualBounds2D(x_range=(x0, x1), y_range=(-y1, -y0))
    kinds = [kind for kind, wanted in (("rectangles", rectangles), ("bands", bands)) if wanted] or ["rectangles"]
    maps = [rrb.Spatial2DView(origin="/", contents=[f"/{root}/overlay", f"/{root}/{kind}/**"],
                              name=f"plan · {kind} over coverage (yellow → red) and probability (grey) · {HOVER_NOTE}",
                              visual_bounds=bounds) for kind in kinds]
    return rrb.Tabs(
        *maps,
        rrb.Spatial2DView(origin="/", contents=[f"/{root}/coverage", *(f"/{root}/{kind}/**" for kind in kinds)],
                          name=f"plan · coverage (m² per m²) · {HOVER_NOTE}", visual_bounds=bounds),
        rrb.Spatial2DView(origin="/", contents=[f"/{root}/probability"],
                          name=f"plan · the map searched (cell probabilities) · {HOVER_NOTE}", visual_bounds=bounds),
        rrb.BarChartView(origin=f"/{root}/pos_curve", name="plan · POS vs effort (km²)"),
        rrb.TextDocumentView(origin=f"/{root}/summary", name="plan · summary"),
        *(() if not periods else (
            rrb.BarChartView(origin=f"/{root}/{PERIODS_ENTITY}/pos_by_sweep", name="plan · total POS by sweep"),
            rrb.BarChartView(origin=f"/{root}/{PERIODS_ENTITY}/first_detection",
                             name="plan · first detection by period"),
            rrb.TextDocumentView(origin=f"/{root}/{PERIODS_ENTITY}/summary", name="plan · periods"))),
        name="plan",
    )

