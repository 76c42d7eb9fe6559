"""Evidence in a recording: the searches that found nothing, the reports and land, and each layer's
posterior beside its prior.

Under ``evidence`` (north up, world metres):

- ``evidence/marks/NAME``: each evidence's geometry, logged at its time on the timeline (so that
  it appears when it happened): an area searched (its outline), a searcher's track (a line with a
  point at each timed position), a reported position, bearing stations with their bearing lines;
  land (an exclusion) is static;
- ``evidence/LAYER/prior`` and ``evidence/LAYER/posterior``: log10 of the layer's cell
  probabilities before and after the evidence that began by the map's time (the prior
  normalised over the grid, as the posterior is), one colour range for both (:data:`LOG_DECADES`
  below the larger peak), so that they compare colour for colour;
- ``evidence/LAYER/pod``: the cumulative probability of detection of each cell (0 to 1);
- ``evidence/LAYER/pos`` and ``evidence/LAYER/search_pos/NAME``: the POS of the searches together
  and of each search alone, as scalars at each map time (POS over time);
- ``evidence/LAYER/summary``: a markdown summary, and ``evidence/LAYER/values``: the same numbers
  as ``AnyValues`` (what ``bananagrid inspect`` reports, :func:`evidence_values`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .blueprint import HOVER_NOTE
from .entities import entity_path, strict
from .images import image_from_values, log_north_up, pixel_to_world

__all__ = ["EVIDENCE_ENTITY", "MARKS", "evidence_values", "evidence_markdown", "log_evidence_marks",
           "log_posterior", "evidence_view", "LOG_DECADES"]

#: Where a scene's evidence is recorded.
EVIDENCE_ENTITY = "evidence"
#: The evidence's geometry, under :data:`EVIDENCE_ENTITY`.
MARKS = "marks"
#: Colours: searched areas and tracks orange, reports cyan, land grey.
SEARCH_COLOUR = (255, 140, 0)
REPORT_COLOUR = (0, 220, 255)
LAND_COLOUR = (160, 160, 160)
#: Decades of cell probability the prior and posterior images show below the larger peak: the
#: holes a search punches in the tails stay visible beside the peak.
LOG_DECADES = 6.0


def evidence_values(post, used: Sequence, specs: Sequence, *, layer: str = "", t: float = 0.0) -> dict:
    """A posterior's numbers, flat: ``layer``, ``t`` (s), ``pos`` (the searches together),
    ``normaliser`` (the probability of the evidence under the prior), ``evidence`` (the names
    of the evidence the map took), ``searches`` (every search of the scene, by name) and
    ``search_pos`` (each one's own POS, NaN for a search that began after the map's time)."""
    own = dict(zip([s.name for s in used if s.search], post.search_pos))
    searches = [s.name for s in specs if s.search]
    return {
        "layer": layer, "t": float(t), "pos": float(post.pos), "normaliser": float(post.normaliser),
        "evidence": [s.name for s in used], "searches": searches,
        "search_pos": [float(own.get(name, math.nan)) for name in searches],
        "prior_mass": float(np.sum(post.prior)),
    }


def evidence_markdown(values: dict, specs: Sequence) -> str:
    """:func:`evidence_values` as a layer's markdown summary at one time."""
    out = [f"## Evidence: layer {values['layer']} at t = {values['t']:g} s", "",
           f"- **POS** {values['pos']:.4f}: the probability that the searches so far would have found the target "
           f"(given the reports and land)",
           f"- **Probability of the evidence** under the prior {values['normaliser']:.6g}", "",
           "| evidence | kind | t [s] | POS alone |", "|---|---|---|---|"]
    pos = dict(zip(values["searches"], values["search_pos"]))
    for spec in specs:
        taken = spec.name in values["evidence"]
        when = "always" if spec.span is None else (f"{spec.span[0]:g}" if spec.span[0] == spec.span[1]
                                                   else f"{spec.span[0]:g} to {spec.span[1]:g}")
        share = f"{pos[spec.name]:.4f}" if spec.search and taken else ("" if taken else "later")
        out.append(f"| {spec.name} | {spec.kind.replace('_', ' ')} | {when} | {share} |")
    out += ["", "**Reading the maps.** Prior and posterior are log10 of the layer's cell probabilities before and "
            f"after the evidence that began by this time, in one colour range ({LOG_DECADES:g} decades); the POD map is the probability that the "
            "searches would have detected a target in each cell. Searched areas and tracks are orange, reports "
            f"cyan, land grey, each drawn from its own time on. North is up; \"{HOVER_NOTE}\"."]
    return "\n".join(out) + "\n"


def log_evidence_marks(rec: rr.RecordingStream, specs: Sequence, set_time, extent, entity: str = EVIDENCE_ENTITY) -> None:
    """Each evidence's geometry under ``entity/marks/NAME`` at its time (``set_time(seconds)``
    puts the recording there; land is static); ``extent`` (x0, x1, y0, y1: the grid) sizes the
    bearing lines: each runs from its station to the distance of the grid's farthest corner."""
    root = entity_path(entity)
    log_north_up(rec, root)
    with strict():
        for spec in specs:
            path = f"{root}/{MARKS}/{spec.name}"
            static = spec.span is None
            if not static:
                set_time(spec.span[0])
            label = f"{spec.name} · {spec.kind.replace('_', ' ')}"
            if spec.shapes:
                colour = LAND_COLOUR if spec.kind == "exclusion" else SEARCH_COLOUR
                rings = [np.vstack([s, s[:1]]) for s in spec.shapes]
                rec.log(path, rr.LineStrips2D(rings, colors=[colour], radii=rr.Radius.ui_points(2.0),
                                              labels=[label] * len(rings), show_labels=True, draw_order=40.0),
                        static=static)
            elif spec.track is not None:
                rec.log(path, rr.LineStrips2D([spec.track[:, :2]], colors=[SEARCH_COLOUR],
                                              radii=rr.Radius.ui_points(2.0), labels=[label], show_labels=True,
                                              draw_order=40.0))
                rec.log(f"{path}/points", rr.Points2D(spec.track[:, :2], colors=[SEARCH_COLOUR],
                                                      radii=rr.Radius.ui_points(3.0), draw_order=41.0))
            elif spec.points is not None:
                rec.log(path, rr.Points2D(spec.points, colors=[REPORT_COLOUR], radii=rr.Radius.ui_points(4.0),
                                          labels=[label] + [""] * (len(spec.points) - 1), show_labels=True,
                                          draw_order=42.0))
                fix = getattr(spec.evidence, "fix", None)
                if fix is not None:  # each station's bearing as a line, to the grid's far side
                    corners = np.array([[x, y] for x in extent[:2] for y in extent[2:]])
                    lines = [np.array([s, s + float(np.max(np.hypot(*(corners - s).T)))
                                       * np.array([math.sin(b), math.cos(b)])])
                             for s, b in zip(np.asarray(fix.sensors), np.asarray(fix.bearings))]
                    rec.log(f"{path}/bearings", rr.LineStrips2D(lines, colors=[REPORT_COLOUR],
                                                                radii=rr.Radius.ui_points(1.0), draw_order=39.0))


def log_posterior(rec: rr.RecordingStream, layer: str, post, values: dict, specs: Sequence, *,
                  entity: str = EVIDENCE_ENTITY, colormap: str = "viridis") -> None:
    """A layer's prior, posterior, POD map and POS at the recording's current time (see the module)."""
    root = f"{entity_path(entity)}/{entity_path(layer)}"
    prior = np.asarray(post.prior, dtype=np.float64)
    prior_p = prior / np.sum(prior)  # normalised, as the posterior: the two compare cell for cell
    maps = {"prior": prior_p, "posterior": np.asarray(post.values, dtype=np.float64)}
    top = math.log10(max(float(m.max()) for m in maps.values()))
    floor = top - LOG_DECADES
    where = pixel_to_world(post)
    with strict():
        for name, image in maps.items():
            with np.errstate(divide="ignore"):
                logs = np.where(image > 10.0**floor, np.log10(np.maximum(image, 1e-300)), floor)
            rec.log(f"{root}/{name}", rr.DepthImage(image_from_values(logs), meter=1.0, colormap=colormap,
                                                     depth_range=(floor, top)), where)
        rec.log(f"{root}/pod", rr.DepthImage(image_from_values(post.pod), meter=1.0, colormap="inferno",
                                             depth_range=(0.0, 1.0)), where)
        rec.log(f"{root}/pos", rr.Scalars([values["pos"]]))
        for name, pos in zip(values["searches"], values["search_pos"]):
            if math.isfinite(pos):
                rec.log(f"{root}/search_pos/{name}", rr.Scalars([pos]))
        rec.log(f"{root}/summary", rr.TextDocument(evidence_markdown(values, specs), media_type=rr.MediaType.MARKDOWN))
        rec.log(f"{root}/values", rr.AnyValues(**{k: v for k, v in values.items() if v != []}))


def evidence_view(layers: Sequence[str], extent: tuple | None = None, entity: str = EVIDENCE_ENTITY) -> rrb.Tabs:
    """The evidence's panel: per layer, its prior above its posterior (the searches,
    tracks, reports and land over both), then the POD map, the POS over time and the summary."""
    root = entity_path(entity)
    bounds = None
    if extent is not None:  # the view's y axis points down (north up): world y maps to -y
        x0, x1, y0, y1 = extent
        bounds = rrb.VisualBounds2D(x_range=(x0, x1), y_range=(-y1, -y0))
    marks = f"/{root}/{MARKS}/**"
    tabs = []
    for layer in layers:
        base = f"/{root}/{entity_path(layer)}"
        tabs.append(rrb.Vertical(
            rrb.Spatial2DView(origin="/", contents=[f"{base}/prior", marks], name=f"{layer} · prior (log10 cell probability)",
                              visual_bounds=bounds),
            rrb.Spatial2DView(origin="/", contents=[f"{base}/posterior", marks],
                              name=f"{layer} · posterior after the evidence (log10 cell probability) · {HOVER_NOTE}", visual_bounds=bounds),
            name=f"{layer} · prior and posterior"))
    for layer in layers:
        base = f"/{root}/{entity_path(layer)}"
        tabs.append(rrb.Spatial2DView(origin="/", contents=[f"{base}/pod", marks],
                                      name=f"{layer} · POD of the searches (0 to 1)", visual_bounds=bounds))
    tabs.append(rrb.TimeSeriesView(origin="/", contents=[f"/{root}/{entity_path(layer)}/pos" for layer in layers]
                                   + [f"/{root}/{entity_path(layer)}/search_pos/**" for layer in layers],
                                   name="POS over time", axis_y=rrb.ScalarAxis(range=(0.0, 1.05), zoom_lock=False)))
    tabs += [rrb.TextDocumentView(origin=f"/{root}/{entity_path(layer)}/summary", name=f"{layer} · evidence summary")
             for layer in layers]
    return rrb.Tabs(*tabs, name="evidence")
