"""Make the README's pictures from the bundled scenes: ``python docs/make_pictures.py``.

Each grid scene is drawn as ``bananagrid plot`` draws it (its layers at the last time, log10
maps with labelled probability-mass contours) at a coarser step so the pictures stay small;
array scenes (angular cells, not grids) are left to their recordings. Pass scene names to
make only those.
"""

from __future__ import annotations

import sys
from pathlib import Path

from bananagrid.scenes.pictures import Panel, write_picture
from bananagrid.scenes.load import load_scene
from bananagrid.scenes.presence import PresenceScene
from bananagrid.scenes.run import compute

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "pictures"

#: The scenes pictured, each with the step (m) it is drawn at.
PICTURED = {"figure1": 10.0, "folding": 10.0, "bearing_three_stations": 50.0, "submarine": 2000.0, "ship_heading": 5.0}


def make(name: str) -> Path:
    """The picture of one bundled scene, written to ``docs/pictures/NAME.png``."""
    scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_step(PICTURED[name])
    if isinstance(scene, PresenceScene):
        raise SystemExit(f"{name}: an array scene has no grid to draw")
    last = max(t for _, t in scene.jobs())
    chosen = []
    for layer, t in scene.jobs():
        if t == last:
            model = layer.model(t)
            raster, _ = compute(scene, layer, t, model=model)
            chosen.append(Panel(layer.name, t, raster))
    return write_picture(OUT / f"{name}.png", scene.title, chosen, dpi=60)


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    for name in sys.argv[1:] or PICTURED:
        print(f"wrote {make(name)}")
