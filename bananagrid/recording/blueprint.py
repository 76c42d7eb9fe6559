"""The default blueprint: one map per layer (log10 first) beside the summary and the scene."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import rerun as rr
import rerun.blueprint as rrb

from .entities import entity_path
from .timeline import ELAPSED

__all__ = ["HOVER_NOTE", "default_blueprint", "send_blueprint", "union_extent"]


def default_blueprint(
    layer_entities: Sequence[str],
    *,
    scene_entity: str = "scene",
    summary_entity: str | None = None,
    extra_images: Sequence[str] = (),
    text_entities: Sequence[str] = (),
    extra_views: Sequence[rrb.View] = (),
    several_times: bool = False,
    frames: Mapping[str, tuple[float, float, float, float]] | None = None,
    map_view: rrb.View | None = None,
) -> rrb.Blueprint:
    """The default layout: one map per layer (log10 first), beside the summary and the scene.

    The maps and the text panel fill rows of at most three panels, with no empty cell. Each
    layer's map is a tab group: the log10 density (shown first: the tails and the
    probability-mass contours are visible there), the linear density, then any extra images.
    The captured-mass plot is shown only when the scene has several times (one point says
    nothing that the summary does not), and the time cursor then starts at the last time
    (the time panel follows the data to its end).

    Parameters
    ----------
    layer_entities : sequence of str
        The ``entity`` paths given to :func:`log_raster`.
    scene_entity : str
        The entity given to :func:`log_scene_text`.
    summary_entity : str, optional
        A text document summarising the run (shown first, before the scene text).
    extra_images : sequence of str
        Further images under some layers (``"layers/NAME/IMAGE"``), each shown as one more
        tab of its layer (e.g. a bearing fix's difference to its linear map).
    text_entities : sequence of str
        Further text documents (e.g. a validation table), each a tab beside the scene text.
    extra_views : sequence of rerun views
        Further views (e.g. radial-curve plots), as tabs beside the summary and the scene.
    several_times : bool
        Whether the layers are logged at more than one elapsed time.
    frames : mapping of layer entity to (x0, x1, y0, y1), optional
        Where each map opens (m): its :func:`focus_extent` (over all times, see
        :func:`union_extent`) and the legend beside it. Anything beyond (the rest of the
        grid, distant bearing stations) is a zoom-out away.
    map_view : rerun view, optional
        A geographic scene's map (:func:`bananagrid.recording.geomap.map_view`), a panel
        after the layers' maps.
    """
    layers = [entity_path(e) for e in layer_entities]
    extras = [entity_path(e) for e in extra_images]
    texts = [] if summary_entity is None else [rrb.TextDocumentView(origin=f"/{entity_path(summary_entity)}", name="summary")]
    texts.append(rrb.TextDocumentView(origin=f"/{entity_path(scene_entity)}", name="scene"))
    texts += [rrb.TextDocumentView(origin=f"/{entity_path(e)}", name=entity_path(e)) for e in text_entities]
    texts += list(extra_views)
    side = rrb.Tabs(*texts) if len(texts) > 1 else texts[0]
    if several_times and layers:
        side = rrb.Vertical(
            side,
            rrb.TimeSeriesView(origin="/", contents=[f"/{e}/mass" for e in layers], name="captured mass"),
            row_shares=[2, 1],
        )
    # "following" puts the cursor at the last time; an explicit panel state, because rerun
    # drops the panel's state chunk with a warning when it is left empty.
    time_panel = rrb.TimePanel(state="expanded", timeline=ELAPSED, play_state="following") if several_times else None
    if not layers:
        return rrb.Blueprint(side, collapse_panels=False)
    frames = {entity_path(e): extent for e, extent in (frames or {}).items()}
    maps = [
        _layer_tabs(e, [x.rsplit("/", 1)[1] for x in extras if x.rsplit("/", 1)[0] == e],
                    _framed(frames[e]) if e in frames else None)
        for e in layers
    ]
    if map_view is not None:
        maps.append(map_view)
    top = _panels(maps, side)
    parts = [top] if time_panel is None else [top, time_panel]
    return rrb.Blueprint(*parts, collapse_panels=False)


def _panels(maps: Sequence, side) -> rrb.Container:
    """Maps and the text panel in rows of at most three, the rows as even as possible, so
    that no cell is empty; one or two maps sit in one row with a narrower text panel."""
    if len(maps) <= 2:
        return rrb.Horizontal(*maps, side, column_shares=[3] * len(maps) + [2])
    cells = [*maps, side]
    rows = math.ceil(len(cells) / 3)
    sizes = [len(cells) // rows + (1 if k < len(cells) % rows else 0) for k in range(rows)]
    out, k = [], 0
    for size in sizes:
        out.append(rrb.Horizontal(*cells[k:k + size]))
        k += size
    return rrb.Vertical(*out)


def _framed(extent: tuple[float, float, float, float]) -> rrb.VisualBounds2D:
    """View bounds holding ``extent``, the colour bar east of it and the scale bar below it.

    The view's y axis points down (the layers are flipped north up), so world ``y`` maps to
    ``-y`` there.
    """
    x0, x1, y0, y1 = extent
    width, height = x1 - x0, y1 - y0
    return rrb.VisualBounds2D(
        x_range=(x0 - 0.03 * width, x1 + 0.16 * width), y_range=(-(y1 + 0.08 * height), -(y0 - 0.1 * height)),
    )


def _layer_tabs(entity: str, extra_images: Sequence[str] = (), bounds: rrb.VisualBounds2D | None = None) -> rrb.Tabs:
    """Log10 density and density views of one layer (and any extra images), each with its
    contours and whatever geometry the layer carries; the log10 view is the active tab."""
    return rrb.Tabs(
        *(_map_view(entity, image, bounds) for image in ("log10_density", "density", *extra_images)),
        name=entity,
    )


#: Shown in every map view's name: rerun's hover reports the view's own coordinates, whose y axis
#: points down (the maps are flipped north up), so a hovered line's "y" is minus the northing;
#: over an image it reports the pixel (column from the west edge, row from the north edge).
HOVER_NOTE = "hover y = −north"


def _map_view(entity: str, image: str, bounds: rrb.VisualBounds2D | None = None) -> rrb.Spatial2DView:
    """A 2D view of one image, the contours, the legend (log10 view) and the layer's geometry
    overlay (if any); rooted at ``/`` so the north-up flip applies."""
    contents = [f"/{entity}/{image}", f"/{entity}/contours/**", f"/{entity}/density_contours/**", f"/{entity}/geometry/**"]
    if image == "log10_density":
        contents.append(f"/{entity}/legend/**")
    label = entity.removeprefix("layers/")
    return rrb.Spatial2DView(
        origin="/", contents=contents, name=f"{label} · {image.replace('_', ' ')} · {HOVER_NOTE}", visual_bounds=bounds,
    )


def send_blueprint(rec: rr.RecordingStream, blueprint: rrb.BlueprintLike) -> None:
    """Send ``blueprint`` into ``rec``'s sinks as the active and default blueprint.

    With a file sink the blueprint is written into the ``.rrd`` as a separate blueprint store.
    :func:`write_recording` embeds its ``blueprint`` argument already.
    """
    rec.send_blueprint(blueprint, make_active=True, make_default=True)


def union_extent(extents: Iterable[tuple[float, float, float, float]]) -> tuple[float, float, float, float]:
    """The smallest extent holding all of ``extents`` (at least one)."""
    x0, x1, y0, y1 = zip(*extents)
    return min(x0), max(x1), min(y0), max(y1)
