"""Pictures of a scene's layers without a viewer: from the scene itself (computed as ``run``
computes it), from a recording ``run`` wrote, or from its ``.npz`` arrays; one panel per layer
at one time, written to a PNG atomically.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..contours import DEFAULT_MASS_LEVELS
from ..domains.grid import Grid
from ..plotting import plot_raster, pyplot
from ..recording.readback import read_rasters
from ..results import Raster
from ..validate import BananagridError, show
from .load import load_scene
from .presence import PresenceScene
from .run import compute

__all__ = ["INPUTS", "Panel", "panels", "write_picture"]

#: What ``bananagrid plot`` reads, by file suffix.
INPUTS = (".toml", ".rrd", ".npz")


@dataclass(frozen=True)
class Panel:
    """One map of a picture: a layer at one elapsed time, and the points to mark on it."""

    layer: str
    t: float
    raster: Raster
    markers: tuple = ()


def panels(source: str | os.PathLike, *, layers: Sequence[str] = (), t: float | None = None,
           threads: int | None = None) -> tuple[str, list[Panel]]:
    """The scene's name and its panels: every layer (or ``layers``) at time ``t`` (default: the
    last time).

    ``source`` is a scene ``.toml`` (its layers are computed), a recording ``.rrd`` or arrays
    ``.npz`` written by ``bananagrid run``.
    """
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix not in INPUTS:
        raise BananagridError(f"{path}: cannot plot a {suffix or 'suffix-less'} file; give one of {', '.join(INPUTS)}")
    if suffix == ".toml":
        name, found = _from_scene(path, t, threads)
    elif suffix == ".rrd":
        name, found = path.stem, [Panel(r.layer, r.t, r.raster) for r in read_rasters(path)]
    else:
        name, found = _from_npz(path)
    times = sorted({p.t for p in found})
    if t is None:
        t = times[-1]
    elif not any(np.isclose(t, u, rtol=1e-12, atol=1e-9) for u in times):
        raise BananagridError(f"--t = {show(t)}: {path} has times {', '.join(f'{u:g}' for u in times)} s")
    chosen = [p for p in found if np.isclose(p.t, t, rtol=1e-12, atol=1e-9)]
    names = list(dict.fromkeys(p.layer for p in chosen))
    for layer in layers:
        if layer not in names:
            raise BananagridError(f"--layer {show(layer)}: not a layer of {path} at t = {t:g} s; choose one of {', '.join(names)}")
    if layers:
        chosen = [p for p in chosen if p.layer in layers]
    return name, chosen


def write_picture(out: str | os.PathLike, title: str, chosen: Sequence[Panel], *,
                  mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS, dpi: int = 100) -> Path:
    """One PNG with a panel per layer (up to three per row), written atomically."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise BananagridError(f"-o {out}: the picture is a PNG; give a name ending in .png")
    if not (isinstance(dpi, int) and 20 <= dpi <= 600):
        raise BananagridError(f"--dpi = {show(dpi)}: must be an integer in [20, 600]")
    mass_levels = tuple(mass_levels)
    plt = pyplot()
    columns = min(3, len(chosen))
    rows = -(-len(chosen) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(5.5 * columns, 4.2 * rows), layout="constrained", squeeze=False)
    try:
        for ax, panel in zip(axes.flat, chosen):
            plot_raster(panel.raster, ax, mass_levels=mass_levels, title=f"{panel.layer}, t = {panel.t:g} s",
                        markers=panel.markers)
        for ax in list(axes.flat)[len(chosen):]:
            ax.set_visible(False)
        figure.suptitle(title)
        with atomic_write(out) as partial:
            figure.savefig(partial, format="png", dpi=dpi)
    finally:
        plt.close(figure)
    return out


def _from_scene(path: Path, t: float | None, threads: int | None) -> tuple[str, list[Panel]]:
    scene = load_scene(path)
    if isinstance(scene, PresenceScene):
        raise BananagridError(
            f"{path}: an [array] scene maps angular cells, not a grid; run it and look at the recording "
            "(its log10 table and the cells on the plane)"
        )
    jobs = scene.jobs()
    last = max(time for _, time in jobs) if t is None else t
    found = []
    for layer, time in jobs:
        if np.isclose(time, last, rtol=1e-12, atol=1e-9):
            model = layer.model(time)
            raster, _ = compute(scene, layer, time, threads=threads, model=model)
            found.append(Panel(layer.name, time, raster, _markers(model)))
    if not found:
        times = sorted({time for _, time in jobs})
        raise BananagridError(f"--t = {show(t)}: {path} has times {', '.join(f'{u:g}' for u in times)} s")
    return scene.name, found


def _markers(model) -> tuple:
    """Points worth marking: a bearing fix's stations and fix, else a motion model's start."""
    sensors = getattr(model, "sensors", None)
    if sensors is not None:
        marks = [(float(x), float(y), f"sensor {k}") for k, (x, y) in enumerate(np.asarray(sensors))]
        fix = getattr(model, "fix", None)
        if fix is not None and not callable(fix):
            marks.append((float(fix[0]), float(fix[1]), "fix"))
        return tuple(marks)
    pose = getattr(model, "pose", None)
    origin = getattr(pose, "origin", None)
    return () if origin is None else ((float(origin[0]), float(origin[1]), "start"),)


def _from_npz(path: Path) -> tuple[str, list[Panel]]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            provenance = json.loads(str(archive["provenance"]))
            x, y = archive["x"], archive["y"]
            arrays = {key: archive[key] for key in provenance["arrays"]}
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        raise BananagridError(f"{path}: not a bananagrid .npz ({type(exc).__name__}: {exc})") from None
    dx = float(x[1] - x[0]) if len(x) > 1 else float(provenance["grid"]["dx"])
    dy = float(y[1] - y[0]) if len(y) > 1 else float(provenance["grid"]["dy"])
    grid = Grid(origin=(float(x[0]) - dx / 2, float(y[0]) - dy / 2), dx=dx, dy=dy, nx=len(x), ny=len(y))
    found = []
    for key, entry in provenance["arrays"].items():
        raster = Raster(values=np.asarray(arrays[key], dtype=np.float64), grid=grid, mass=float(entry["mass"]),
                        normalised=bool(entry["normalised"]), provenance=dict(entry.get("provenance", {})))
        found.append(Panel(entry["layer"], float(entry["t"]), raster))
    return provenance["scene"], found
