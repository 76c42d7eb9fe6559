"""The bundled story ``scenes/submarine_barriers.toml`` tells the truth.

Its map at 2.5 h (two barrier searches over intervals that found nothing, carried through
Butterly's courses) agrees with 10^6 draws of the model's own generative story
(``Butterly.sample_paths``: start, course, speed), each detected by each barrier with its own
POD (random search spread over the interval: 1 - exp(-C x the fraction of the interval its
straight path spends inside), the undetected histogrammed at 2.5 h: chi-square over the cells,
POS, each barrier's own POS and region masses within 4 sigma. The figures the scene's header
states (from its run at its own 2 km cells) agree with the same draws, and so do its statements
about the bearing pairs at 3 and 4 h (the draws weighted by the bearings' likelihoods), which
cost no kernel run here (the 4 h map takes over a CPU minute: tests/test_cli.py runs it).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import bananagrid as bg
from bananagrid.cli import format_evidence
from bananagrid.recording.inspect import format_inspection
from bananagrid.scenes.run_evidence import scene_posterior

# the vectorised box clipping and the knot (m/s) of tests/evidence/test_butterly_monte_carlo.py
from test_butterly_monte_carlo import KN, fraction_inside

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "submarine_barriers.toml"
#: The header's text (its comment lines, joined): the story the figures below are checked in.
HEADER = " ".join(line.lstrip("#").strip() for line in SCENE.read_text().split("[scene]")[0].splitlines())
#: The guide's telling of the same story (its lines joined).
GUIDE = " ".join((ROOT / "docs" / "guide" / "evidence.md").read_text()
                 .split("`scenes/submarine_barriers.toml` tells")[1].split("\n\n")[0].split())
#: The cells of tests/test_cli.py's quick run of the scene (coarse cells cost as much as fine
#: ones: the cell rule's sub-cells follow the start's smallest SD, 0.43 km).
STEP = 4000.0
EARLY, LATE = 9000.0, 14400.0  # the scene's map times, s
N = 10**6
ALPHA = 1e-3
SEED = 20261127


def box(polygon) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) of an axis-aligned rectangle (the barriers are; fraction_inside clips boxes)."""
    v = np.asarray(polygon, dtype=float)
    xs, ys = sorted(set(v[:, 0])), sorted(set(v[:, 1]))
    assert len(v) == 4 and len(xs) == 2 and len(ys) == 2, polygon
    return xs[0], xs[1], ys[0], ys[1]


@pytest.fixture(scope="module")
def scene():
    return bg.load_scene(SCENE)


@pytest.fixture(scope="module")
def story(scene):
    """The draws: positions at 2.5 h and 4 h, each barrier's detection (drawn with its POD), the
    bearing pairs' likelihoods at their times, and each draw's speed (kn) and course (deg)."""
    (layer,) = scene.layers
    by_name = {spec.name: spec.evidence for spec in scene.evidence}
    barriers = [by_name["barrier_north"], by_name["barrier_east"]]
    bearings = [by_name["bearings_3h"], by_name["bearings_4h"]]
    times = [t for b in barriers for t in b.t] + [EARLY, *(b.t for b in bearings), LATE]
    rng = np.random.default_rng(SEED)
    paths = layer.model(LATE).sample_paths(N, times, rng)
    detected = []
    for k, barrier in enumerate(barriers):
        inside = fraction_inside(paths[:, 2 * k], paths[:, 2 * k + 1], *box(barrier.polygon))
        detected.append(rng.uniform(size=N) < -np.expm1(-barrier.coverage * inside))
    likelihood = [b.likelihood(paths[:, 5 + k, 0], paths[:, 5 + k, 1]) for k, b in enumerate(bearings)]
    velocity = (paths[:, -1] - paths[:, 4]) / (LATE - EARLY)
    return {"early": paths[:, 4], "late": paths[:, -1], "detected": detected, "likelihood": likelihood,
            "speed": np.rint(np.hypot(velocity[:, 0], velocity[:, 1]) / KN),
            "course": np.degrees(np.arctan2(velocity[:, 0], velocity[:, 1])) % 360.0}


def quarter(bearing_deg, centre: float) -> np.ndarray:
    """Within 45 deg of the bearing ``centre`` (deg clockwise from north)."""
    return np.abs((np.asarray(bearing_deg) - centre + 180.0) % 360.0 - 180.0) < 45.0


def stated(phrase: str, figure: str, value: float, sigma: float) -> None:
    """The header says ``phrase`` with ``figure`` (a number as written there) in its ``{}``, and
    the figure is ``value`` (a Monte Carlo estimate with standard error ``sigma``) within 4 sigma
    and half a unit of its last digit (its rounding)."""
    assert phrase.format(figure) in HEADER, phrase.format(figure)
    decimals = len(figure.split(".")[1]) if "." in figure else 0
    assert abs(float(figure) - value) <= 4.0 * sigma + 0.5 * 10.0**-decimals, (figure, value, sigma)


def weighted(values, weights) -> tuple[float, float, float]:
    """(mean, SD, the mean's standard error by the weights' effective sample size)."""
    mean = float(np.sum(weights * values) / np.sum(weights))
    sd = math.sqrt(float(np.sum(weights * (values - mean) ** 2) / np.sum(weights)))
    ess = float(np.sum(weights)) ** 2 / float(np.sum(weights**2))
    return mean, sd, sd / math.sqrt(ess)


def test_the_map_at_2_5_h_is_the_generative_story(scene, story):
    """The scene's own posterior at 2.5 h (as its run computes it, on the quick run's cells)
    against the draws: chi-square over the cells with expected count >= 5 (alpha 1e-3), POS and
    each barrier's POS, and the masses of the speed rings and quarters within 4 sigma. The cell
    rule (tol 1e-3 per sub-cell and axis) is far below a cell's Poisson SD here (1 / sqrt(count):
    at least 0.6 % on the fullest cell, whose count is at most N times the prior's peak density,
    1.4e-9 m^-2, times 16 km^2); the time rule of the barriers' intervals (at most C 0.35 / 16 in a
    crossing path's log-weight) changes sign along the crossing times and averages out over a
    cell's paths: measured with three seeds, the chi-square's p-value 0.31 to 0.71 and every
    region within 2.6 sigma."""
    quick = scene.with_step(STEP)
    grid = quick.grid
    found = scene_posterior(quick, quick.layers[0], EARLY)
    post = found.posterior
    assert found.values["evidence"] == ["barrier_north", "barrier_east"]  # the bearings came later
    north, east = story["detected"]
    kept = story["early"][~(north | east)]
    counts, _, _ = np.histogram2d(kept[:, 1], kept[:, 0], bins=[grid.ny, grid.nx],
                                  range=[(grid.origin[1], grid.origin[1] + grid.ny * grid.dy),
                                         (grid.origin[0], grid.origin[0] + grid.nx * grid.dx)])
    assert counts.sum() == len(kept)  # the grid holds every draw at 2.5 h (15 kn: 69 km out)
    # the expected count of a cell: N times its unnormalised posterior mass, prior x P(not found)
    expected = N * post.values * post.mass
    big = expected >= 5.0
    chi2 = float(np.sum((counts[big] - expected[big]) ** 2 / expected[big]))
    assert stats.chi2.sf(chi2, int(big.sum()) - 1) > ALPHA, (chi2, int(big.sum()))
    for p, seen in [(post.pos, (north | east).mean()), *zip(post.search_pos, (north.mean(), east.mean()))]:
        assert abs(p - seen) <= 4.0 * math.sqrt(seen * (1.0 - seen) / N), (p, seen)
    xc, yc = np.meshgrid(grid.x, grid.y)
    radius, bearing = np.hypot(xc, yc), np.degrees(np.arctan2(xc, yc)) % 360.0
    rings = [np.abs(radius - knots * KN * EARLY) < 2.5 * KN * EARLY for knots in (5.0, 10.0, 15.0)]
    for region in [*rings, *(quarter(bearing, c) for c in (0.0, 90.0, 180.0, 270.0))]:
        p = float(np.sum(post.values[region]) * post.mass)
        seen = float(counts[region].sum()) / N
        assert abs(seen - p) <= 4.0 * math.sqrt(p * (1.0 - p) / N), (seen, p)


def test_the_header_states_the_2_5_h_figures(story):
    """POS 0.203 (north 0.121, east 0.088), the rings 0.42, 0.25 and 0.32 and the southern and
    western quarters 0.31 and 0.29: the header's figures are the draws' (speed rings by each
    draw's speed, quarters by its bearing from the fix at 2.5 h). Its words too: the 10 kn
    submarines heading north and east are caught, the 5 kn ones never reach a barrier."""
    north, east = story["detected"]
    caught = north | east
    for phrase, figure, seen in (("with probability {} (their POS", "0.203", caught.mean()),
                                 ("north barrier alone {},", "0.121", north.mean()),
                                 ("the east one {})", "0.088", east.mean())):
        stated(phrase, figure, seen, math.sqrt(seen * (1.0 - seen) / N))
    left = ~caught
    speed, course = story["speed"], story["course"]
    early = story["early"]
    where = np.degrees(np.arctan2(early[:, 0], early[:, 1])) % 360.0
    for phrase, figure, region in (("the 5 kn ring {} (0.20)", "0.25", speed == 5.0),
                                   ("the 10 kn ring holds {} (prior 0.50)", "0.42", speed == 10.0),
                                   ("the 15 kn ring {} (0.30)", "0.32", speed == 15.0),
                                   ("western quarters {} and", "0.31", quarter(where, 180.0)),
                                   ("and {} (0.25 each)", "0.29", quarter(where, 270.0))):
        share = float(np.mean(region[left]))
        stated(phrase, figure, share, math.sqrt(share * (1.0 - share) / left.sum()))
    assert np.array_equal(np.unique(speed), [5.0, 10.0, 15.0])
    pod = {(knots, c): caught[(speed == knots) & quarter(course, c)].mean()
           for knots in (5.0, 10.0, 15.0) for c in (0.0, 90.0, 180.0, 270.0)}
    assert min(pod[10.0, 0.0], pod[10.0, 90.0]) > 0.5 > 0.1 > max(pod[10.0, 180.0], pod[10.0, 270.0])
    assert max(pod[5.0, c] for c in (0.0, 90.0, 180.0, 270.0)) < 1e-3
    assert 0.05 < caught[speed == 15.0].mean() < caught[speed == 10.0].mean()


def test_the_header_states_what_the_bearings_say(story):
    """After the 3 h pair only the 10 kn submarines heading south-west (course 225 deg, SD 4
    deg) are left; after the 4 h pair the course SD is 2 deg and the target a spot 74 km
    south-west of the fix (SD 2 km in x and y); given the bearings the barriers could not have
    found it: POS 0.0000. The draws weighted by the likelihoods of the bearings (and kept where no
    barrier detected them): the standard errors from the weights' effective sample size."""
    north, east = story["detected"]
    left = ~(north | east)
    first, second = story["likelihood"]
    for weights, spread in ((left * first, "4"), (left * first * second, "2")):
        # "only the 10 kn": their share is 1 - 2e-8 after the first pair
        assert np.sum(weights[story["speed"] == 10.0]) / np.sum(weights) > 1.0 - 1e-6
        mean, sd, error = weighted(story["course"], weights)
        stated("(course {} deg", "225", mean, error)
        # the SD's standard error: SD / sqrt(2 ESS), a normal sample's
        stated("SD {} deg)" if spread == "2" else "SD {} deg);", spread, sd,
               sd / math.sqrt(2.0 * (np.sum(weights) ** 2 / np.sum(weights**2))))
    weights = left * first * second
    late = story["late"]
    (mx, sx, ex), (my, sy, ey) = weighted(late[:, 0], weights), weighted(late[:, 1], weights)
    stated("spot {} km south-west of the fix", "74", math.hypot(mx, my) / 1000.0, math.hypot(ex, ey) / 1000.0)
    assert abs(math.degrees(math.atan2(mx, my)) % 360.0 - 225.0) < 1.0  # south-west of the fix
    for sd in (sx, sy):
        stated("(SD {} km in x and y)", "2", sd / 1000.0, 0.0)
    # POS given the bearings: 1 - P(not found, bearings) / P(bearings); the barriers' weight
    # lies where the bearings' likelihood is below 1e-20 of its peak
    pos = 1.0 - float(np.sum(weights)) / float(np.sum(first * second))
    assert "POS 0.0000" in HEADER and pos < 5e-5


# --- the printed line: what the POS is conditioned on --------------------------------------------


def _row(evidence, searches, search_pos, pos, normaliser):
    return {"scene": "s", "evidence": {"layer": "sub", "t": 14400.0, "pos": pos, "normaliser": normaliser,
                                       "evidence": evidence, "searches": searches, "search_pos": search_pos}}


@pytest.mark.parametrize("row, says", [
    # searches alone: POS is the probability of detection under the prior
    (_row(["north", "east"], ["north", "east"], [0.1211, 0.0883], 0.203, 0.797),
     "s: posterior of sub at t = 14400 s after north, east: POS 0.2030 (each search alone: north 0.1211, "
     "east 0.0883), probability of the evidence 0.797"),
    # with reports: POS given them (0 here: the bearings put it where no barrier looked)
    (_row(["north", "east", "b3", "b4"], ["north", "east"], [0.0, 0.0], 0.0, 0.005824),
     "s: posterior of sub at t = 14400 s after north, east, b3, b4: POS 0.0000 given b3, b4 (each search "
     "alone: north 0.0000, east 0.0000), probability of the evidence 0.005824"),
    # land alone, the scene's search not begun yet
    (_row(["land"], ["box"], [math.nan], 0.0, 0.9),
     "s: posterior of sub at t = 14400 s after land: POS 0.0000 given land, probability of the evidence 0.9"),
    (_row(["box", "land", "E4", "E5"], ["box"], [0.5], 0.5, 0.25),
     "s: posterior of sub at t = 14400 s after box, land, E4, E5: POS 0.5000 given land, E4, E5 (each search "
     "alone: box 0.5000), probability of the evidence 0.25"),
], ids=["searches", "reports", "land", "three"])
def test_the_printed_line_says_what_the_pos_is_given(row, says):
    assert format_evidence([row]) == ["", says]


def test_the_guide_tells_the_header_s_figures():
    """docs/guide/evidence.md quotes the figures the tests above check in the header, and the line
    the run prints at 4 h (test_the_printed_line_says_what_the_pos_is_given's wording)."""
    for phrase in ("POS is 0.203 (the north one alone 0.121, the east one 0.088)", "falls from 0.50 to 0.42",
                   "rises from 0.20 to 0.25", "course 225 deg, 74 km south-west of the fix at 4 h",
                   "`POS 0.0000 given bearings_3h, bearings_4h`"):
        assert phrase in GUIDE, phrase
    for figure in ("0.203", "0.121", "0.088", "0.42 (prior 0.50)", "0.25 (0.20)", "(course 225 deg", "spot 74 km"):
        assert figure in HEADER, figure


def test_inspect_says_what_the_pos_is_given():
    """``bananagrid inspect`` (text) names the reports and land a recorded POS is conditioned on,
    and none where the map took searches alone."""
    info = {"path": "s.rrd", "application_id": "bananagrid", "recording_id": "r", "blueprint": True,
            "timelines": {}, "entities": {},
            "evidence": [{"layer": "sub", "t": 9000.0, "pos": 0.203, "normaliser": 0.797, "prior_mass": 1.0,
                          "evidence": ["north", "east"], "search_pos": {"north": 0.121, "east": 0.088}},
                         {"layer": "sub", "t": 14400.0, "pos": 0.0, "normaliser": 0.0058, "prior_mass": 1.0,
                          "evidence": ["north", "east", "b3", "b4"], "search_pos": {"north": 0.0, "east": 0.0}}]}
    text = format_inspection(info).splitlines()
    assert "    POS                    0.203000 (each search alone: north 0.121000, east 0.088000)" in text
    assert ("    POS                    0.000000 given b3, b4 (each search alone: north 0.000000, east 0.000000)"
            in text)
