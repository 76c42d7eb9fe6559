"""Densities against Monte Carlo from each model's own generative story (``sample``).

Binned counts of N samples are compared with the bin probabilities integrated from the kernel
(midpoint rule on a sub-grid) by Pearson's chi-square test over bins expecting at least 5
counts (the rest pooled). Each test rejects a correct density with probability ALPHA; the seeds
are fixed, so the outcome is deterministic.
"""

import numpy as np
import pytest
from scipy import stats

import bananagrid as bg

from cases import FIG1, FOLDING

#: False-alarm rate of each chi-square test.
ALPHA = 1e-3
N_SAMPLES = 400_000
#: Bins of BIN m, integrated on SUB x SUB sub-cells. The midpoint rule's relative error is about
#: (h^2 / 24) |f''| / f with h = BIN / SUB = 5 m and the radial scale sigma_a t^2 / 2 = 83 m:
#: 1.5e-4, well below the 1 / sqrt(counts) >= 4e-3 statistical error of the fullest bins.
BIN = 200.0
SUB = 40

CASES = {
    "cat-fig1": (lambda: bg.CAT(**FIG1), dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0))),
    "rough-fig1": (lambda: bg.PolarBanana(**FIG1, variant="rough"), dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0))),
    "improved-fig1": (lambda: bg.PolarBanana(**FIG1), dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0))),
    "cat-folding": (lambda: bg.CAT(**FOLDING), dict(x=(-3200.0, 3200.0), y=(-2400.0, 3400.0))),
    "cat-posed": (
        lambda: bg.CAT(**FIG1, pose=bg.Pose(origin=(500.0, 200.0), heading=np.radians(-35.0))),
        dict(x=(-3000.0, 3000.0), y=(-600.0, 3600.0)),
    ),
}


def bin_probabilities(model, bounds):
    """Probability of each BIN x BIN bin: kernel densities on a sub-grid, midpoint rule."""
    fine = bg.Grid.from_bounds(**bounds, step=BIN / SUB)
    values = bg.rasterise(model, fine).values
    ny, nx = values.shape[0] // SUB, values.shape[1] // SUB
    blocks = values[: ny * SUB, : nx * SUB].reshape(ny, SUB, nx, SUB)
    return blocks.sum(axis=(1, 3)) * fine.cell_area, fine


@pytest.mark.parametrize("case", CASES)
def test_density_matches_samples(case):
    make, bounds = CASES[case]
    model = make()
    probs, fine = bin_probabilities(model, bounds)
    pts = model.sample(N_SAMPLES, np.random.default_rng(20261121))
    x0, y0 = fine.origin
    ny, nx = probs.shape
    counts, _, _ = np.histogram2d(
        pts[:, 1], pts[:, 0], bins=(ny, nx), range=((y0, y0 + ny * BIN), (x0, x0 + nx * BIN))
    )
    expected = probs * N_SAMPLES
    outside_expected = N_SAMPLES - expected.sum()
    outside_observed = N_SAMPLES - counts.sum()
    big = expected >= 5
    obs = np.append(counts[big], counts[~big].sum() + outside_observed)
    exp = np.append(expected[big], expected[~big].sum() + outside_expected)
    assert exp[-1] >= 0.0
    if exp[-1] < 5:  # too little pooled mass for Pearson's approximation: fold it into the test
        obs, exp = obs[:-1], exp[:-1] * (obs[:-1].sum() / exp[:-1].sum())
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    p_value = stats.chi2.sf(chi2, df=len(obs) - 1)
    assert p_value > ALPHA, f"chi2 = {chi2:.1f} on {len(obs) - 1} dof, p = {p_value:.2e}"
    # and the bins hold what the grid says it captured
    assert abs(counts.sum() / N_SAMPLES - probs.sum()) < 5 * np.sqrt(probs.sum() * (1 - probs.sum()) / N_SAMPLES) + 1e-4
