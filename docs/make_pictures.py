"""Make the README's pictures from the bundled scenes: ``python docs/make_pictures.py``.

Every grid scene in ``scenes/`` is drawn as ``bananagrid plot scenes/NAME.toml --step S
[--t T] [--layer NAME...] --dpi 60`` draws it (the same code: :func:`bananagrid.scenes.pictures.read_picture` and
:func:`~bananagrid.scenes.pictures.write_picture`), at the step and time listed in ``PICTURED``:
coarser than the scene's own so that the script takes seconds; each PNG is then stored with a
128-colour palette to keep it small. Array scenes (angular cells, not grids) have no map; their
recordings hold the cell tables.

Usage: ``python docs/make_pictures.py [NAME ...] [--out DIR]`` (default: every pictured scene,
into ``docs/pictures``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from PIL import Image  # installed with matplotlib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's bananagrid draws, whichever is installed

from bananagrid.atomic import atomic_write  # noqa: E402
from bananagrid.scenes.pictures import read_picture, write_picture  # noqa: E402

SCENES = ROOT / "scenes"
OUT = ROOT / "docs" / "pictures"

#: The pictured scenes: the step (m) each is computed at, its time (s; None: the last) and
#: the order of its layers (empty: the scene's; figure8 pairs exact CAT with improved).
PICTURED = {
    "figure1": (10.0, None, ()),
    "folding": (10.0, None, ()),
    "sequence": (25.0, None, ()),
    "figure8": (10.0, None, ("cat_0", "improved_0", "cat_6deg", "improved_6deg", "cat_12deg", "improved_12deg")),
    "ship_heading": (5.0, None, ()),
    "bearing_coastal": (50.0, None, ()),
    "bearing_poor_crossing": (100.0, None, ()),
    "bearing_three_stations": (50.0, None, ()),
    "submarine": (500.0, 7200.0, ()),
    "rice_isotropic": (10.0, None, ()),
    "slow_contact": (40.0, None, ()),
    "geo_ship": (50.0, None, ()),
    "geo_bearing": (50.0, None, ()),
}

DPI = 60
PALETTE_COLOURS = 128


def make(name: str, out: Path = OUT) -> Path:
    """The picture of the bundled scene ``name``, written to ``out/NAME.png``."""
    step, t, layers = PICTURED[name]
    picture = read_picture(SCENES / f"{name}.toml", step=step, t=t, layers=layers)
    path = write_picture(out / f"{name}.png", picture, dpi=DPI)
    with Image.open(path) as image:
        small = image.convert("RGB").quantize(colors=PALETTE_COLOURS)
    with atomic_write(path) as partial:
        small.save(partial, format="PNG", optimize=True)
    return path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"scenes to draw (default: all of {', '.join(PICTURED)})")
    parser.add_argument("--out", type=Path, default=OUT, help="folder for the PNGs (default: docs/pictures)")
    args = parser.parse_args(argv)
    unknown = [name for name in args.names if name not in PICTURED]
    if unknown:
        parser.error(f"not pictured: {', '.join(unknown)}; choose from {', '.join(PICTURED)}")
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.names or PICTURED:
        print(f"wrote {make(name, args.out)}")


if __name__ == "__main__":
    main()
