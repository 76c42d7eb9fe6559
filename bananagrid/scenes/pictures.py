"""Pictures of a scene's layers without a viewer (``bananagrid plot``): from the scene itself
(computed as ``run`` computes it), from a recording ``run`` wrote, or from its ``.npz`` arrays or
CF NetCDF maps (``--netcdf``); one map per layer at one time, in one PNG written atomically, or
an animation over the scene's times (``--animate``: a GIF with Pillow, an MP4 with ffmpeg).

Panels side by side share one colour range and one colour bar, and one key to the contour
colours. A geographic scene's maps are charts (:mod:`bananagrid.geo.chart`): latitude and
longitude lines and labels, the bundled land, a km scale bar, and the UTC time in each title.

Each map is :func:`bananagrid.plotting.plot_raster`'s: log10 density in km, the
probability-mass contours labelled with their areas, and what the layer's provenance names (a
bearing fix's sensors, bearing lines with +-2 sigma wedges and fix; a start and its heading), so
a recording or an ``.npz`` gives the same picture as its scene. Array scenes (``[array]``: cell
probabilities on an angular lattice, not a grid) are refused with a one-line message; their
recordings hold the cell table.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import shutil
import textwrap
import zipfile
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..contours import DEFAULT_MASS_LEVELS, mass_levels as checked_levels
from ..domains.grid import Grid
from ..geo.chart import chart as geo_chart
from ..geo.dataset import read_maps
from ..geo.frame import GeoFrame
from ..plotting import (
    colour_range,
    figure_layout,
    format_time,
    MapGeometry,
    legend_handles,
    map_frame,
    map_geometry,
    plot_overview,
    plot_raster,
    pyplot,
    shared_colour_range,
    utc_label,
)
from ..recording.readback import read_rasters
from ..results import Raster
from ..validate import BananagridError, positive, regular_file, show
from .load import load_scene
from .run_grid import compute

__all__ = ["ANIMATIONS", "DEFAULT_FPS", "INPUTS", "MAX_FPS", "Panel", "Picture", "check_animation_options",
           "check_picture_options", "picture_layout", "read_picture", "read_timeline", "write_animation",
           "write_picture"]

#: What ``bananagrid plot`` reads, by file suffix.
INPUTS = (".toml", ".rrd", ".npz", ".nc")
#: What ``bananagrid plot --animate`` writes, by file suffix (MP4 needs ffmpeg).
ANIMATIONS = (".gif", ".mp4")
#: Frames per second of an animation by default (a scene has a handful of times: each is read).
DEFAULT_FPS = 2.0
#: GIF stores a frame's duration in hundredths of a second: 50 frames per second at most.
MAX_FPS = 50.0
#: Room under the maps for the key to the contour colours, inches.
LEGEND_HEIGHT = 0.45

#: Times closer than this (relative, absolute s) are the same time.
_SAME_TIME = {"rtol": 1e-12, "atol": 1e-9}


@dataclass(frozen=True)
class Panel:
    """One map of a picture: a layer at one elapsed time, and more points to mark on it
    (``(x, y, label)``, m) beyond what its provenance names."""

    layer: str
    t: float
    raster: Raster
    markers: tuple = ()


@dataclass(frozen=True)
class Picture:
    """What one PNG shows: a heading (the scene's name and title), its panels, and the
    probability-mass levels to draw (the scene's ``output.mass_levels`` for a scene file)."""

    heading: str
    panels: tuple
    mass_levels: tuple = DEFAULT_MASS_LEVELS


def _plot_input(source) -> tuple[Path, str]:
    """``source`` as a path and its lower-case suffix, refused unless one of :data:`INPUTS` and a
    regular file (a FIFO would wait for a writer)."""
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix not in INPUTS:
        raise BananagridError(
            f"{path}: cannot plot a {suffix or 'suffix-less'} file; give one of {', '.join(INPUTS)} "
            "(a scene, or a recording, arrays or NetCDF maps written by bananagrid run)"
        )
    regular_file(path, "a file to plot")
    return path, suffix


def read_picture(source: str | os.PathLike, *, layers: Sequence[str] = (), t: float | None = None,
                 threads: int | None = None, step: float | None = None) -> Picture:
    """The panels of ``source``: every layer (or those named in ``layers``) at time ``t``
    (default: the last time).

    Parameters
    ----------
    source : path-like
        A scene ``.toml`` (its layers at that time are computed, as ``bananagrid run`` does),
        a recording ``.rrd``, arrays ``.npz`` or maps ``.nc`` written by ``bananagrid run``.
    layers : sequence of str
        Layer names to keep, in the order given (default: all, in the file's order).
    t : float, optional
        Elapsed time, s; one of the file's times.
    threads : int, optional
        CPU threads for computing a scene.
    step : float, optional
        Compute a scene on square cells of this size, m (over the same bounds).

    Raises
    ------
    BananagridError
        One line: an unknown suffix (naming those accepted), a missing file, an array scene,
        a time the file does not hold (listing its times), an unknown layer (listing them).
    """
    path, suffix = _plot_input(source)
    if t is not None and not (isinstance(t, (int, float)) and np.isfinite(t)):
        raise BananagridError(f"--t = {show(t)}: expected a finite time in seconds")
    if step is not None and suffix != ".toml":
        raise BananagridError(f"step = {show(step)}: only a scene (.toml) is computed at another step")
    heading, levels, found = _panels(path, t, threads, step)
    times = sorted({p.t for p in found})
    if t is None:
        t = times[-1]
    elif not any(np.isclose(t, u, **_SAME_TIME) for u in times):
        raise BananagridError(f"--t = {show(t)}: {path} has times {_listed(times)} s")
    chosen = [p for p in found if np.isclose(p.t, t, **_SAME_TIME)]
    names = list(dict.fromkeys(p.layer for p in chosen))
    for layer in layers:
        if layer not in names:
            raise BananagridError(
                f"--layer {show(layer)}: not a layer of {path} at t = {t:g} s; choose one of {', '.join(names)}"
            )
    if layers:
        chosen = [p for name in dict.fromkeys(layers) for p in chosen if p.layer == name]
    return Picture(heading, tuple(chosen), levels)


def read_timeline(source: str | os.PathLike, *, layers: Sequence[str] = (), threads: int | None = None,
                  step: float | None = None) -> list[Picture]:
    """One :class:`Picture` per time of ``source`` (sorted): the frames of an animation.

    A scene's layers are computed at every time of its timeline (its ``times``, or each
    layer's own ``t``), as ``bananagrid run`` records them. Each frame holds every layer (or
    those named in ``layers``, in that order): at the frame's time, or, for a layer without
    that time (a timeless bearing fix), at its latest time before it (its first, if none).

    Arguments and errors as for :func:`read_picture`.
    """
    path, suffix = _plot_input(source)
    if step is not None and suffix != ".toml":
        raise BananagridError(f"step = {show(step)}: only a scene (.toml) is computed at another step")
    heading, levels, found = _panels(path, None, threads, step, every=True)
    names = list(dict.fromkeys(p.layer for p in found))
    for layer in layers:
        if layer not in names:
            raise BananagridError(f"--layer {show(layer)}: not a layer of {path}; choose one of {', '.join(names)}")
    shown = list(dict.fromkeys(layers)) or names
    times = sorted({p.t for p in found})
    frames = []
    for t in times:
        chosen = []
        for name in shown:
            own = sorted((p for p in found if p.layer == name), key=lambda p: p.t)
            before = [p for p in own if p.t <= t or np.isclose(p.t, t, **_SAME_TIME)]
            chosen.append(before[-1] if before else own[0])
        frames.append(Picture(heading, tuple(chosen), levels))
    return frames


def picture_layout(frames: Sequence[tuple[float, float, float, float]]) -> tuple[int, int, tuple[float, float]]:
    """Rows, columns and size (inches) of a picture of maps framed on ``frames``:
    :func:`bananagrid.plotting.figure_layout`'s, with room for the key to the contour colours."""
    rows, columns, (width, height) = figure_layout(frames)
    return rows, columns, (width, round(height + LEGEND_HEIGHT, 2))


def write_picture(out: str | os.PathLike, picture: Picture, *, mass_levels: Iterable[float] | None = None,
                  dpi: int = 100) -> Path:
    """One PNG with a map per panel, written atomically.

    Parameters
    ----------
    out : path-like
        The PNG (its name must end in ``.png``); its folder must exist.
    picture : Picture
        What to draw (:func:`read_picture`).
    mass_levels : iterable of float, optional
        Probability-mass levels in (0, 1) (default: the picture's).
    dpi : int
        Pixels per inch, 20 to 600; the figure's size and maps per row are
        :func:`bananagrid.plotting.figure_layout`'s.

    Returns
    -------
    Path
        ``out``.
    """
    out = check_picture_options(out, dpi)
    levels = checked_levels(picture.mass_levels if mass_levels is None else mass_levels, key="--mass-levels")
    if not picture.panels:
        raise BananagridError(f"{out}: nothing to draw")
    plt = pyplot(headless=True)
    extents = [map_frame(p.raster, levels) for p in picture.panels]
    overview = picture_overview(picture, extents)
    _, _, size = picture_layout(extents + ([overview[0]] if overview else []))
    figure = plt.figure(figsize=size, layout="constrained")
    try:
        clim = shared_colour_range(colour_range(p.raster, levels) for p in picture.panels)
        draw_picture(figure, picture, levels, clim=clim, extents=extents, overview=overview)
        figure.canvas.draw()  # the layout settles on the second pass (equal-aspect maps and titles)
        with atomic_write(out) as partial:
            figure.savefig(partial, format="png", dpi=int(dpi))
    finally:
        plt.close(figure)
    return out


def draw_picture(figure, picture: Picture, levels: Sequence[float], *, clim: tuple[float, float],
                 extents: Sequence[tuple[float, float, float, float]], charts: Sequence | None = None,
                 overview: tuple | None = None) -> list:
    """Draw ``picture`` on the empty ``figure``: a map per panel framed on ``extents`` (m), all
    in the colour range ``clim`` (log10 m^-2) with one colour bar, one key to the contour
    colours under them, and the heading above. A panel with a geographic frame is a chart
    (``charts``: one per panel, each a :class:`bananagrid.geo.chart.Chart` or None; computed
    when not given); ``overview`` (:func:`picture_overview`) adds a last panel showing where
    the maps lie among what they leave out. Returns the axes of the panels."""
    rows, columns, size = picture_layout(list(extents) + ([overview[0]] if overview else []))
    axes = figure.subplots(rows, columns, squeeze=False)
    if charts is None:
        charts = [panel_chart(p, e) for p, e in zip(picture.panels, extents)]
    drawn = []
    for ax, panel, extent, chart in zip(axes.flat, picture.panels, extents, charts):
        plot_raster(panel.raster, ax, mass_levels=levels, title=_panel_title(panel), markers=panel.markers,
                    colorbar=False, legend=False, clim=clim, extent=extent,
                    chart=None if chart is None else (lambda _, c=chart: c))
        drawn.append(ax)
    spare = list(axes.flat)[len(picture.panels):]
    if overview:
        extent, chart, geometry = overview
        plot_overview(spare.pop(0), geometry, extents, extent, chart)
    for ax in spare:
        ax.set_visible(False)
    figure.colorbar(drawn[0].images[0], ax=list(axes.flat), label="log10 density [m⁻²]", shrink=0.9, aspect=30,
                    pad=0.02)
    # the key in one row where the figure is wide enough (about 1.4 in an entry), else in two
    columns_of_key = len(levels) if size[0] >= 1.4 * len(levels) else -(-len(levels) // 2)
    figure.legend(handles=legend_handles(levels), loc="outside lower center", ncols=columns_of_key, fontsize=8,
                  title="probability mass (contours)", title_fontsize=8, frameon=False)
    figure.suptitle("\n".join(textwrap.wrap(picture.heading, max(30, int(size[0] / 0.085)))), fontsize=11)
    return drawn


#: An overview reaches this fraction of its size beyond the outermost point or map it shows.
OVERVIEW_MARGIN = 0.12


def picture_overview(picture: Picture, extents) -> tuple | None:
    """``(extent, chart, geometry)`` of an overview of a geographic picture whose maps leave
    out a point their provenance names (a bearing fix's stations, a start), else None: the
    extent holds every map's frame and every point, with a margin, at an aspect (width over
    height) between 0.6 and 3; the chart is :func:`bananagrid.geo.chart.chart`'s of it."""
    frames = [getattr(p.raster, "frame", None) for p in picture.panels]
    if not frames or any(frame is None for frame in frames):
        return None
    seen, markers, bearings, heading = set(), [], [], None
    for panel in picture.panels:
        shown = map_geometry(panel.raster.provenance)
        for x, y, label in list(shown.markers) + list(panel.markers):
            if (round(x, 3), round(y, 3), label) not in seen:
                seen.add((round(x, 3), round(y, 3), label))
                markers.append((x, y, label))
        bearings = bearings or list(shown.bearings)
        heading = heading or shown.heading
    left_out = [(x, y) for panel, (x0, x1, y0, y1) in zip(picture.panels, extents)
                for x, y, _ in list(map_geometry(panel.raster.provenance).markers) + list(panel.markers)
                if not (x0 <= x <= x1 and y0 <= y <= y1)]
    if not left_out:
        return None
    xs = [v for e in extents for v in e[:2]] + [x for x, _, _ in markers]
    ys = [v for e in extents for v in e[2:]] + [y for _, y, _ in markers]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    grow = OVERVIEW_MARGIN * max(x1 - x0, y1 - y0)
    x0, x1, y0, y1 = x0 - grow, x1 + grow, y0 - grow, y1 + grow
    width, height = x1 - x0, y1 - y0
    if width < 0.6 * height:
        x0, x1 = (x0 + x1) / 2 - 0.3 * height, (x0 + x1) / 2 + 0.3 * height
    elif width > 3.0 * height:
        y0, y1 = (y0 + y1) / 2 - width / 6.0, (y0 + y1) / 2 + width / 6.0
    extent = (x0, x1, y0, y1)
    return extent, geo_chart(frames[0], extent), MapGeometry(tuple(markers), tuple(bearings), heading)


def panel_chart(panel: Panel, extent):
    """The chart of a panel's map framed on ``extent`` (m) when its raster has a geographic
    frame (:func:`bananagrid.geo.chart.chart`), else None."""
    frame = getattr(panel.raster, "frame", None)
    return None if frame is None else geo_chart(frame, extent)


def check_animation_options(out: str | os.PathLike, fps: float, dpi: int = 100) -> Path:
    """``out`` as a path, after checking (one-line errors, before any computing) that it names a
    GIF or an MP4, that ffmpeg is there for an MP4, that ``fps`` lies in (0, ``MAX_FPS``] and
    ``dpi`` in [20, 600]."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in ANIMATIONS:
        raise BananagridError(f"--animate {out}: an animation is a GIF or an MP4; give a name ending in .gif or .mp4")
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(fps) and 0.0 < fps <= MAX_FPS):
        raise BananagridError(f"--fps = {show(fps)}: frames per second must lie in (0, {MAX_FPS:g}]")
    if suffix == ".mp4" and ffmpeg_path() is None:
        raise BananagridError(f"--animate {out}: writing MP4 needs ffmpeg, which is not on PATH; install ffmpeg, or "
                              "give a name ending in .gif (written with Pillow)")
    check_picture_options(out.with_suffix(".png"), dpi)
    return out


def ffmpeg_path() -> str | None:
    """Where the ffmpeg that matplotlib would run is, or None."""
    matplotlib = importlib.import_module("matplotlib")
    return shutil.which(str(matplotlib.rcParams["animation.ffmpeg_path"]))


def write_animation(out: str | os.PathLike, frames: Sequence[Picture], *, mass_levels: Iterable[float] | None = None,
                    dpi: int = 100, fps: float = DEFAULT_FPS,
                    progress: Callable[[int, int, float], None] | None = None) -> Path:
    """An animation of ``frames`` (:func:`read_timeline`), one frame each, written atomically.

    Every frame is drawn by :func:`draw_picture`, as a still picture is, in one figure of one
    size: each panel framed on the union of its frames over the timeline, and every frame in one
    colour range, so that colours and places compare across frames.

    Parameters
    ----------
    out : path-like
        ``.gif`` (written with Pillow) or ``.mp4`` (with matplotlib's FFMpegWriter; needs ffmpeg).
    frames : sequence of Picture
        The frames, in order; each has the same layers.
    mass_levels : iterable of float, optional
        Probability-mass levels in (0, 1) (default: the first frame's).
    dpi : int
        Pixels per inch, 20 to 600.
    fps : float
        Frames per second, in (0, ``MAX_FPS``].
    progress : callable, optional
        Called after each frame with (frame number from 1, frame count, its time in s).

    Returns
    -------
    Path
        ``out``.
    """
    out = check_animation_options(out, fps, dpi)
    if not frames or not frames[0].panels:
        raise BananagridError(f"{out}: nothing to draw")
    levels = checked_levels(frames[0].mass_levels if mass_levels is None else mass_levels, key="--mass-levels")
    count = len(frames[0].panels)
    extents = []
    for k in range(count):
        boxes = np.array([map_frame(frame.panels[k].raster, levels) for frame in frames])
        extents.append((boxes[:, 0].min(), boxes[:, 1].max(), boxes[:, 2].min(), boxes[:, 3].max()))
    clim = shared_colour_range(colour_range(p.raster, levels) for frame in frames for p in frame.panels)
    charts = [panel_chart(panel, extent) for panel, extent in zip(frames[0].panels, extents)]  # one per layer
    overview = picture_overview(frames[0], extents)
    plt = pyplot(headless=True)
    _, _, size = picture_layout(extents + ([overview[0]] if overview else []))
    figure = plt.figure(figsize=size, layout="constrained")
    try:
        with atomic_write(out) as partial:
            if out.suffix.lower() == ".gif":
                _write_gif(partial, figure, frames, levels, clim, extents, (charts, overview), dpi, fps, progress)
            else:
                _write_mp4(partial, figure, frames, levels, clim, extents, (charts, overview), dpi, fps, progress)
    finally:
        plt.close(figure)
    return out


def _frame_time(frame: Picture) -> float:
    return max(p.t for p in frame.panels)


def _draw_frames(figure, frames, levels, clim, extents, charts, progress):
    """Each frame drawn on the cleared figure in turn (``charts``: the panels' charts and the
    overview); yields after each."""
    for k, frame in enumerate(frames):
        figure.clear()
        draw_picture(figure, frame, levels, clim=clim, extents=extents, charts=charts[0], overview=charts[1])
        yield
        if progress is not None:
            progress(k + 1, len(frames), _frame_time(frame))


def _write_gif(path, figure, frames, levels, clim, extents, charts, dpi, fps, progress) -> None:
    image_module = importlib.import_module("PIL.Image")  # installed with matplotlib
    figure.set_dpi(int(dpi))
    images = []
    for _ in _draw_frames(figure, frames, levels, clim, extents, charts, progress):
        figure.canvas.draw()
        figure.canvas.draw()  # the layout settles on the second pass
        rgba = np.asarray(figure.canvas.buffer_rgba())
        images.append(image_module.fromarray(rgba[..., :3].copy()).quantize(colors=256))
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], loop=0,
                   duration=max(20, round(1000.0 / fps)))


def _write_mp4(path, figure, frames, levels, clim, extents, charts, dpi, fps, progress) -> None:
    animation = importlib.import_module("matplotlib.animation")
    subprocess = importlib.import_module("subprocess")
    # H.264 in yuv420p (what every player reads) needs even sides: pad by a pixel where odd
    writer = animation.FFMpegWriter(fps=fps, codec="libx264", extra_args=[
        "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-f", "mp4"])
    try:
        with writer.saving(figure, str(path), int(dpi)):
            for _ in _draw_frames(figure, frames, levels, clim, extents, charts, progress):
                figure.canvas.draw()  # the layout settles before the frame is grabbed
                writer.grab_frame()
    except (subprocess.CalledProcessError, OSError) as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise BananagridError(f"--animate: ffmpeg failed writing the MP4 ({reason})") from None


def check_picture_options(out: str | os.PathLike, dpi: int) -> Path:
    """``out`` as a path, after checking that it names a PNG and that ``dpi`` is an integer in
    [20, 600] (one-line errors), so a command can refuse them before computing anything."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise BananagridError(f"-o {out}: the picture is a PNG; give a name ending in .png")
    if isinstance(dpi, bool) or not isinstance(dpi, (int, np.integer)) or not 20 <= dpi <= 600:
        raise BananagridError(f"--dpi = {show(dpi)}: must be an integer in [20, 600]")
    return out


def _panel_title(panel: Panel) -> str:
    """``layer (Model), t = 10 s``; no time for a timeless layer (a bearing fix at t = 0)."""
    provenance = panel.raster.provenance or {}
    model = provenance.get("model")
    title = f"{panel.layer} ({model})" if isinstance(model, str) and model else panel.layer
    timeless = "t" not in provenance and panel.t == 0.0
    when = utc_label(getattr(panel.raster, "frame", None), panel.t)
    title = title if timeless else f"{title}, t = {format_time(panel.t)}"
    return title if when is None else f"{title}\n{when}"


def _listed(times: Sequence[float]) -> str:
    return ", ".join(f"{u:g}" for u in times)


def _panels(path: Path, t: float | None, threads: int | None, step: float | None,
            every: bool = False) -> tuple[str, tuple, list[Panel]]:
    """The heading, mass levels and panels of a file (a scene computed at ``t``, or at every
    time with ``every``)."""
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return _from_scene(path, t, threads, step, every)
    if suffix == ".rrd":
        heading, found = path.stem, [Panel(r.layer, r.t, r.raster) for r in read_rasters(path)]
    elif suffix == ".nc":
        heading, found = _from_netcdf(path)
    else:
        heading, found = _from_npz(path)
    return heading, DEFAULT_MASS_LEVELS, found


def _from_scene(path: Path, t: float | None, threads: int | None,
                step: float | None, every: bool = False) -> tuple[str, tuple, list[Panel]]:
    scene = load_scene(path)
    if not scene.gridded:
        raise BananagridError(
            f"{path}: an [array] scene maps angular cells, not a grid, so it has no map to plot; run it "
            "and read its cell table in the recording (bananagrid inspect)"
        )
    if step is not None:
        scene = scene.with_step(positive("step", step))
    jobs = scene.jobs()
    times = sorted({time for _, time in jobs})
    wanted = times[-1] if t is None else t
    if not any(np.isclose(wanted, u, **_SAME_TIME) for u in times):
        raise BananagridError(f"--t = {show(t)}: {path} has times {_listed(times)} s")
    found = []
    for layer, time in jobs:
        if every or np.isclose(time, wanted, **_SAME_TIME):
            raster, _ = compute(scene, layer, time, threads=threads, model=layer.model(time))
            found.append(Panel(layer.name, time, raster))
    heading = scene.name if scene.title in ("", scene.name) else f"{scene.name}: {scene.title}"
    return heading, tuple(scene.mass_levels), found


def _from_netcdf(path: Path) -> tuple[str, list[Panel]]:
    """The maps of a NetCDF file ``run --netcdf`` wrote (:func:`bananagrid.geo.dataset.read_maps`)."""
    title, maps = read_maps(path)
    found = []
    for item in maps:
        described = item["grid"]
        grid = Grid(origin=tuple(described["origin"]), dx=described["dx"], dy=described["dy"],
                    nx=described["nx"], ny=described["ny"])
        frame = None if item["frame"] is None else GeoFrame.from_identity(item["frame"])
        raster = Raster(values=item["values"], grid=grid, mass=item["mass"], normalised=item["normalised"],
                        provenance=item["provenance"], frame=frame)
        found.append(Panel(item["layer"], item["t"], raster))
    return (f"{path.stem}: {title}" if title else path.stem), found


#: What reading a damaged or foreign .npz raises (zipfile, zlib, NumPy's header parser).
_NPZ_ERRORS = (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, zlib.error,
               NotImplementedError, OverflowError, MemoryError, IndexError, AttributeError)


def _from_npz(path: Path) -> tuple[str, list[Panel]]:
    """The layers of an ``.npz`` that ``run --npz`` wrote. Each member of the zip archive
    carries a CRC-32 of its bytes; every one is checked first (``testzip`` reads them all), so
    a damaged archive is an error before NumPy parses any header of it."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
        if bad is not None:
            raise zipfile.BadZipFile(f"bad CRC-32 for {bad}")
        with np.load(path, allow_pickle=False) as archive:
            provenance = json.loads(str(archive["provenance"]))
            x, y = archive["x"], archive["y"]
            arrays = {key: archive[key] for key in provenance["arrays"]}
    except _NPZ_ERRORS as exc:
        first = (str(exc).splitlines() or [""])[0]
        raise BananagridError(
            f"{path}: damaged, or not an .npz written by bananagrid run --npz ({type(exc).__name__}: {first})"
        ) from None
    try:  # the float64 grid of the provenance, checked against the cell centres
        described = provenance["grid"]
        grid = Grid(origin=tuple(described["origin"]), dx=described["dx"], dy=described["dy"], nx=described["nx"],
                    ny=described["ny"])
    except (KeyError, TypeError, BananagridError) as exc:
        raise BananagridError(f"{path}: no grid in its provenance ({type(exc).__name__}: {exc})") from None
    same = x.shape == grid.x.shape and y.shape == grid.y.shape
    if not (same and np.allclose(grid.x, x, rtol=0, atol=1e-6 * grid.dx) and np.allclose(grid.y, y, rtol=0, atol=1e-6 * grid.dy)):
        raise BananagridError(f"{path}: its x and y do not match the grid in its provenance")
    found = []
    for key, entry in provenance["arrays"].items():
        given = dict(entry.get("provenance") or {})
        try:  # the frame the provenance names (run writes it for a geographic scene)
            frame = GeoFrame.from_identity(given["geo"]) if isinstance(given.get("geo"), dict) else None
        except (KeyError, TypeError, ValueError, BananagridError) as exc:
            raise BananagridError(f"{path}: damaged geographic frame in its provenance ({type(exc).__name__}: "
                                  f"{(str(exc).splitlines() or [''])[0]})") from None
        raster = Raster(values=np.asarray(arrays[key], dtype=np.float64), grid=grid, mass=float(entry["mass"]),
                        normalised=bool(entry["normalised"]), provenance=given, frame=frame)
        found.append(Panel(entry["layer"], float(entry["t"]), raster))
    if not found:
        raise BananagridError(f"{path}: holds no layers")
    name, title = provenance.get("scene", path.stem), provenance.get("title", "")
    return (name if title in ("", name) else f"{name}: {title}"), found
