"""Pictures of a scene's layers without a viewer (``bananagrid plot``): from the scene itself
(computed as ``run`` computes it), from a recording ``run`` wrote, or from its ``.npz`` arrays or
CF NetCDF maps (``--netcdf``); one map per layer at one time, in one PNG written atomically.

Each map is :func:`bananagrid.plotting.plot_raster`'s: log10 density in km, the
probability-mass contours labelled with their areas, and what the layer's provenance names (a
bearing fix's sensors, bearing lines with +-2 sigma wedges and fix; a start and its heading), so
a recording or an ``.npz`` gives the same picture as its scene. Array scenes (``[array]``: cell
probabilities on an angular lattice, not a grid) are refused with a one-line message; their
recordings hold the cell table.
"""

from __future__ import annotations

import json
import os
import textwrap
import zipfile
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..contours import DEFAULT_MASS_LEVELS, mass_levels as checked_levels
from ..domains.grid import Grid
from ..geo.dataset import read_maps
from ..geo.frame import GeoFrame
from ..plotting import figure_layout, format_time, map_frame, plot_raster, pyplot
from ..recording.readback import read_rasters
from ..results import Raster
from ..validate import BananagridError, positive, regular_file, show
from .load import load_scene
from .run_grid import compute

__all__ = ["INPUTS", "Panel", "Picture", "check_picture_options", "read_picture", "write_picture"]

#: What ``bananagrid plot`` reads, by file suffix.
INPUTS = (".toml", ".rrd", ".npz", ".nc")

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
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix not in INPUTS:
        raise BananagridError(
            f"{path}: cannot plot a {suffix or 'suffix-less'} file; give one of {', '.join(INPUTS)} "
            "(a scene, or a recording, arrays or NetCDF maps written by bananagrid run)"
        )
    regular_file(path, "a file to plot")  # a FIFO would wait for a writer
    if t is not None and not (isinstance(t, (int, float)) and np.isfinite(t)):
        raise BananagridError(f"--t = {show(t)}: expected a finite time in seconds")
    if step is not None and suffix != ".toml":
        raise BananagridError(f"step = {show(step)}: only a scene (.toml) is computed at another step")
    levels = DEFAULT_MASS_LEVELS
    if suffix == ".toml":
        heading, levels, found = _from_scene(path, t, threads, step)
    elif suffix == ".rrd":
        heading, found = path.stem, [Panel(r.layer, r.t, r.raster) for r in read_rasters(path)]
    elif suffix == ".nc":
        heading, found = _from_netcdf(path)
    else:
        heading, found = _from_npz(path)
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
    rows, columns, size = figure_layout([map_frame(p.raster, levels) for p in picture.panels])
    figure, axes = plt.subplots(rows, columns, figsize=size, layout="constrained", squeeze=False)
    try:
        for ax, panel in zip(axes.flat, picture.panels):
            plot_raster(panel.raster, ax, mass_levels=levels, title=_panel_title(panel), markers=panel.markers)
        for ax in list(axes.flat)[len(picture.panels):]:
            ax.set_visible(False)
        figure.suptitle("\n".join(textwrap.wrap(picture.heading, max(30, int(size[0] / 0.085)))), fontsize=11)
        with atomic_write(out) as partial:
            figure.savefig(partial, format="png", dpi=int(dpi))
    finally:
        plt.close(figure)
    return out


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
    return title if timeless else f"{title}, t = {format_time(panel.t)}"


def _listed(times: Sequence[float]) -> str:
    return ", ".join(f"{u:g}" for u in times)


def _from_scene(path: Path, t: float | None, threads: int | None,
                step: float | None) -> tuple[str, tuple, list[Panel]]:
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
        if np.isclose(time, wanted, **_SAME_TIME):
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
        raster = Raster(values=np.asarray(arrays[key], dtype=np.float64), grid=grid, mass=float(entry["mass"]),
                        normalised=bool(entry["normalised"]), provenance=dict(entry.get("provenance") or {}))
        found.append(Panel(entry["layer"], float(entry["t"]), raster))
    if not found:
        raise BananagridError(f"{path}: holds no layers")
    name, title = provenance.get("scene", path.stem), provenance.get("title", "")
    return (name if title in ("", name) else f"{name}: {title}"), found
