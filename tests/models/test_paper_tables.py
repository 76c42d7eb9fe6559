"""Tables 1 and 2 and the Section 6.1 goodness figure of the polar-banana paper, with the exact
CAT kernel as truth on the paper's frame (x in [-3000, 3000] m, y in [-200, 3400] m).

The table statistics come from ``oracles.table_stats`` / ``oracles.goodness`` (written
independently of the package): mass inside {exact >= L} over the grid total, and the maximal
|approx / exact - 1| inside it.

What we get at 4 m cell centres (and 2 m, for convergence):

=========  ==========  ==========  ==========  ==========  ==========
level      1e-6        1e-7        1e-8        1e-9        1e-10
mass       58.0717 %   95.9841 %   99.6160 %   99.9632 %   99.99647 %
rough      1.363 %     8.085 %     26.31 %     57.45 %     108.04 %
improved   0.0650 %    0.2219 %    0.6486 %    2.647 %     6.560 %
=========  ==========  ==========  ==========  ==========  ==========

goodness (5 %) = 0.9999227 (2 m: 0.9999217), printed 0.99992.

Three printed entries are not our numbers rounded: the mass inside 1e-10 (ours 99.99647 %, at
4 m and at 2 m alike, printed 99.997 %) and the improved errors at 1e-6 and 1e-8 (ours 0.0650 %
and 0.6486 %, printed 0.06 % and 0.64 %: truncated rather than rounded, while 1.363 % -> 1.4 %
and 6.560 % -> 6.6 % are rounded). The maximal errors are taken on a grid and creep up as it is
refined (2 m: 0.0660 %, 0.6496 %), and the paper does not state its grid. Every other entry is
ours rounded. We assert each table entry to within one unit of its last printed digit and the
goodness figure to within half a unit (rounding).
"""

import numpy as np
import pytest

import bananagrid as bg
import oracles

from cases import FIG1, FIG1_BOUNDS

LEVELS = [1e-6, 1e-7, 1e-8, 1e-9, 1e-10]
# Table 1 / Table 2, in percent, with the unit of the last printed digit
PAPER_MASS = [(58, 1), (96, 1), (99.6, 0.1), (99.96, 0.01), (99.997, 0.001)]
PAPER_ERROR = {
    "rough": [(1.4, 0.1), (8, 1), (26, 1), (57, 1), (108, 1)],
    "improved": [(0.06, 0.01), (0.22, 0.01), (0.64, 0.01), (2.6, 0.1), (6.6, 0.1)],
}
PAPER_GOODNESS = (0.99992, 0.00001)


@pytest.fixture(scope="module", params=[4.0, 2.0], ids=["4m", "2m"])
def rasters(request):
    grid = bg.Grid.from_bounds(**FIG1_BOUNDS, step=request.param)
    exact = bg.rasterise(bg.CAT(**FIG1), grid).values
    approx = {v: bg.rasterise(bg.PolarBanana(**FIG1, variant=v), grid).values for v in PAPER_ERROR}
    return grid, exact, approx


def test_mass_inside_contours(rasters):
    grid, exact, approx = rasters
    rows = oracles.table_stats(exact, approx["rough"], grid.cell_area, LEVELS)
    for row, (printed, unit) in zip(rows, PAPER_MASS):
        assert abs(100 * row["mass"] - printed) <= unit, (row["level"], 100 * row["mass"])


@pytest.mark.parametrize("variant", ["rough", "improved"])
def test_maximal_error_inside_contours(rasters, variant):
    grid, exact, approx = rasters
    rows = oracles.table_stats(exact, approx[variant], grid.cell_area, LEVELS)
    for row, (printed, unit) in zip(rows, PAPER_ERROR[variant]):
        assert abs(100 * row["max_rel_err"] - printed) <= unit, (row["level"], 100 * row["max_rel_err"])


def test_goodness_of_improved_approximation(rasters):
    grid, exact, approx = rasters
    value = oracles.goodness(exact, approx["improved"], grid.cell_area, threshold=0.05)
    printed, unit = PAPER_GOODNESS
    assert abs(value - printed) <= unit / 2, value


def test_grid_captures_the_mass(rasters):
    grid, exact, _ = rasters
    # the frame holds all but ~7e-9 of the mass (the omega tail beyond 8 sigma is 1e-15)
    assert abs(exact.sum() * grid.cell_area - 1.0) < 1e-7
