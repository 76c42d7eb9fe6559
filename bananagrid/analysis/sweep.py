"""The Figure 7 study of the polar-banana paper: how good is the improved approximation over the
whole range of settings?

Section 6.2: the CAT position is v0 t times a function of omega t and a t / v0 only, so the
goodness of Section 6.1 depends on sigma_a t / v0 and sigma_omega t alone, and v0 t is a scale
(here v0 t = 1000 m, t = 10 s). The study grids sigma_a t / v0 over (0, 0.2] and sigma_omega t
over (0, 75 deg] with ``n`` values each, cell-centred ((k + 1/2) / n of each range: the models
need both SDs > 0), and computes for each setting the goodness of the improved approximation
with the exact CAT as truth.

Each setting is sampled on a lattice that follows its own banana (a Cartesian grid fine enough
for the thinnest bananas would need 10^7 cells): bearings phi over +-min(pi, 6 sigma_phi), and at
each bearing ranges over P_mu(phi) +- 6.5 s(phi) (together they leave out about 1e-9 of the
mass, far below Figure 7's finest contour, 0.99999), s(phi) = sigma_a t^2 / 2 scc(phi) (the range
SD of Section 4.3; scc >= 1/3 on [0, pi]), both by the midpoint rule, each node standing for
its polar area r dr dphi. :func:`sweep_point` on Figure 1's setting gives the single-scene
``compare`` figure 0.99992 (tests/analysis/test_compare.py checks the two agree, and that doubling the
lattice changes the goodness by less than 1e-5).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..engine.points import evaluate_points
from ..models.cat import CAT
from ..models.polar import PolarBanana
from ..validate import BananagridError, positive, positive_int
from .compare import DEFAULT_THRESHOLD, compare_samples

__all__ = ["SweepResult", "sweep", "sweep_point", "banana_lattice", "ALPHA_MAX", "BETA_MAX_DEG"]

#: Ranges of the study (Section 6.3).
ALPHA_MAX = 0.2
BETA_MAX_DEG = 75.0
#: v0 t = V0 T = 1000 m: only a scale (Section 6.2).
V0, T = 100.0, 10.0
#: Lattice of each setting: bearings x ranges.
BEARING_NODES = 160
RANGE_NODES = 104
RANGE_SDS = 6.5
BEARING_SDS = 6.0
#: The paper's claim (Section 6.3): below these the goodness is at least CLAIM_LEVEL.
CLAIM_ALPHA, CLAIM_BETA_DEG, CLAIM_LEVEL = 0.1, 42.0, 0.999
#: Contour levels of Figure 7's goodness map.
FIGURE7_LEVELS = (0.99, 0.999, 0.9999, 0.99999)


@dataclass(frozen=True)
class SweepResult:
    """Goodness over the grid of settings.

    Attributes
    ----------
    alpha : ndarray (n,)
        sigma_a t / v0 values.
    beta : ndarray (n,)
        sigma_omega t values, radians.
    goodness : ndarray (n, n)
        goodness[i, j] at beta[i], alpha[j] (rows: sigma_omega t, as Figure 7's vertical axis).
    threshold : float
    seconds : float
    """

    alpha: np.ndarray
    beta: np.ndarray
    goodness: np.ndarray
    threshold: float
    seconds: float

    def claim(self) -> dict:
        """The paper's claim checked on this grid: the least goodness over the settings with
        alpha < 0.1 and beta < 42 deg, and, for each alpha, the largest beta whose goodness (and
        that of every smaller beta) is at least 0.999: where the 99.9% contour lies."""
        inside = (self.alpha[None, :] < CLAIM_ALPHA) & (self.beta[:, None] < math.radians(CLAIM_BETA_DEG))
        least = float(self.goodness[inside].min()) if inside.any() else math.nan
        contour = []
        for j, a in enumerate(self.alpha):
            ok = self.goodness[:, j] >= CLAIM_LEVEL
            k = int(np.argmin(ok)) if not ok.all() else len(ok)
            contour.append(math.degrees(self.beta[k - 1]) if k > 0 else math.nan)
        return {
            "least_goodness_in_claim_region": least,
            "claim_holds_on_grid": bool(least >= CLAIM_LEVEL),
            "contour_999_beta_deg": np.array(contour),
        }


def _settings(alpha: float, beta: float) -> dict:
    return dict(v0=V0, t=T, sigma_a=alpha * V0 / T, sigma_omega=beta / T)


def banana_lattice(alpha: float, beta: float, *, bearings: int = BEARING_NODES, ranges: int = RANGE_NODES):
    """Sample points (x, y) of the local frame and their polar areas for one setting."""
    params = _settings(alpha, beta)
    sigma_phi = 0.5 * beta
    phi_max = min(math.pi, BEARING_SDS * sigma_phi)
    dphi = 2.0 * phi_max / bearings
    phi = -phi_max + dphi * (np.arange(bearings) + 0.5)
    polar = PolarBanana(**params, variant="improved")
    with np.errstate(all="ignore"):
        mean = polar.p_mu(phi)
    sinc = np.sinc(phi / np.pi)
    scc = (4.0 * sinc - np.cos(phi)) / 3.0
    sd = 0.5 * params["sigma_a"] * T**2 * scc
    lo = np.maximum(0.0, mean - RANGE_SDS * sd)
    hi = mean + RANGE_SDS * sd
    dr = (hi - lo) / ranges
    r = lo[:, None] + dr[:, None] * (np.arange(ranges) + 0.5)[None, :]
    x = r * np.sin(phi)[:, None]
    y = r * np.cos(phi)[:, None]
    area = r * dr[:, None] * dphi
    return x, y, area


def sweep_point(alpha: float, beta: float, *, threshold=DEFAULT_THRESHOLD, threads=None,
                bearings: int = BEARING_NODES, ranges: int = RANGE_NODES) -> float:
    """Goodness of the improved approximation at sigma_a t / v0 = alpha, sigma_omega t = beta
    (radians), exact CAT as truth, on the setting's banana lattice."""
    alpha = positive("alpha", alpha)
    beta = positive("beta", beta)
    params = _settings(alpha, beta)
    x, y, area = banana_lattice(alpha, beta, bearings=bearings, ranges=ranges)
    exact = evaluate_points(CAT(**params), x, y, threads=threads)
    approx = evaluate_points(PolarBanana(**params, variant="improved"), x, y, threads=threads)
    return compare_samples(exact, approx, area, levels=(1.0,), threshold=threshold).goodness


def sweep(n: int = 50, *, threshold=DEFAULT_THRESHOLD, threads=None,
          progress: Callable[[int, int], None] | None = None) -> SweepResult:
    """The Figure 7 study on an n x n grid of settings (see the module notes)."""
    n = positive_int("n", n)
    if n < 2:
        raise BananagridError(f"n = {n}: must be >= 2 (a grid of settings)")
    alpha = ALPHA_MAX * (np.arange(n) + 0.5) / n
    beta = math.radians(BETA_MAX_DEG) * (np.arange(n) + 0.5) / n
    goodness = np.empty((n, n))
    start = time.perf_counter()
    with warnings.catch_warnings():
        # large sigma_a t / v0: P_sigma (11) turns negative at large bearings (the model warns);
        # the improved density is 0 there and the goodness says how much that costs
        warnings.simplefilter("ignore", UserWarning)
        for i, b in enumerate(beta):
            for j, a in enumerate(alpha):
                goodness[i, j] = sweep_point(a, b, threshold=threshold, threads=threads)
            if progress is not None:
                progress(i + 1, n)
    return SweepResult(alpha, beta, goodness, threshold, time.perf_counter() - start)
