"""Make the planning page's picture: ``python docs/make_planning_picture.py`` writes
``docs/pictures/planning.png`` (2 km^2 of random search over the Figure 1 banana at 20 m,
three rectangles, the POS curve), drawn by :func:`bananagrid.plot_allocation` and stored with a
128-colour palette to keep it small."""

from __future__ import annotations

import io
import math
from pathlib import Path

from PIL import Image  # installed with matplotlib

import bananagrid as bg
from bananagrid.atomic import atomic_write

OUT = Path(__file__).resolve().parent / "pictures" / "planning.png"


def main() -> None:
    fig1 = dict(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=20.0)
    prior = bg.rasterise(bg.PolarBanana(**fig1, variant="improved"), grid, quantity="probability")
    plan = bg.allocate(prior, effort=2.0e6)
    flown = bg.search_rectangles(plan, k=3, sweep_width=200.0)
    fig = bg.plot_allocation(plan, flown, title="Figure 1 banana, 10 s after the fix: 2 km$^2$ of random search, "
                                                "3 rectangles at a 200 m sweep width")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    image = Image.open(buffer).convert("RGB").quantize(128)
    with atomic_write(OUT) as partial:
        image.save(partial, format="PNG", optimize=True)


if __name__ == "__main__":
    main()
