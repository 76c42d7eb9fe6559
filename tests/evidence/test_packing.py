"""Packing evidence for the kernels: the nodes and channels a pack holds (times sorted, the
quadrature weights of an interval summing to its length, each bearing a node of one factor,
the channels' factors), and every refusal in one line naming the evidence's key."""

from __future__ import annotations

import math

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.evidence.packing import AREA_PANELS, DEFINITE_CHORDS, MAX_NODES, PANEL_NODES, pack
from bananagrid.kernels import evidence as ek

SQUARE = [(0.0, 0.0), (100.0, 0.0), (100.0, 100.0), (0.0, 100.0)]
FIX = bg.BearingFix(sensors=[(-500.0, 0.0), (500.0, 0.0), (0.0, -600.0)], bearings=[0.8, -0.8, 0.1],
                    sigmas=[0.05, 0.05, 0.1])


def test_nodes_and_channels():
    evidence = [bg.AreaSearch(SQUARE, t=(1.0, 3.0), coverage=2.0), bg.BearingReport(FIX, t=0.5),
                bg.TrackSearch([(0.0, -50.0, 0.5), (200.0, -50.0, 4.0)], sweep_width=60.0),
                bg.PositionReport((5.0, 5.0), t=4.5, sigma=10.0), bg.AreaSearch(SQUARE, t=2.0, pod=1.0)]
    p = pack(evidence, 5.0)
    assert np.all(np.diff(p.time) >= 0.0) and p.time[-1] <= 5.0
    factor = p.ints[:, 1]
    # the interval: AREA_PANELS x PANEL_NODES nodes whose weights sum to its length, rate -C / span
    area = factor == 0
    assert area.sum() == AREA_PANELS * PANEL_NODES
    assert math.isclose(p.q[area].sum(), 2.0, rel_tol=1e-14)
    assert np.all(p.data[area, 0] == -1.0) and np.all(p.ints[area, 0] == ek.KIND_POLYGON)
    # the bearings: one node per sensor, one factor, one time
    bearing = factor == 1
    assert bearing.sum() == 3 and np.all(p.time[bearing] == 0.5) and np.all(p.ints[bearing, 0] == ek.KIND_BEARING)
    # the track: panels of W / 4 of the searcher's travel (200 m: 14 panels), weights sum to the leg's time
    track = factor == 2
    assert track.sum() == math.ceil(200.0 / 15.0) * PANEL_NODES
    assert math.isclose(p.q[track].sum(), 3.5, rel_tol=1e-14)
    assert np.allclose(p.data[track, 2], 60.0**2 * (200.0 / 3.5) / (8.0 * math.pi), rtol=1e-15)
    # POD 1 at one time: log(1 - POD) = -inf
    assert p.data[factor == 4, 0][0] == -math.inf
    assert p.channel_names == ("prior", "all", "searches", "others", "search:evidence[0]", "search:evidence[2]",
                               "search:evidence[4]")
    want = [[0, 0, 0, 0, 0], [1, 1, 1, 1, 1], [1, 0, 1, 0, 1], [0, 1, 0, 1, 0], [1, 1, 0, 1, 0], [0, 1, 1, 1, 0],
            [0, 1, 0, 1, 1]]
    np.testing.assert_array_equal(p.channels, want)
    assert p.factor_kinds == ("search", "report", "search", "report", "search")
    with pytest.raises(ValueError):
        p.time[0] = 1.0  # read-only


LAND = bg.Exclusion(SQUARE)
REFUSED = [
    ("after the map", [bg.AreaSearch(SQUARE, t=(4.0, 6.0), pod=0.5)],
     r"^evidence\[0\]\.t = 6\.0: after the map's time t = 5\.0"),
    ("land", [bg.AreaSearch(SQUARE, t=1.0, pod=0.5), LAND], r"^evidence\[1\]: land holds at every time"),
    ("definite, too many chords", [bg.TrackSearch([(0, 0, 1.0), (100, 0, 4.0)], sweep_width=10.0, law="definite")],
     r"^evidence\[0\]: the definite-range track needs 6001 time nodes .*above 4096; pass fewer definite_chords"),
    ("not evidence", [SQUARE], r"^evidence\[0\] = .*expected one of bg\.AreaSearch"),
    ("too many nodes", [bg.TrackSearch([(0, 0, 1.0), (1e6, 0, 2.0)], sweep_width=10.0)],
     rf"^evidence\[0\]\.sweep_width = 10\.0: a leg of 1e\+06 m needs 1600000 time nodes .*above {MAX_NODES}"),
]


@pytest.mark.parametrize("what, evidence, message", REFUSED, ids=[r[0] for r in REFUSED])
def test_refused_in_one_line(what, evidence, message):
    with pytest.raises(bg.BananagridError, match=message) as caught:
        pack(evidence, 5.0, definite_chords=10000 if what.startswith("definite") else DEFINITE_CHORDS)
    assert "\n" not in str(caught.value)


def test_definite_track_chain():
    """A definite-range track: a node at its first point, then one at each chord's end, each
    leg cut into the fewest equal chords of at most t / definite_chords; the searcher's
    positions at the chord's ends, h = W / 2, two scratch slots after the factors, the start
    and leg-end flags; sorted in time among the other nodes with the chain's order kept."""
    track = bg.TrackSearch([(0.0, 0.0, 1.0), (100.0, 0.0, 2.0), (100.0, 50.0, 2.1)], sweep_width=30.0, law="definite")
    p = pack([bg.AreaSearch(SQUARE, t=1.5, pod=0.5), track], 8.0, definite_chords=16)  # chords of <= 0.5 s
    chain = np.flatnonzero(p.ints[:, 0] == ek.KIND_DEFINITE)
    np.testing.assert_allclose(p.time[chain], [1.0, 1.5, 2.0, 2.1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(p.data[chain, :5], [[0, 0, 0, 0, 15], [50, 0, 0, 0, 15], [100, 0, 50, 0, 15],
                                                   [100, 50, 100, 0, 15]], rtol=0, atol=1e-12)
    assert p.ints[chain, 1].tolist() == [1] * 4 and p.ints[chain, 2].tolist() == [2] * 4  # factor 1; slots 2, 3
    start, leg = ek.DEFINITE_START, ek.DEFINITE_LEG
    assert p.ints[chain, 3].tolist() == [start | leg, 0, leg, leg]
    assert p.slots == 2 and p.scratch == 4
    assert np.all(np.diff(p.time) >= 0)
    with pytest.raises(bg.BananagridError, match=r"^definite_chords = 0: must be"):
        pack([track], 8.0, definite_chords=0)


def test_keys_name_the_evidence():
    with pytest.raises(bg.BananagridError, match=r"^scene\.evidence\[3\]\.t = 6\.0: after"):
        pack([bg.AreaSearch(SQUARE, t=6.0, pod=0.5)], 5.0, keys=["scene.evidence[3]"])
    with pytest.raises(bg.BananagridError, match=r"^keys: 2 names for 1 pieces of evidence"):
        pack([bg.AreaSearch(SQUARE, t=1.0, pod=0.5)], 5.0, keys=["a", "b"])


def test_area_panels():
    """More panels over an interval: more nodes, the same total weight; a count that is not a
    positive integer refused in one line."""
    e = bg.AreaSearch(SQUARE, t=(1.0, 3.0), coverage=1.0)
    p = pack([e], 5.0, area_panels=40)
    assert p.nodes == 40 * PANEL_NODES and math.isclose(p.q.sum(), 2.0, rel_tol=1e-14)
    with pytest.raises(bg.BananagridError, match=r"^area_panels = 0") as caught:
        pack([e], 5.0, area_panels=0)
    assert "\n" not in str(caught.value)
