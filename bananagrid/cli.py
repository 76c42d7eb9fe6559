"""Command line: ``bananagrid run``, ``examples``, ``plot``, ``inspect``, ``compare``, ``sweep`` and ``bench``.

Errors a user can fix (bad scene, missing file, unwritable directory) are printed as one line,
``bananagrid: error: MESSAGE``, with exit code 2 and no traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import threading
import time
import tomllib
import warnings
from dataclasses import replace
from pathlib import Path
from typing import TextIO

import numpy as np

from .analysis.compare import compare
from .analysis.sweep import FIGURE7_LEVELS, sweep
from .atomic import (OutputSet, OutputWriteError, Terminated, check_target, check_writable,
                     signals_as_exceptions)
from .bench import runner as bench
from .contours import DEFAULT_LEVELS, format_area, mass_levels
from .engine.cluster import CONNECT_SECONDS, check_memory_limit, check_scheduler, check_workers, dask_client, worker_need
from .engine.memory import memory_limit
from .engine.tiles import DEFAULT_CHUNK
from .engine.warp_runtime import compile_notice
from .engine.work import work_limit
from .geo.zarr_store import check_store_target
from .recording.compare import write_compare_recording, write_sweep_recording
from .recording.core import recording_id_for
from .recording.inspect import cell_map_summaries, format_inspection, inspect_recording, json_ready, layer_summaries
from .scenes.examples import example_names, example_path, example_title, scene_source
from .scenes.load import Scene, load_scene
from .scenes.pictures import (
    DEFAULT_FPS,
    MAX_FPS,
    check_animation_options,
    check_picture_options,
    read_picture,
    read_timeline,
    write_animation,
    write_picture,
)
from .scenes.run_tiled import (
    check_tiled, format_tiled_summary, posterior_worker_need, run_scene_tiled, tiled_maps, tiled_posteriors,
)
from .scenes.run_evidence import evidence_paths
from .scenes.run_plan import plan_paths, sweep_notice
from .scenes.run import (RUN_ONLY_PROVENANCE, check_exports, check_run_memory, check_run_work, compute, export_paths,
                         plan_outputs, run_scene)
from .validate import BananagridError, positive
from .version import __version__

__all__ = ["main", "build_parser"]

#: Exit codes: success, a user error (also argparse's usage errors), an interrupt.
OK, USER_ERROR, INTERRUPTED = 0, 2, 130


#: ``bananagrid inspect --json``: what scripts get (the help's epilog; the docs repeat it).
INSPECT_JSON_SCHEMA = """\
--json prints a list, one object per file (numbers as numbers, whole counts as integers, NaN as null):
  path, application_id, recording_id, blueprint (bool)
  layers: per density layer and time, by time then layer:
    layer, entity, t [s], mass (captured, before normalising), normalised,
    peak [m^-2], peak_x, peak_y [m, the cell centre; x east, y north],
    peak_lat, peak_lon [deg], utc (t as ISO 8601), crs: for a geographic scene, else null,
    grid {origin [m], dx, dy, nx, ny},
    regions: per level {probability, reached, density [m^-2, the boundary], enclosed, cells,
             area [m^2], area_km2}
  cell_maps: per angular cell map and time:
    entity, t, geometry, cells, region_probability, total, peak [cell probability],
    peak_azimuth_deg, peak_elevation_deg, peak_x, peak_y, peak_z [m, array frame],
    regions: per level {probability, reached, cell_probability, enclosed, cells}
  timelines: {name: {kind, count, min, max, values}}  (seconds for durations)
  entities: {path: {archetypes, components, static_rows, temporal_rows,
                    image_shapes, value_range, non_finite, scalars, values}}
"""


def main(argv: list[str] | None = None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    parser, commands = build_parser()
    with warnings.catch_warnings():
        warnings.showwarning = _warning_printer()
        try:
            args, rest = parser.parse_known_args(argv)
            if args.command == "bench":
                code = _bench(rest)
            else:
                if rest:
                    commands[args.command].error(f"unrecognized arguments: {' '.join(rest)}")
                with signals_as_exceptions(), native_log_held():
                    code = args.handler(args)
            sys.stdout.flush()  # here a reader that left raises below, not in the interpreter's exit
            return code
        except SystemExit as exc:  # argparse: --help (0) and usage errors (2)
            return exc.code if isinstance(exc.code, int) else USER_ERROR
        except BrokenPipeError:  # the reader left (`| head`): stop quietly, as cat does
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # the exit's own flush must not fail again
            return OK
        except (BananagridError, OSError, tomllib.TOMLDecodeError) as exc:
            print(f"bananagrid: error: {_one_line(exc)}", file=sys.stderr)
            return USER_ERROR
        except KeyboardInterrupt:
            print("bananagrid: interrupted", file=sys.stderr)
            return INTERRUPTED
        except Terminated as exc:  # SIGTERM, SIGHUP: temporary files are already removed
            print(f"bananagrid: terminated by {exc.name}", file=sys.stderr)
            return 128 + exc.signum


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The top-level parser and its subcommand parsers by name."""
    parser = argparse.ArgumentParser(
        prog="bananagrid",
        description="Probability maps from target-motion models, rasterised and recorded for rerun.",
    )
    parser.add_argument("--version", action="version", version=f"bananagrid {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    run = sub.add_parser(
        "run", help="rasterise scene files into .rrd recordings",
        description="Rasterise every layer of each scene at every time and write OUT/NAME.rrd "
        "(and OUT/NAME.npz with --npz; the map files of --netcdf, --geotiff, --geojson and --kml, which need "
        "the geo extra). Progress goes to stderr, a summary table to stdout.",
    )
    run.add_argument("scenes", nargs="*", metavar="SCENE.toml", type=Path, help="scene files")
    run.add_argument("--example", action="append", default=[], metavar="NAME",
                     help="also run the bundled scene NAME (repeatable; `bananagrid examples` lists them)")
    run.add_argument("--out", default="out", metavar="DIR",
                     help="output directory, created if missing (default: ./out)")
    run.add_argument("--npz", action="store_true", help="also write the arrays to NAME.npz")
    run.add_argument("--netcdf", action="store_true",
                     help="also write NAME.nc: CF-1.10 NetCDF (x, y; with [geo] lat, lon, CRS and UTC times)")
    run.add_argument("--geotiff", action="store_true",
                     help="also write NAME.tif: one georeferenced float32 band per layer and time")
    run.add_argument("--geojson", action="store_true",
                     help="also write NAME-areas.geojson: the probability-mass regions as WGS84 polygons (needs [geo])")
    run.add_argument("--kml", action="store_true",
                     help="also write NAME.kml for Google Earth and chart plotters: the probability-mass regions, "
                     "styled per level, and the fix and stations as placemarks (needs [geo])")
    run.add_argument("--step", type=float, metavar="S",
                     help="override the grid step of every scene, m (e.g. for a quick look)")
    run.add_argument("--threads", type=int, metavar="N",
                     help="CPU threads per rasterisation (default: every core)")
    run.add_argument("--max-memory", type=float, metavar="GB",
                     help="memory a scene's run may take, GB (default: what the system has available); "
                     "a larger estimate is refused before computing")
    run.add_argument("--max-seconds", type=float, metavar="S",
                     help="computing a scene's run may take, wall-clock seconds (default 3600; inf for no "
                     "limit); a larger estimate is refused before computing")
    run.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    tiles = run.add_argument_group(
        "tiles on a Dask cluster (the cluster extra)",
        "With --zarr the scene's maps are computed in tiles by Dask workers and written to one Zarr store, "
        "block by block (the grid may exceed memory: up to 2**38 cells); no .rrd is written. Tiles the "
        "model proves below 1e-13 of its peak are not computed. The maps are raw densities with each "
        "layer's captured mass beside it (LAYER_mass). A scene's [[evidence]] is taken: each map's posterior "
        "(LAYER_posterior), POD map (LAYER_pod), POS and each search's POS are computed in tiles too and "
        "stored as in the NetCDF export (--netcdf). A [plan] needs its map in memory: refused with --zarr.",
    )
    tiles.add_argument("--zarr", metavar="OUT.zarr",
                       help="write the scene's maps to this Zarr store (one scene), read with xarray.open_zarr")
    tiles.add_argument("--chunks", type=int, default=DEFAULT_CHUNK, metavar="N",
                       help=f"tile side, cells (default {DEFAULT_CHUNK}; a multiple of 32 for Butterly)")
    tiles.add_argument("--workers", type=int, metavar="N",
                       help="worker processes of the local cluster (default: one per core)")
    tiles.add_argument("--memory-limit", metavar="SIZE",
                       help="memory per local worker, e.g. 4GiB (default: the machine's, shared); at least what a "
                       "worker needs for one block (about 0.5 GB and 32 bytes per block cell, over Dask's pause fraction)")
    tiles.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on the existing Dask cluster at ADDRESS (tcp://host:8786) instead of a local one")
    tiles.add_argument("--connect-timeout", type=float, metavar="S",
                       help=f"seconds to wait for the scheduler at --scheduler to answer (default {CONNECT_SECONDS:g})")
    run.set_defaults(handler=_run)

    examples = sub.add_parser(
        "examples", help="list the bundled example scenes",
        description="List the scenes installed with the package (name and title), or print one "
        "of them to copy and edit (`bananagrid examples --show figure1 > mine.toml`). Run one with "
        "`bananagrid run --example NAME`; `compare` and `plot` take --example NAME too.",
    )
    examples.add_argument("--show", metavar="NAME", help="print the scene file NAME instead of the list")
    examples.set_defaults(handler=_examples)

    plot = sub.add_parser(
        "plot", help="draw a scene's maps to a PNG, or animate its timeline (needs matplotlib: the plot extra)",
        description="Draw every layer (or --layer) at the last time (or --t) as log10 maps, north up, "
        "with labelled probability-mass contours and their key, one panel per layer in one colour range "
        "with one colour bar. A geographic scene ([geo]) is drawn as a chart: latitude and longitude lines "
        "and labels, the land (bundled Natural Earth data, no download), a km scale bar and the UTC time; "
        "other scenes have km axes. --animate OUT.gif draws one frame per time of the scene's timeline "
        "(GIF with Pillow; OUT.mp4 needs ffmpeg). "
        "INPUT is a scene .toml (computed as run does), or a .rrd, .npz or .nc written by run.",
    )
    plot.add_argument("input", nargs="?", metavar="INPUT", type=Path,
                      help="SCENE.toml, FILE.rrd, FILE.npz or FILE.nc (or --example)")
    plot.add_argument("--example", metavar="NAME",
                      help="the bundled scene NAME instead of INPUT (`bananagrid examples` lists them)")
    plot.add_argument("-o", "--output", type=Path, metavar="OUT.png", help="the PNG to write (this, --animate, or both)")
    plot.add_argument("--animate", type=Path, metavar="OUT.gif",
                      help="also, or instead, an animation with one frame per time: OUT.gif (Pillow) or OUT.mp4 "
                      "(needs ffmpeg); every frame in one colour range and frame; a line per frame on stderr")
    plot.add_argument("--fps", type=float, default=DEFAULT_FPS, metavar="F",
                      help=f"frames per second of --animate, in (0, {MAX_FPS:g}] (default {DEFAULT_FPS:g})")
    plot.add_argument("--layer", action="append", default=[], metavar="NAME", help="only this layer (repeatable)")
    plot.add_argument("--t", type=float, metavar="T", help="elapsed time of the PNG, s (default: the last)")
    plot.add_argument("--mass-levels", metavar="P1,P2,...",
                      help="probability-mass contours, each in (0, 1) (default: a scene's output.mass_levels, "
                      "else 0.5,0.9,0.95,0.99)")
    plot.add_argument("--dpi", type=int, default=100, metavar="N", help="pixels per inch, 20 to 600 (default 100)")
    plot.add_argument("--step", type=float, metavar="S", help="compute a scene on cells of S m (a quick look)")
    plot.add_argument("--threads", type=int, metavar="N", help="CPU threads for a scene (default: every core)")
    plot.set_defaults(handler=_plot)

    inspect = sub.add_parser(
        "inspect", help="say where the target is in a recording, and what it holds",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Read .rrd recordings written by `bananagrid run` without a viewer.\n\n"
        "Per density layer and time: the captured mass, the peak density and where it is (its cell\n"
        "centre, x east, y north, m) and the probability-mass (highest-density) regions: what they\n"
        "hold, their area (km², m²) and cells. Per angular cell map (an array scene): the peak cell\n"
        "probability, its direction and cell, the regions in cells. Then the timelines and every\n"
        "entity with its latest values.",
        epilog=INSPECT_JSON_SCHEMA,
    )
    inspect.add_argument("files", nargs="+", metavar="FILE.rrd", type=Path, help="recordings")
    inspect.add_argument("--json", action="store_true", help="print all of it as one JSON list (see below)")
    inspect.add_argument("--mass-levels", metavar="P1,P2,...", default="0.5,0.9,0.95,0.99",
                         help="probability-mass regions reported, each in (0, 1) (default 0.5,0.9,0.95,0.99)")
    inspect.set_defaults(handler=_inspect)

    compare = sub.add_parser(
        "compare", help="compare two layers of a scene (Tables 1 and 2, goodness, Bhattacharyya)",
        description="Rasterise two layers of a scene (SCENE.toml, or --example NAME) on its grid, "
        "print the table of Tables 1 and 2 "
        "of the polar-banana paper (reference mass inside each contour, largest relative error of "
        "the model inside it), the goodness of Section 6.1 and the Bhattacharyya coefficient, and "
        "write OUT/NAME-MODEL-vs-REFERENCE.rrd with both layers and the relative-error map.",
    )
    compare.add_argument("scene", nargs="?", metavar="SCENE.toml", type=Path, help="scene file (or --example)")
    compare.add_argument("--example", metavar="NAME",
                         help="the bundled scene NAME instead of a file (`bananagrid examples` lists them)")
    compare.add_argument("--reference", required=True, metavar="LAYER", help="the reference layer (truth)")
    compare.add_argument("--model", required=True, metavar="LAYER", help="the layer compared with it")
    compare.add_argument("--t", type=float, metavar="T",
                         help="elapsed time, s (default: the layers' own, or the scene's only time)")
    compare.add_argument("--threshold", type=float, default=0.05, metavar="X",
                         help="relative error that ends the goodness contour (default 0.05)")
    compare.add_argument("--levels", metavar="L1,L2,...",
                         help="contour levels, m^-2 (default: the scene's contour_levels)")
    compare.add_argument("--step", type=float, metavar="S", help="override the grid step, m")
    compare.add_argument("--out", default="out", metavar="DIR",
                         help="output directory, created if missing (default: ./out)")
    compare.add_argument("--threads", type=int, metavar="N", help="CPU threads (default: every core)")
    compare.set_defaults(handler=_compare)

    sweep = sub.add_parser(
        "sweep", help="the Figure 7 study: goodness over sigma_a t / v0 and sigma_omega t",
        description="Goodness (Section 6.1) of the improved polar approximation, exact CAT as truth, "
        "over n x n settings: sigma_a t / v0 in (0, 0.2], sigma_omega t in (0, 75] deg (cell-centred). "
        "Writes OUT/sweep.rrd (the map with Figure 7's contour levels) and OUT/sweep.npz, and "
        "checks the paper's claim (sigma_a t / v0 < 0.1 and sigma_omega t < 42 deg => >= 99.9%%).",
    )
    sweep.add_argument("--n", type=int, default=50, help="settings per axis (default 50; the paper used 200)")
    sweep.add_argument("--threshold", type=float, default=0.05, metavar="X",
                       help="relative error that ends the goodness contour (default 0.05)")
    sweep.add_argument("--out", default="out", metavar="DIR",
                       help="output directory, created if missing (default: ./out)")
    sweep.add_argument("--threads", type=int, metavar="N", help="CPU threads (default: every core)")
    sweep.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    sweep.set_defaults(handler=_sweep)

    # bench parses its own options (its --help included): everything after it is passed on.
    bench = sub.add_parser("bench", add_help=False, help="throughput against a NumPy baseline")
    bench.set_defaults(handler=None)
    return parser, {"run": run, "examples": examples, "plot": plot, "inspect": inspect, "compare": compare, "sweep": sweep,
                    "bench": bench}


# --- subcommands ------------------------------------------------------------------------------


def _run(args: argparse.Namespace) -> int:
    """``bananagrid run``: load and check every scene first, then run them in order."""
    if args.threads is not None and args.threads < 1:
        raise BananagridError(f"--threads = {args.threads}: must be >= 1")
    if args.step is not None:
        positive("--step", args.step)
    args.out = _path_option(args.out, "--out")
    if args.zarr is not None:
        args.zarr = _path_option(args.zarr, "--zarr")
    if args.out.exists() and not args.out.is_dir():
        raise BananagridError(f"--out {args.out}: exists and is not a directory")
    paths = [*args.scenes, *(example_path(name) for name in args.example)]
    if not paths:
        raise BananagridError("run: give at least one SCENE.toml or --example NAME (`bananagrid examples` lists them)")
    if args.zarr is not None:
        return _run_tiled(args, paths)
    tiled_only = [f"--{k.replace('_', '-')}" for k in ("workers", "memory_limit", "scheduler", "connect_timeout")
                  if getattr(args, k) is not None]
    if tiled_only:
        raise BananagridError(f"{', '.join(tiled_only)}: only with --zarr (tiles on a Dask cluster)")
    scenes = [load_scene(path) for path in paths]
    if args.step is not None:
        scenes = [scene.with_step(args.step) for scene in scenes]
    _check_unique_names(scenes)
    exports = {"netcdf": args.netcdf, "geotiff": args.geotiff, "geojson": args.geojson, "kml": args.kml}
    limit = None if args.max_memory is None else memory_limit(args.max_memory)
    max_seconds = None if args.max_seconds is None else work_limit(args.max_seconds)
    for scene in scenes:  # every scene's checks before any computing
        check_exports(scene, **exports)
        check_run_memory(scene, exports=any(exports.values()), limit=limit)
        check_run_work(scene, threads=args.threads, limit=max_seconds)
    args.out.mkdir(parents=True, exist_ok=True)
    check_writable(args.out)
    for scene in scenes:  # and every file's target: nothing of anyone's is replaced but a regular file
        plan_outputs(scene, args.out, npz=args.npz, **exports)
    rows, written = [], []
    for scene in scenes:
        progress = None if args.quiet else _Progress(scene.name, sys.stderr)
        failed = True
        notice = compile_notice.set(None if progress is None else progress.compiling)
        sweeps = sweep_notice.set(None if progress is None else progress.note)
        try:
            rows += run_scene(scene, args.out, npz=args.npz, threads=args.threads, progress=progress,
                              max_memory=limit, max_seconds=max_seconds, **exports)
            failed = False
        finally:
            sweep_notice.reset(sweeps)
            compile_notice.reset(notice)
            if progress is not None:
                progress.close()
            if failed and written:  # the scenes before this one are complete: say so
                print(f"bananagrid: written before the error: {', '.join(map(str, written))}", file=sys.stderr)
        written.append(args.out / f"{scene.name}.rrd")
        if args.npz:
            written.append(args.out / f"{scene.name}.npz")
        written += export_paths(scene.name, args.out, **exports, cell_probabilities=scene.cell_probabilities,
                                evidence=bool(scene.evidence)).values()
        written += plan_paths(scene, args.out, geojson=args.geojson)
        written += evidence_paths(scene, args.out, geojson=args.geojson)
    print(format_summary(rows))
    print()
    for path in written:
        print(f"wrote {path}")
    return OK


def _run_tiled(args: argparse.Namespace, paths: list[Path]) -> int:
    """``bananagrid run SCENE --zarr OUT.zarr``: one scene in tiles on a Dask cluster, into Zarr."""
    if len(paths) != 1:
        raise BananagridError(f"--zarr {args.zarr}: writes one scene's store; {len(paths)} scenes given")
    combined = [f"--{k}" for k in ("npz", "netcdf", "geotiff", "geojson", "kml") if getattr(args, k)]
    if combined:
        raise BananagridError(f"--zarr cannot be combined with {', '.join(combined)} (those files hold a grid in memory)")
    if args.threads is not None:
        raise BananagridError("--threads does not apply to --zarr: Dask runs the tiles (--workers N)")
    if args.chunks < 1:
        raise BananagridError(f"--chunks = {args.chunks}: must be >= 1")
    if not args.zarr.parent.is_dir():
        raise BananagridError(f"--zarr {args.zarr}: directory {args.zarr.parent} does not exist")
    check_store_target(args.zarr)  # a file, a link or someone else's directory there: refused now
    scene = load_scene(paths[0], tiled=True)
    if args.step is not None:
        scene = scene.with_step(args.step, tiled=True)
    check_tiled(scene)
    max_seconds = None if args.max_seconds is None else work_limit(args.max_seconds)
    panels = tiled_maps(scene, args.chunks, max_seconds=max_seconds)  # every check before a cluster starts
    posteriors = tiled_posteriors(scene, args.chunks, max_seconds=max_seconds)  # the evidence's checks too
    timeout = _check_cluster(args, panels, [posterior_worker_need(job) for job in posteriors])
    with dask_client(workers=args.workers, memory_limit=args.memory_limit, scheduler=args.scheduler,
                     timeout=timeout) as client:
        if not args.quiet:
            where = args.scheduler or f"a local cluster of {len(client.scheduler_info()['workers'])} workers"
            link = client.dashboard_link if args.scheduler else None
            print(f"bananagrid: {scene.name}: tiles on {where}" + (f" (dashboard {link})" if link else ""),
                  file=sys.stderr)
        rows = run_scene_tiled(scene, args.zarr, args.chunks, progress=not args.quiet, max_seconds=max_seconds)
    print("\n".join([format_tiled_summary(rows), *format_evidence(rows)]))
    print()
    print(f"wrote {args.zarr}")
    return OK


def _check_cluster(args: argparse.Namespace, panels, posterior_needs=()) -> float:
    """The cluster options of ``run --zarr``, checked before any worker starts or any connection is
    kept: the scheduler answers as one, or the workers' memory holds a block (of a map, or of a
    posterior: ``posterior_needs``, bytes). Returns the timeout."""
    if args.connect_timeout is not None and args.scheduler is None:
        raise BananagridError("--connect-timeout: only with --scheduler")
    timeout = CONNECT_SECONDS if args.connect_timeout is None else positive("--connect-timeout", args.connect_timeout)
    if args.scheduler is not None:
        if args.workers is not None or args.memory_limit is not None:
            raise BananagridError("--scheduler: an existing cluster has its own workers and memory limits; "
                                  "give --workers and --memory-limit only for a local cluster")
        check_scheduler(args.scheduler, timeout=timeout, name="--scheduler")
        return timeout
    check_workers(args.workers, name="--workers")
    needs = [(worker_need(t.chunks, t.values.dtype, t.provenance["computed_in"]), t.chunks) for _, _, t in panels]
    needs += [(need, panels[0][2].chunks) for need in posterior_needs]
    need, (rows, cols) = max(needs, key=lambda pair: pair[0])
    check_memory_limit(args.memory_limit, need=need, name="--memory-limit", what=f"a block of {rows} x {cols} cells")
    return timeout


def _examples(args: argparse.Namespace) -> int:
    """``bananagrid examples``: the bundled scenes with their titles, or one scene's text."""
    if args.show is not None:
        print(example_path(args.show, key="--show").read_text(), end="")
        return OK
    names = example_names()
    width = max(map(len, names), default=0)
    for name in names:
        print(f"{name.ljust(width)}  {example_title(name)}")
    return OK


def _plot(args: argparse.Namespace) -> int:
    """``bananagrid plot``: one PNG of a scene's layers at one time, and/or an animation over its
    times (:mod:`bananagrid.scenes.pictures`); every option checked before any computing."""
    levels = None
    if args.mass_levels is not None:
        levels = mass_levels(_split(args.mass_levels, "--mass-levels"), key="--mass-levels")
    if args.threads is not None and args.threads < 1:
        raise BananagridError(f"--threads = {args.threads}: must be >= 1")
    if args.step is not None:
        positive("--step", args.step)
    if args.output is None and args.animate is None:
        raise BananagridError("plot: nothing to write; give -o OUT.png, --animate OUT.gif, or both")
    if args.output is None and args.t is not None:
        raise BananagridError(f"--t = {args.t:g}: an animation shows every time; --t picks the time of the PNG (-o)")
    for path, what in ((args.output, "PNG"), (args.animate, "animation")):
        if path is None:
            continue
        if what == "PNG":
            check_picture_options(path, args.dpi)
        else:
            check_animation_options(path, args.fps, args.dpi)
        check_writable(path.parent if str(path.parent) else Path("."))
        check_target(path, what)  # a directory or a link there: refused before computing
    source = scene_source(args.input, args.example, what="INPUT")
    if args.animate is not None:
        frames = read_timeline(source, layers=args.layer, threads=args.threads, step=args.step)

        def progress(k: int, n: int, t: float) -> None:
            print(f"frame {k}/{n}: t = {t:g} s", file=sys.stderr, flush=True)

        out = write_animation(args.animate, frames, mass_levels=levels, dpi=args.dpi, fps=args.fps, progress=progress)
        print(f"wrote {out} ({len(frames)} frame{'' if len(frames) == 1 else 's'})")
        if args.output is not None:
            picture = frames[-1] if args.t is None else \
                read_picture(source, layers=args.layer, t=args.t, threads=args.threads, step=args.step)
            print(f"wrote {write_picture(args.output, picture, mass_levels=levels, dpi=args.dpi)}")
        return OK
    picture = read_picture(source, layers=args.layer, t=args.t, threads=args.threads, step=args.step)
    out = write_picture(args.output, picture, mass_levels=levels, dpi=args.dpi)
    print(f"wrote {out}")
    return OK


def _split(text: str, option: str) -> list[float]:
    """A comma-separated list of numbers, or a one-line error naming the option."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise BananagridError(f"{option} = {text!r}: expected numbers separated by commas") from None


def _inspect(args: argparse.Namespace) -> int:
    """``bananagrid inspect``: per file where the target is in each density layer or cell map
    (:func:`bananagrid.recording.inspect.layer_summaries`, ``cell_map_summaries``) and what the
    recording holds (``inspect_recording``), as text or, with ``--json``, as one JSON list."""
    levels = mass_levels(_split(args.mass_levels, "--mass-levels"), key="--mass-levels")
    infos = []
    for path in args.files:
        info = inspect_recording(path)
        info["layers"] = layer_summaries(path, levels)
        info["cell_maps"] = cell_map_summaries(path, levels)
        infos.append(info)
    if args.json:
        print(json.dumps(json_ready(infos), indent=1, allow_nan=False))
    else:
        print("\n\n".join(format_inspection(info) for info in infos))
    return OK


def _path_option(value: str | Path, option: str) -> Path:
    """A path option's value; an empty one (which would mean the current directory) is refused."""
    if str(value) == "":
        raise BananagridError(f"{option} {str(value)!r}: an empty path; give a directory or file name "
                              f"(e.g. {option} out; {option} . for the current directory)")
    return Path(value)


def _out_dir(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise BananagridError(f"--out {out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    check_writable(out)


def _threads(threads) -> None:
    if threads is not None and threads < 1:
        raise BananagridError(f"--threads = {threads}: must be >= 1")


def _compare(args: argparse.Namespace) -> int:
    """``bananagrid compare``: two layers of a scene, their table and the error map."""
    _threads(args.threads)
    args.out = _path_option(args.out, "--out")
    scene = load_scene(scene_source(args.scene, args.example))
    if args.step is not None:
        scene = scene.with_step(positive("--step", args.step))
    layers = {layer.name: layer for layer in scene.layers}
    for option in ("reference", "model"):
        name = getattr(args, option)
        if name not in layers:
            raise BananagridError(f"--{option} {name}: no such layer in {scene.source} (layers: {', '.join(layers)})")
    reference, model = layers[args.reference], layers[args.model]
    t = _compare_time(scene, reference, model, args.t)
    # the scene's fixed levels, else Figure 7's densities (compare reports fixed levels)
    levels = (scene.levels or DEFAULT_LEVELS) if args.levels is None else _parse_levels(args.levels)
    _out_dir(args.out)  # and the recording's target, before computing
    path = check_target(args.out / f"{scene.name}-{model.name}-vs-{reference.name}.rrd", "recording")
    plain = _raw(scene)
    ref_raster, _ = compute(plain, reference, t, threads=args.threads)
    model_raster, _ = compute(plain, model, t, threads=args.threads)
    comparison = compare(ref_raster, model_raster, levels=levels, threshold=args.threshold)
    write_compare_recording(
        path, recording_id=recording_id_for(f"{scene.text}\n{reference.name}\n{model.name}\n{t}\n{levels}"),
        scene_text=scene.text, names=(reference.name, model.name),
        rasters=tuple(_recordable(r) for r in (ref_raster, model_raster)),
        comparison=comparison, levels=levels, colormap=scene.colormap,
    )
    print(f"{scene.name}: {model.name} against {reference.name} at t = {t:g} s on {scene.grid.nx} x {scene.grid.ny} cells "
          f"(reference captures {ref_raster.mass:.9f} of its mass)")
    print(comparison.table())
    print(f"\nwrote {path}")
    return OK


def _recordable(raster):
    """The raster without run-dependent provenance (timings, threads): equal runs, equal recordings."""
    return replace(raster, provenance={k: v for k, v in raster.provenance.items() if k not in RUN_ONLY_PROVENANCE})


def _raw(scene):
    """The scene with rasters left raw: the table divides by the reference's captured mass."""
    return replace(scene, normalise=False)


def _compare_time(scene: Scene, reference: str, model: str, t: float | None) -> float:
    if t is not None:
        return positive("--t", t)
    times = scene.times or tuple(dict.fromkeys(layer.params.get("t") for layer in (reference, model)))
    times = tuple(x for x in times if x is not None) or (0.0,)
    if len(times) != 1:
        raise BananagridError(f"--t: the layers have several elapsed times ({', '.join(f'{x:g}' for x in times)}); choose one")
    return times[0]


def _parse_levels(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise BananagridError(f"--levels {text}: expected comma-separated densities (m^-2)") from None
    if not values:
        raise BananagridError(f"--levels {text!r}: expected at least one density (m^-2)")
    return tuple(positive(f"--levels[{k}]", v) for k, v in enumerate(values))


def _sweep(args: argparse.Namespace) -> int:
    """``bananagrid sweep``: the Figure 7 study."""
    _threads(args.threads)
    args.out = _path_option(args.out, "--out")
    _out_dir(args.out)
    outputs = OutputSet()  # both checked before computing, replaced together
    rrd = outputs.add(args.out / "sweep.rrd", "recording")
    npz = outputs.add(args.out / "sweep.npz", ".npz arrays")

    def progress(done, total):
        if not args.quiet:
            print(f"\r[{done}/{total}] sigma_omega t rows", end="" if done < total else "\n", file=sys.stderr, flush=True)

    result = sweep(args.n, threshold=args.threshold, threads=args.threads, progress=progress)
    claim = result.claim()
    with outputs:
        write_sweep_recording(rrd, result, recording_id=recording_id_for(f"sweep {args.n} {args.threshold}"),
                              levels=FIGURE7_LEVELS, stage=outputs.stage)
        try:
            with outputs.stage(npz) as tmp, open(tmp, "wb") as fh:
                np.savez(fh, alpha=result.alpha, beta=result.beta, goodness=result.goodness,
                         threshold=result.threshold, contour_999_beta_deg=claim["contour_999_beta_deg"])
        except OSError as exc:
            raise OutputWriteError(f"{npz}: cannot write the .npz arrays ({exc.strerror or exc})") from None
        outputs.commit()
    print(f"{args.n} x {args.n} settings in {result.seconds:.1f} s; goodness from {result.goodness.min():.6f} "
          f"to {result.goodness.max():.6f}")
    verdict = "holds" if claim["claim_holds_on_grid"] else "does NOT hold"
    print(f"claim (sigma_a t / v0 < 0.1 and sigma_omega t < 42 deg => >= 99.9%): least goodness there "
          f"{claim['least_goodness_in_claim_region']:.6f}: {verdict} on this grid")
    print("99.9% contour (largest sigma_omega t with goodness >= 0.999, by sigma_a t / v0): " + ", ".join(
        f"{a:.3f}: {b:.1f} deg" for a, b in zip(result.alpha, claim["contour_999_beta_deg"])
        if not np.isnan(b))
    )
    print(f"wrote {rrd}\nwrote {npz}")
    return OK


def _bench(argv: list[str]) -> int:
    """``bananagrid bench``: delegated to :func:`bananagrid.bench.runner.main` with the rest of argv."""
    return bench.main(list(argv))


# --- output -----------------------------------------------------------------------------------

SUMMARY_COLUMNS = (
    ("scene", "scene", "{}"),
    ("layer", "layer", "{}"),
    ("t [s]", "t", "{:g}"),
    ("cells", "cells", "{:,}"),
    ("captured mass", "mass", "{:.6f}"),
    ("peak", "peak", "{:.4g}"),
    ("seconds", "seconds", "{:.2f}"),
)


def format_summary(rows: list[dict]) -> str:
    """The summary rows of :func:`bananagrid.scenes.run.run_scene` as an aligned text table.

    The peak carries its unit (``m^-2`` for a density map, ``per cell`` for the cell
    probabilities of an array scene); one ``P % area`` column per probability-mass level of
    the rows (the area of the smallest region holding P % of the probability; ``-`` where a
    row has none).
    """
    levels = sorted({r.probability for row in rows for r in row.get("regions", ())})
    header = [title for title, _, _ in SUMMARY_COLUMNS[:-1]] + [f"{100 * p:g} % area" for p in levels] + ["seconds"]
    body = []
    for row in rows:
        cells = [fmt.format(row[key]) for _, key, fmt in SUMMARY_COLUMNS[:-1]]
        cells[5] += " " + row.get("peak_unit", "m^-2")
        areas = {r.probability: _region_size(r) for r in row.get("regions", ())}
        cells += [areas.get(p, "-") for p in levels] + ["{:.2f}".format(row["seconds"])]
        body.append(cells)
    widths = [max(len(cell) for cell in column) for column in zip(header, *body)]
    # Text columns left-aligned, numbers right-aligned.
    def line(cells):
        return "  ".join(
            cell.ljust(w) if k < 2 else cell.rjust(w) for k, (cell, w) in enumerate(zip(cells, widths))
        ).rstrip()

    plans = [format_plan(row["scene"], row["plan"]) for row in rows if row.get("plan")]
    found = format_evidence(rows)
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, body), *found, *plans])


def format_evidence(rows: list[dict]) -> list[str]:
    """Each map's posterior (:func:`bananagrid.recording.evidence.evidence_values`) in one line:
    the searches' POS together, the evidence it is conditioned on (the reports and land the map
    took: POS is the probability that the searches would have found the target *given* them),
    each search's own POS, and the probability of the evidence."""
    lines = []
    for row in rows:
        found = row.get("evidence")
        if not found:
            continue
        if not lines:
            lines.append("")
        own = ", ".join(f"{name} {pos:.4f}" for name, pos in zip(found["searches"], found["search_pos"])
                        if math.isfinite(pos))
        given = [name for name in found["evidence"] if name not in found["searches"]]
        lines.append(f"{row['scene']}: posterior of {found['layer']} at t = {found['t']:g} s after "
                     f"{', '.join(found['evidence']) or 'no evidence yet'}: POS {found['pos']:.4f}"
                     + (f" given {', '.join(given)}" if given else "")
                     + (f" (each search alone: {own})" if own else "")
                     + f", probability of the evidence {found['normaliser']:.4g}")
    return lines


def format_plan(scene: str, plan: dict) -> str:
    """A scene's plan (:func:`bananagrid.recording.plan.plan_values`) in a few lines: the
    ideal POS, the effort and marginal gain, and each kind of areas' POS and areas; a plan over
    several periods (:func:`bananagrid.recording.plan.periods_values`): its total POS, then each
    period's so."""
    if "period_plans" in plan:
        head = (f"{scene}: plan over {plan['periods']} periods on layer {plan['layer']}: total POS {plan['pos']:.4f} "
                f"({plan['law']}, {plan['sweeps']} sweeps, {'converged' if plan['converged'] else 'NOT converged'}); "
                "first detections " + ", ".join(f"{p:.4f}" for p in plan["first_detection"]))
        # each period's lines as a one-period plan's, without the leading blank line and scene name
        return "\n".join(["", head] + [f"  period {k + 1}: " + format_plan(scene, period)[len(scene) + 3:].replace(
            "\n", "\n  ") for k, period in enumerate(plan["period_plans"])])
    lines = ["", f"{scene}: plan on layer {plan['layer']} at t = {plan['t']:g} s: {plan['effort_m2'] / 1e6:g} km^2 of "
             f"effort ({plan['law']}), ideal POS {plan['pos']:.4f}, marginal gain {plan['marginal_gain'] * 1e6:.4g} "
             "per km^2"]
    for name in ("rectangles", "bands"):
        if f"{name}_pos" in plan:
            areas = ", ".join(f"p {p:.3f} POD {pod:.2f} spacing {s:,.0f} m" for p, pod, s in
                              zip(plan[f"{name}_probability"], plan[f"{name}_pod"], plan[f"{name}_track_spacing_m"]))
            lines.append(f"  {len(plan[f'{name}_probability'])} {name}: POS {plan[f'{name}_pos']:.4f} "
                         f"({plan[f'{name}_effort_m2'] / 1e6:g} km^2 flown): {areas}")
    return "\n".join(lines)


def _region_size(region) -> str:
    """A region's area, or its number of cells where cells have no common area (array scenes)."""
    if not region.reached:
        return "not reached"
    return format_area(region.area) if np.isfinite(region.area) else f"{region.cells:,} cells"


#: What the progress line says while Warp compiles a kernel module (the first run on a machine).
COMPILING = "compiling kernels (first run, cached after)"


class _Progress:
    """Progress lines ``[3/6] scene: layer t=10 s ... 0.09 s`` for :func:`run_scene`.

    ``run_scene`` calls it before each item (``done`` finished so far) and after it
    (``done + 1``); the first call of a pair opens the line, the second closes it with the time.
    """

    #: The progress line left open (waiting for its time), if any: a warning ends it first.
    open_line: "_Progress | None" = None

    def __init__(self, scene: str, stream: TextIO):
        self.scene = scene
        self.stream = stream
        self.started: float | None = None
        self.head = ""
        self.broken = False
        self.said_compiling = False

    def __call__(self, done: int, total: int, label: str) -> None:
        if self.started is None:
            self.started = time.perf_counter()
            self.head, self.broken = f"[{done + 1}/{total}] {self.scene}: {label} ...", False
            self.said_compiling = False
            print(self.head, end="", file=self.stream, flush=True)
            _Progress.open_line = self
        else:
            seconds = time.perf_counter() - self.started
            self.started = None
            _Progress.open_line = None
            # after a warning the line is restated, so the time is not left alone on a line
            print(f"{self.head if self.broken else ''} {seconds:.2f} s", file=self.stream, flush=True)

    def note(self, text: str) -> None:
        """Say ``text`` on a line of its own under the open line (a plan's sweeps); the open
        line is restated with its time when it closes."""
        _Progress.interrupt()
        print(f"    {text}", file=self.stream, flush=True)

    def compiling(self) -> None:
        """Say on the open line that Warp is compiling kernels (called from a timer thread while
        a kernel module loads: :data:`~bananagrid.engine.warp_runtime.compile_notice`), once a line."""
        if self.started is not None and not self.said_compiling:
            self.said_compiling = True
            print(f" {COMPILING} ...", end="", file=self.stream, flush=True)

    def close(self) -> None:
        """End a line left open by an item that failed, so the error starts on its own line."""
        if self.started is not None:
            self.started = None
            _Progress.open_line = None
            print(file=self.stream, flush=True)

    @classmethod
    def interrupt(cls) -> None:
        """End the open progress line (if any) before something else is printed."""
        line = cls.open_line
        if line is not None and not line.broken:
            line.broken = True
            print(file=line.stream, flush=True)


#: At most this much of the native log is held (the rest is dropped), and the held lines are
#: waited for this long after a command.
HELD_BYTES = 1 << 20
HELD_WAIT_SECONDS = 2.0


@contextlib.contextmanager
def native_log_held():
    """Hold what native code writes to file descriptor 2 while a command runs (rerun's logger,
    Dask's worker processes), and show it after, unless an output could not be written
    (:class:`~bananagrid.atomic.OutputWriteError`: a full disk, a file-size limit): then our one
    line names the file and the cause, and their lines about the same failure are left out.

    Python's own ``sys.stderr`` (progress, warnings, errors) is moved to a copy of the
    descriptor meanwhile, so it is shown at once. Nothing is held where ``sys.stderr`` is not
    descriptor 2 (e.g. under a test's capture).

    The lines are held in a pipe drained by a thread, not in a file: under a file-size limit
    a held file could not grow, and rerun's logger, refused, stopped the run for ever."""
    try:
        direct = sys.stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):
        direct = False
    if not direct:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    shown = sys.stderr
    drop = False
    held = bytearray()
    read_end, write_end = os.pipe()

    def drain() -> None:
        while chunk := os.read(read_end, 1 << 16):  # b"" once no process holds the write end
            held.extend(chunk[:max(0, HELD_BYTES - len(held))])

    reader = threading.Thread(target=drain, name="bananagrid-held-log", daemon=True)
    reader.start()
    os.dup2(write_end, 2)
    os.close(write_end)
    sys.stderr = open(saved, "w", encoding=shown.encoding, errors="backslashreplace", buffering=1, closefd=False)
    try:
        yield
    except OutputWriteError:
        drop = True
        raise
    finally:
        sys.stderr.close()  # flushes; the descriptor (closefd=False) is closed below
        sys.stderr = shown
        os.dup2(saved, 2)
        os.close(saved)
        # the pipe ends when the last holder of its write end closes it (a worker process still
        # alive keeps it open: then what arrived so far is shown)
        reader.join(HELD_WAIT_SECONDS)
        if not reader.is_alive():
            os.close(read_end)
        if held and not drop:
            os.write(2, bytes(held))


def _warning_printer():
    """A ``warnings.showwarning`` for one command: each warning as one line, like errors (on a
    line of their own), and each text once, however many places raise it (a model built for the
    scene, for each time and for the blueprint; Python's own once-per-place filter would print it
    as many times as there are places, fewer where an earlier command in the process saw one)."""
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = _one_line(message)
        if text in shown:
            return
        shown.add(text)
        _Progress.interrupt()
        print(f"bananagrid: warning: {text}", file=sys.stderr)

    return show


def _one_line(exc) -> str:
    """An exception's message on one line (OSError: strerror and file name)."""
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror}"
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _check_unique_names(scenes) -> None:
    """Two scenes with one name would write the same output files."""
    seen = {}
    for scene in scenes:
        if scene.name in seen:
            raise BananagridError(
                f"{scene.source}: scene.name = \"{scene.name}\" is also the name of {seen[scene.name]}; "
                "each scene writes NAME.rrd, so names must differ"
            )
        seen[scene.name] = scene.source


if __name__ == "__main__":
    sys.exit(main())
