"""The default blueprint: one map per layer (log10 first) beside the summary and the scene."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import rerun as rr
import rerun.blueprint as rrb

from .entities import entity_path
from .legend import format_length, nice_length
from .labels import (
    BOX_PADDING_POINTS,
    CHAR_POINTS,
    LABEL_GAP_POINTS,
    PANEL_POINTS,
    TEXT_HEIGHT_POINTS,
    metres_per_point,
)
from .timeline import ELAPSED

__all__ = ["HOVER_NOTE", "SHARED_NOTE", "ColourRange", "default_blueprint", "map_panel_points", "mass_axis",
           "send_blueprint", "union_extent", "view_bounds"]

#: The viewer's area for the views, in points, in the reference window of 1600 x 1000 points with
#: the blueprint and selection panels open (about 200 and 300 points wide) and the time panel
#: below (measured on the viewer's screenshots).
VIEWPORT_POINTS = (1100.0, 680.0)
#: Height of a tab bar above a view, in points.
TAB_BAR_POINTS = 24.0


def map_panel_points(n_maps: int) -> tuple[float, float]:
    """The size (width, height, points) of each of ``n_maps`` map panels (a geographic scene's
    map view counts as one) in the default layout (:func:`default_blueprint`) of the reference
    viewer window (:data:`VIEWPORT_POINTS`); the smallest where rows differ."""
    width, height = VIEWPORT_POINTS
    if n_maps <= 0:
        return PANEL_POINTS
    if n_maps <= 2:
        return width * 3.0 / (3.0 * n_maps + 2.0), height - TAB_BAR_POINTS
    cells = n_maps + 1
    rows = math.ceil(cells / 3)
    widest_row = math.ceil(cells / rows)
    return width / widest_row, height / rows - TAB_BAR_POINTS


@dataclass(frozen=True)
class ColourRange:
    """One colour range for every map of a scene: ``log10`` = (floor, top) of the log10 images
    (the highest floor and the highest top of the layers': a cell below the floor shows the
    floor's colour in every map alike) and ``peak``, the top of the density images (m^-2)."""

    log10: tuple[float, float]
    peak: float

    @classmethod
    def shared(cls, ranges: Iterable[tuple[float, float, float]]) -> ColourRange:
        """From each map's ``(floor, top, peak)``."""
        floors, tops, peaks = zip(*ranges)
        floor, top = max(floors), max(tops)
        return cls((floor, top if top > floor else floor + 1.0), max(peaks) if max(peaks) > 0.0 else 1.0)


#: In the name of a map view whose colours are shared with the scene's other maps.
SHARED_NOTE = "colours shared by all maps"


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
    colours: ColourRange | None = None,
    mass_top: float = 1.0,
    timeline: str = ELAPSED,
    follow: bool = False,
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
    colours : ColourRange, optional
        One colour range for every layer's maps (their images and colour bars), so that maps
        side by side compare colour for colour; each view's name then says so
        (:data:`SHARED_NOTE`). None: each image keeps the range it was logged with.
    mass_top : float
        The largest captured mass plotted: the captured-mass plot's y axis runs from 0 to
        :func:`mass_axis` of it (a mass near 1 is then read as near 1, not as a sliver).
    timeline : str
        The time panel's timeline (``elapsed``, or ``utc`` for a geographic scene with a time).
    follow : bool
        Show the time panel with its cursor at the last time even when the layers have one time
        (a scene's evidence is logged at its own, earlier times: the viewer would open there,
        before the maps).
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
            rrb.TimeSeriesView(origin="/", contents=[f"/{e}/mass" for e in layers], name="captured mass",
                               axis_y=rrb.ScalarAxis(range=mass_axis(mass_top), zoom_lock=False),
                               axis_x=rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                                             end=rrb.TimeRangeBoundary.infinite()))),
            row_shares=[2, 1],
        )
    # "following" puts the cursor at the last time; an explicit panel state, because rerun
    # drops the panel's state chunk with a warning when it is left empty.
    time_panel = (rrb.TimePanel(state="expanded", timeline=timeline, play_state="following")
                  if several_times or follow else None)
    if not layers:
        return rrb.Blueprint(side, collapse_panels=False)
    frames = {entity_path(e): extent for e, extent in (frames or {}).items()}
    panel = map_panel_points(len(layers) + (map_view is not None))
    maps = [
        _layer_tabs(e, [x.rsplit("/", 1)[1] for x in extras if x.rsplit("/", 1)[0] == e],
                    _framed(frames[e], panel) if e in frames else None, colours if len(layers) > 1 else None)
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


def mass_axis(mass_top: float) -> tuple[float, float]:
    """The captured-mass plot's y range: 0 to 5 % above the larger of 1 and ``mass_top``."""
    top = mass_top if math.isfinite(mass_top) and mass_top > 1.0 else 1.0
    return 0.0, 1.05 * top


#: Room around the legend's and the labels' boxes inside a view's bounds, in screen points.
VIEW_MARGIN_POINTS = 6.0
#: The longest labels the colour bar carries east of the frame: "1e-10", and the shared bar's
#: title (bananagrid.recording.legend.SHARED_TITLE, "log10 m^-2 · all maps").
_TICK_CHARS, _TITLE_CHARS = 5, 21


def view_bounds(extent: tuple[float, float, float, float],
                panel: tuple[float, float] = PANEL_POINTS) -> tuple[float, float, float, float]:
    """What a map's view shows (x0, x1, y0, y1, m, north up): its frame ``extent`` and the legend
    :func:`~bananagrid.recording.legend.log_legend` draws beside it (the colour bar east, its
    decade labels and title, the scale bar and its length below), each with
    ``VIEW_MARGIN_POINTS`` of room; the labels are sized in screen points as the label board
    sizes them on a map ``panel`` (width, height) points large
    (:func:`~bananagrid.recording.labels.metres_per_point`)."""
    x0, x1, y0, y1 = extent
    width, height = x1 - x0, y1 - y0
    pt = metres_per_point(extent, panel)
    tick_half = 0.5 * (CHAR_POINTS * _TICK_CHARS + BOX_PADDING_POINTS) * pt
    title_half = 0.5 * (CHAR_POINTS * _TITLE_CHARS + BOX_PADDING_POINTS) * pt
    margin = VIEW_MARGIN_POINTS * pt
    east = max(x1 + 0.055 * width + tick_half, x1 + 0.03 * width + title_half) + margin
    north = y1 + 0.04 * height + LABEL_GAP_POINTS * pt + margin
    south = y0 - 0.05 * height - (LABEL_GAP_POINTS + TEXT_HEIGHT_POINTS) * pt - 0.5 * TEXT_HEIGHT_POINTS * pt - margin
    # the scale bar's length is centred on the bar, which starts at the frame's west edge: a
    # narrow map's label reaches beyond that edge
    length = nice_length(width / 4.0)
    label_half = 0.5 * (CHAR_POINTS * len(format_length(length)) + BOX_PADDING_POINTS) * pt
    west = min(x0 - max(0.03 * width, margin), x0 + 0.5 * length - label_half - margin)
    return west, east, south, north


def _framed(extent: tuple[float, float, float, float], panel: tuple[float, float] = PANEL_POINTS) -> rrb.VisualBounds2D:
    """View bounds of :func:`view_bounds`. The view's y axis points down (the layers are
    flipped north up), so world ``y`` maps to ``-y`` there."""
    west, east, south, north = view_bounds(extent, panel)
    return rrb.VisualBounds2D(x_range=(west, east), y_range=(-north, -south))


def _layer_tabs(entity: str, extra_images: Sequence[str] = (), bounds: rrb.VisualBounds2D | None = None,
                colours: ColourRange | None = None) -> rrb.Tabs:
    """Log10 density and density views of one layer (and any extra images), each with its
    contours and whatever geometry the layer carries; the log10 view is the active tab."""
    return rrb.Tabs(
        *(_map_view(entity, image, bounds, colours) for image in ("log10_density", "density", *extra_images)),
        name=entity,
    )


#: Shown in every map view's name: rerun's hover reports the view's own coordinates, whose y axis
#: points down (the maps are flipped north up), so a hovered line's "y" is minus the northing;
#: over an image it reports the pixel (column from the west edge, row from the north edge).
HOVER_NOTE = "hover y = −north"


def _map_view(entity: str, image: str, bounds: rrb.VisualBounds2D | None = None,
              colours: ColourRange | None = None) -> rrb.Spatial2DView:
    """A 2D view of one image, the contours, the legend (log10 view) and the layer's geometry
    overlay (if any); rooted at ``/`` so the north-up flip applies. With ``colours``, the
    log10 and density images (and the colour bar) are shown in that shared range."""
    contents = [f"/{entity}/{image}", f"/{entity}/contours/**", f"/{entity}/density_contours/**", f"/{entity}/geometry/**"]
    if image == "log10_density":
        # a shared range: the shared bar (bananagrid.recording.layers.log_shared_colours) in
        # place of the map's own, the scale bar kept
        contents += [f"/{entity}/legend/**"] if colours is None else [f"/{entity}/legend/scale", f"/{entity}/shared_legend/**"]
    label = entity.removeprefix("layers/")
    overrides, note = {}, ""
    if colours is not None and image in ("log10_density", "density"):
        shown = colours.log10 if image == "log10_density" else (0.0, colours.peak)
        overrides[f"/{entity}/{image}"] = rr.DepthImage.from_fields(depth_range=shown)
        note = f" · {SHARED_NOTE}"
    return rrb.Spatial2DView(
        origin="/", contents=contents, name=f"{label} · {image.replace('_', ' ')}{note} · {HOVER_NOTE}",
        visual_bounds=bounds, overrides=overrides or None,
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
