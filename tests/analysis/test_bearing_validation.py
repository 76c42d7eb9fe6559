"""The bearing validation table: Monte Carlo of the exact crossing against Walsh's linearised radii."""

import math
import warnings

import numpy as np
import pytest

from bananagrid import BananagridError
from bananagrid.models.bearing import BearingFix, bearing_to
from bananagrid.analysis.bearing_validation import (
    crossings,
    format_table,
    standard_geometry,
    summary,
    validation_table,
)

FIELDS = {"gamma_deg", "sigma", "r50_m", "r95_m", "p50", "se50", "z50", "p95", "se95", "z95", "discarded", "verdict"}


@pytest.mark.parametrize("gamma", [2.0, 20.0, 45.0, 90.0, 133.0, 160.0, 178.0])
@pytest.mark.parametrize("baseline", [20_000.0, 3_000.0])
def test_true_bearings_cross_at_gamma(gamma, baseline):
    sensors, target, bearings = standard_geometry(gamma, baseline)
    np.testing.assert_array_equal(sensors, [[0.0, 0.0], [baseline, 0.0]])
    assert target[0] == pytest.approx(baseline / 2, rel=1e-15) and target[1] > 0.0
    b = bearing_to(sensors, target)
    np.testing.assert_array_equal(b, bearings)
    # the directions from the stations to the contact differ by gamma, i.e. the lines cross at
    # gamma at the contact (bearing 0 points into +y, so b1 > 0 > b2 = -b1)
    assert math.degrees(b[0] - b[1]) == pytest.approx(gamma, rel=1e-13)
    assert b[0] == pytest.approx(-b[1], rel=1e-15)


def test_crossings_match_bearing_fix_and_discard_behind():
    """The vectorised crossing equals BearingFix's fix (a least-squares solve), and the
    discard rule agrees with BearingFix's refusal of lines crossing behind a station."""
    sensors, target, bearings = standard_geometry(160.0)  # interior angles 10 deg at the stations
    deltas = np.array([[0.01, -0.02], [-0.05, 0.03], [0.1, 0.1], [0.0, 0.0],
                       [0.2, 0.0],  # station 1's line turned 11.5 deg clockwise: behind station 2
                       [0.0, -0.2]])  # mirror image: behind station 1
    b1, b2 = bearings[0] + deltas[:, 0], bearings[1] + deltas[:, 1]
    fx, fy, kept = crossings(sensors, b1, b2)
    np.testing.assert_array_equal(kept, [True, True, True, True, False, False])
    np.testing.assert_allclose([fx[3], fy[3]], target, rtol=1e-12)
    for i in range(len(deltas)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if kept[i]:
                fix = BearingFix(sensors, [b1[i], b2[i]], [0.01, 0.01]).fix
                np.testing.assert_allclose([fx[i], fy[i]], fix, rtol=1e-10)
            else:
                with pytest.raises(BananagridError, match="behind sensor"):
                    BearingFix(sensors, [b1[i], b2[i]], [0.01, 0.01])
    # parallel lines: no crossing at all
    assert not crossings(sensors, np.array([0.3]), np.array([0.3]))[2][0]


def test_small_sigma_matches_linearisation():
    """sigma = 0.001 rad at 90 deg: the nonlinearity is negligible (the table's P(R95) deviation
    grows like sigma^2: -0.0017 at 0.05 rad, so ~1e-6 here), so the empirical containment is
    binomial around 0.5 / 0.95.  Tolerance 3 binomial SE (null SE, n = 200,000: 0.0034 at 0.5,
    0.0015 at 0.95), stricter than the table's 0.005 floor; false-alarm rate (over seeds)
    <= 2 x 0.27 % = 0.54 %.  n = 200,000 costs under 1 s; a smaller n would only loosen the check."""
    n = 200_000
    (rec,) = validation_table([90.0], [0.001], n=n, seed=0)
    assert set(rec) == FIELDS
    assert rec["verdict"] == "holds"
    assert rec["discarded"] == 0.0
    for p0, key in ((0.5, "50"), (0.95, "95")):
        se0 = math.sqrt(p0 * (1 - p0) / n)
        assert abs(rec[f"p{key}"] - p0) <= 3 * se0
        assert rec[f"z{key}"] == pytest.approx((rec[f"p{key}"] - p0) / se0)
        assert rec[f"se{key}"] == pytest.approx(math.sqrt(rec[f"p{key}"] * (1 - rec[f"p{key}"]) / n))
    # the radii are the linearised model's at the true bearings (isotropic check: 90 deg,
    # equal sigmas, equal ranges r = D / sqrt(2) -> covariance (sigma r)^2 I, Rayleigh radii)
    s = 0.001 * 20_000.0 / math.sqrt(2.0)
    assert rec["r50_m"] == pytest.approx(s * math.sqrt(-2 * math.log(0.5)), rel=1e-12)
    assert rec["r95_m"] == pytest.approx(s * math.sqrt(-2 * math.log(0.05)), rel=1e-12)


def test_large_sigma_shallow_crossing_fails():
    """sigma = 0.05 rad, gamma = 20 deg: the banana-shaped true error spills out of the
    linearised R95.  Measured (n = 200,000, seed 0): P(R95) = 0.9194, 0.031 below 0.95
    (z = -62.8); P(R50) = 0.5034 (+3.0 SE).  n = 20,000 suffices: the tolerance is then
    max(3 x 0.0015, 0.005) = 0.005 and the deviation is ~20 SE, six times the tolerance."""
    (rec,) = validation_table([20.0], [0.05], n=20_000, seed=0)
    assert rec["verdict"] == "fails"
    assert rec["p95"] < 0.95 - 0.02
    assert rec["z95"] < -10


def test_cells_depend_only_on_their_own_parameters():
    """Common random numbers: a cell is the same whatever else is in the table."""
    alone = validation_table([90.0], [0.01], n=5000, seed=3)
    table = validation_table([20.0, 90.0], [0.005, 0.01], n=5000, seed=3)
    assert [(r["gamma_deg"], r["sigma"]) for r in table] == [(20.0, 0.005), (20.0, 0.01), (90.0, 0.005), (90.0, 0.01)]
    assert table[3] == alone[0]
    for rec in table:
        assert all(type(rec[k]) is float for k in FIELDS - {"verdict"})
        assert rec["verdict"] in ("holds", "fails")


def test_format_table_and_summary():
    records = validation_table([40.0, 90.0, 160.0], [0.01, 0.05], n=2000, seed=1)
    text = format_table(records)
    lines = text.splitlines()
    for column in ("gamma", "sigma", "R50 m", "R95 m", "P(R50)", "P(R95)", "z50", "z95", "discard", "verdict"):
        assert column in lines[0]
    assert set(lines[1]) == {"-"}
    rows = lines[2:]
    assert len(rows) == len(records) == 6
    assert len({len(line) for line in lines}) == 1  # fixed width
    for row, rec in zip(rows, records):
        fields = row.split()
        assert float(fields[0]) == rec["gamma_deg"] and float(fields[1]) == rec["sigma"]
        assert fields[-1] == rec["verdict"]
    text = summary(records)
    assert "\n" not in text
    assert f"in {sum(r['verdict'] == 'holds' for r in records)} of 6 cells" in text


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"gammas_deg": [90.0, 0.0]}, "gammas_deg[1] = 0.0: must be in (0, 180) deg, exclusive"),
        ({"gammas_deg": [180]}, "gammas_deg[0] = 180.0: must be in (0, 180) deg, exclusive"),
        ({"gammas_deg": [math.nan]}, "gammas_deg[0] = nan: must be in (0, 180) deg, exclusive"),
        ({"gammas_deg": [1.0]}, "gammas_deg[0] = 1.0: must be in [2, 178] deg: BearingFix refuses"),
        ({"gammas_deg": ["90"]}, "gammas_deg[0] = '90': expected a real number"),
        ({"gammas_deg": []}, "gammas_deg = []: must not be empty"),
        ({"gammas_deg": 90.0}, "gammas_deg = 90.0: expected a sequence of numbers"),
        ({"sigmas": [0.01, 0.0]}, "sigmas[1] = 0.0: must be finite and > 0 (radians)"),
        ({"sigmas": [-0.01]}, "sigmas[0] = -0.01: must be finite and > 0 (radians)"),
        ({"sigmas": [math.inf]}, "sigmas[0] = inf: must be finite and > 0 (radians)"),
        ({"n": 999}, "n = 999: must be an integer >= 1000"),
        ({"n": 5000.0}, "n = 5000.0: expected an integer >= 1000"),
        ({"n": True}, "n = True: expected an integer >= 1000"),
        ({"baseline": 0.0}, "baseline = 0.0: must be finite and > 0 (metres)"),
        ({"baseline": math.nan}, "baseline = nan: must be finite and > 0 (metres)"),
        ({"seed": -1}, "seed = -1: must be an integer >= 0"),
    ],
)
def test_bad_arguments(kwargs, message):
    with pytest.raises(BananagridError) as err:
        validation_table(**kwargs)
    assert str(err.value).startswith(message)
