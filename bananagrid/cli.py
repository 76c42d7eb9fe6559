"""Command line: ``bananagrid run``, ``bananagrid inspect`` and ``bananagrid bench``.

Errors a user can fix (bad scene, missing file, unwritable directory) are printed as one line,
``bananagrid: error: MESSAGE``, with exit code 2 and no traceback.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
import warnings
from pathlib import Path
from typing import TextIO

from . import __version__
from .validate import BananagridError, positive

__all__ = ["main", "build_parser"]

#: Exit codes: success, a user error (also argparse's usage errors), an interrupt.
OK, USER_ERROR, INTERRUPTED = 0, 2, 130


def main(argv: list[str] | None = None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    parser, commands = build_parser()
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            args, rest = parser.parse_known_args(argv)
            if args.command == "bench":
                return _bench(rest)
            if rest:
                commands[args.command].error(f"unrecognized arguments: {' '.join(rest)}")
            return args.handler(args)
        except SystemExit as exc:  # argparse: --help (0) and usage errors (2)
            return exc.code if isinstance(exc.code, int) else USER_ERROR
        except (BananagridError, OSError, tomllib.TOMLDecodeError) as exc:
            print(f"bananagrid: error: {_one_line(exc)}", file=sys.stderr)
            return USER_ERROR
        except KeyboardInterrupt:
            print("bananagrid: interrupted", file=sys.stderr)
            return INTERRUPTED


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
        "(and OUT/NAME.npz with --npz). Progress goes to stderr, a summary table to stdout.",
    )
    run.add_argument("scenes", nargs="+", metavar="SCENE.toml", type=Path, help="scene files")
    run.add_argument("--out", type=Path, default=Path("out"), metavar="DIR",
                     help="output directory, created if missing (default: ./out)")
    run.add_argument("--npz", action="store_true", help="also write the arrays to NAME.npz")
    run.add_argument("--step", type=float, metavar="S",
                     help="override the grid step of every scene, m (e.g. for a quick look)")
    run.add_argument("--threads", type=int, metavar="N",
                     help="CPU threads per rasterisation (default: every core)")
    run.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    run.set_defaults(handler=_run)

    inspect = sub.add_parser(
        "inspect", help="print what a recording holds",
        description="Print the timelines and entities of .rrd recordings without a viewer.",
    )
    inspect.add_argument("files", nargs="+", metavar="FILE.rrd", type=Path, help="recordings")
    inspect.set_defaults(handler=_inspect)

    # bench parses its own options (its --help included): everything after it is passed on.
    bench = sub.add_parser("bench", add_help=False, help="throughput against a NumPy baseline")
    bench.set_defaults(handler=None)
    return parser, {"run": run, "inspect": inspect, "bench": bench}


# --- subcommands ------------------------------------------------------------------------------


def _run(args: argparse.Namespace) -> int:
    """``bananagrid run``: load and check every scene first, then run them in order."""
    from .runner import run_scene
    from .scene import load_scene

    if args.threads is not None and args.threads < 1:
        raise BananagridError(f"--threads = {args.threads}: must be >= 1")
    if args.step is not None:
        positive("--step", args.step)
    if args.out.exists() and not args.out.is_dir():
        raise BananagridError(f"--out {args.out}: exists and is not a directory")
    scenes = [load_scene(path) for path in args.scenes]
    if args.step is not None:
        scenes = [scene.with_step(args.step) for scene in scenes]
    _check_unique_names(scenes)
    args.out.mkdir(parents=True, exist_ok=True)
    rows, written = [], []
    for scene in scenes:
        progress = None if args.quiet else _Progress(scene.name, sys.stderr)
        try:
            rows += run_scene(scene, args.out, npz=args.npz, threads=args.threads, progress=progress)
        finally:
            if progress is not None:
                progress.close()
        written.append(args.out / f"{scene.name}.rrd")
        if args.npz:
            written.append(args.out / f"{scene.name}.npz")
    print(format_summary(rows))
    print()
    for path in written:
        print(f"wrote {path}")
    return OK


def _inspect(args: argparse.Namespace) -> int:
    """``bananagrid inspect``: the report of :func:`bananagrid.inspect.format_inspection`."""
    from .inspect import format_inspection, inspect_recording

    reports = [format_inspection(inspect_recording(path)) for path in args.files]
    print("\n\n".join(reports))
    return OK


def _bench(argv: list[str]) -> int:
    """``bananagrid bench``: delegated to :func:`bananagrid.bench.main` with the rest of argv."""
    try:
        from . import bench
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.bench":
            raise
        raise BananagridError("bench: bananagrid.bench is not installed in this build") from None
    return bench.main(list(argv))


# --- output -----------------------------------------------------------------------------------

SUMMARY_COLUMNS = (
    ("scene", "scene", "{}"),
    ("layer", "layer", "{}"),
    ("t [s]", "t", "{:g}"),
    ("cells", "cells", "{:,}"),
    ("captured mass", "mass", "{:.6f}"),
    ("peak [m^-2]", "peak", "{:.4g}"),
    ("seconds", "seconds", "{:.2f}"),
)


def format_summary(rows: list[dict]) -> str:
    """The summary rows of :func:`bananagrid.runner.run_scene` as an aligned text table."""
    header = [title for title, _, _ in SUMMARY_COLUMNS]
    body = [[fmt.format(row[key]) for _, key, fmt in SUMMARY_COLUMNS] for row in rows]
    widths = [max(len(cell) for cell in column) for column in zip(header, *body)]
    # Text columns left-aligned, numbers right-aligned.
    def line(cells):
        return "  ".join(
            cell.ljust(w) if k < 2 else cell.rjust(w) for k, (cell, w) in enumerate(zip(cells, widths))
        ).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, body)])


class _Progress:
    """Progress lines ``[3/6] scene: layer t=10 s ... 0.09 s`` for :func:`run_scene`.

    ``run_scene`` calls it before each item (``done`` finished so far) and after it
    (``done + 1``); the first call of a pair opens the line, the second closes it with the time.
    """

    def __init__(self, scene: str, stream: TextIO):
        self.scene = scene
        self.stream = stream
        self.started: float | None = None

    def __call__(self, done: int, total: int, label: str) -> None:
        if self.started is None:
            self.started = time.perf_counter()
            print(f"[{done + 1}/{total}] {self.scene}: {label} ...", end="", file=self.stream, flush=True)
        else:
            seconds = time.perf_counter() - self.started
            self.started = None
            print(f" {seconds:.2f} s", file=self.stream, flush=True)

    def close(self) -> None:
        """End a line left open by an item that failed, so the error starts on its own line."""
        if self.started is not None:
            self.started = None
            print(file=self.stream, flush=True)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line each, like errors."""
    print(f"bananagrid: warning: {_one_line(message)}", file=sys.stderr)


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
