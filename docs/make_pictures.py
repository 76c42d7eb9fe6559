"""Make the gallery's pictures from the bundled scenes: ``python docs/make_pictures.py``.

Every grid scene in ``scenes/`` is drawn as ``bananagrid plot scenes/NAME.toml --step S
[--t T] [--layer NAME...] --dpi 60`` draws it (the same code: :func:`bananagrid.scenes.pictures.read_picture` and
:func:`~bananagrid.scenes.pictures.write_picture`), at the step and time listed in ``PICTURED``:
coarser than the scene's own so that the script takes seconds; each PNG is then stored with a
128-colour palette to keep it small. Array scenes (angular cells, not grids) have no map; their
recordings hold the cell tables.

The gallery page, ``docs/gallery.md``, is generated from ``PICTURED`` (in its order, with the
captions of ``CAPTIONS``, or a scene's own title where it has none), so that a new scene
appears in it: ``python docs/make_pictures.py --gallery`` rewrites it, and the tests fail if the
committed page differs.

Usage: ``python docs/make_pictures.py [NAME ...] [--out DIR]`` (default: every pictured scene,
into ``docs/pictures``); ``python docs/make_pictures.py --gallery`` (only the page).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from PIL import Image  # installed with matplotlib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's bananagrid draws, whichever is installed

from bananagrid.atomic import atomic_write  # noqa: E402
from bananagrid.scenes.examples import example_title  # noqa: E402
from bananagrid.scenes.pictures import read_picture, write_picture  # noqa: E402

SCENES = ROOT / "scenes"
OUT = ROOT / "docs" / "pictures"
GALLERY = ROOT / "docs" / "gallery.md"

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
    "fast_contact": (100.0, 600.0, ()),
    "submarine_barriers": (500.0, 9000.0, ()),
}

#: The gallery's caption of each picture, and the picture's alternative text. A pictured scene
#: without an entry is captioned with its own title.
CAPTIONS = {
    "figure1": ("Figure 1: exact CAT, rough and improved polar bananas at t = 10 s.",
                "Figure 1: exact CAT, rough and improved polar bananas"),
    "folding": ("sigma_omega t = 120 deg: the banana folds over itself behind the start (arrow: the initial heading).",
                "A folding banana: exact CAT and improved"),
    "sequence": ("The Figure 1 banana at t = 30 s, the last time of `sequence.toml`.",
                 "The banana of the sequence scene at 30 s"),
    "figure8": ("Figure 8: initial-heading noise 0, 6 and 12 deg, exact CAT beside improved (15)-(16).",
                "Figure 8: heading noise, exact and improved"),
    "ship_heading": ("A ship 60 s after its fix, heading known exactly and to 5 deg.", "A ship with a heading known to 5 deg"),
    "bearing_coastal": ("Two coastal stations (south of the frame) and a contact about 30 km out: exact and linear "
                        "maps, the bearing lines and their +-2 sigma wedges.", "Two coastal stations: exact and linear maps"),
    "bearing_poor_crossing": ("A 15 deg crossing: the region is long and thin, and not an ellipse.", "A poor crossing"),
    "bearing_three_stations": ("Three stations, the weighted least-squares fix.", "Three bearing stations"),
    "submarine": ("A submarine 2 h after its fix, 5, 10 or 15 kn on any course: three rings.", "A submarine 2 h after its fix"),
    "rice_isotropic": ("An isotropic start and speeds 0, 2 and 5 m/s after 120 s: a disc and two rings (Rice's law).",
                       "Rice's law: an isotropic start"),
    "slow_contact": ("Travel below the start's SD, 1 h later: the ring has vanished into the normal.", "A slow contact"),
    "geo_ship": ("A vessel west of Bergen, course 200 deg true, 15 minutes after its fix: the CAT from the fix and a "
                 "Butterly start trusting the course to about 20 deg (local km about the fix).", "A vessel west of Bergen"),
    "geo_bearing": ("Two Norwegian coastal direction-finding stations, 38 and 49 km away, given in latitude and "
                    "longitude.", "Two coastal stations west of Bergen"),
    "submarine_barriers": ("The submarine's prior 2.5 h after its fix, before the evidence: two barriers flown north "
                           "and east of the fix found nothing, then two bearing pairs; its recording shows the "
                           "posteriors beside the prior ([In the viewer](viewer.md#submarine_barriers)).",
                           "The submarine's prior 2.5 h after its fix"),
}

GALLERY_HEAD = """# Gallery

<!-- generated by `python docs/make_pictures.py --gallery` from its PICTURED and CAPTIONS: do not edit -->

Every grid scene in `scenes/`, drawn by `python docs/make_pictures.py` (the same code as
`bananagrid plot`, at coarser steps and 60 dpi, stored with a 128-colour palette to keep them
small); the tests redraw one and check that each is there. `bananagrid plot` draws any scene
or result this way ([Pictures without a viewer](guide/pictures.md)).
Array scenes (angular cells, not grids) have no map; their recordings hold the cell tables.
"""

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


def gallery() -> str:
    """The text of ``docs/gallery.md``: each pictured scene under its name, captioned."""
    parts = [GALLERY_HEAD]
    for name in PICTURED:
        title = example_title(name)
        caption, alt = CAPTIONS.get(name, (title, title))
        parts.append(f"## {name}\n\n{caption}\n\n![{alt}](pictures/{name}.png)\n")
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"scenes to draw (default: all of {', '.join(PICTURED)})")
    parser.add_argument("--out", type=Path, default=OUT, help="folder for the PNGs (default: docs/pictures)")
    parser.add_argument("--gallery", action="store_true", help=f"only rewrite the gallery page ({GALLERY.name})")
    args = parser.parse_args(argv)
    if args.gallery:
        with atomic_write(GALLERY) as partial:
            Path(partial).write_text(gallery())
        print(f"wrote {GALLERY}")
        return
    unknown = [name for name in args.names if name not in PICTURED]
    if unknown:
        parser.error(f"not pictured: {', '.join(unknown)}; choose from {', '.join(PICTURED)}")
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.names or PICTURED:
        print(f"wrote {make(name, args.out)}")


if __name__ == "__main__":
    main()
