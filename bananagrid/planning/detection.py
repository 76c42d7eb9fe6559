"""Detection laws: the probability of detecting a target in a cell given the search effort
spent there.

A law is a function b(e) of the coverage e = z / A (the effort z, in m^2 of swept area,
sweep width times track length, over the cell's area A): the probability that a target in the
cell is detected. The optimal plans of :mod:`~bananagrid.planning.allocation` need b
increasing and concave with b(0) = 0 (Stone, *Theory of Optimal Search*, 1975, ch. 2: a
"regular" detection function), its derivative b' and, where it has one in closed form, the
inverse of b'.

The laws provided:

* ``"exponential"``: random search, b(e) = 1 - exp(-e) (Koopman 1946; Stone eq. (2.2.3)).
* ``"inverse_cube"``: parallel sweeps at track spacing S = W / e under Koopman's inverse-cube
  sighting law, b(e) = erf(sqrt(pi) e / 2) (Koopman 1946; Washburn, *Search and Detection*,
  eq. (2-8)).
* ``"definite"``: a definite-range sensor on perfect parallel sweeps, b(e) = min(e, 1); concave
  but not strictly, so its plan is the greedy one (fill the densest cells first).

Any other law: :class:`DetectionLaw` with ``pod`` and ``dpod`` callables, checked to be
increasing and concave on a sample of coverages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import special

from ..validate import BananagridError

#: Coverages the check of a user's law samples (0 to 50: b is within 1e-21 of its limit there
#: for the provided laws, and a law concave up to it is what a plan can use).
_CHECK_COVERAGES = np.concatenate([[0.0], np.geomspace(1e-6, 50.0, 400)])


@dataclass(frozen=True)
class DetectionLaw:
    """A detection law b(e) of the coverage e (effort per unit area): increasing, concave,
    b(0) = 0, b <= 1.

    Attributes
    ----------
    name : str
        How the law is shown in provenance and errors.
    pod : callable
        b(e), vectorised over a float64 array of coverages >= 0.
    dpod : callable
        b'(e), vectorised; positive and non-increasing (b concave).
    inverse_dpod : callable or None
        The coverage e >= 0 at which ln b'(e) = u, given u <= ln b'(0) (the logarithm keeps
        the precision of coverages near 0, where b'(e) is within rounding of b'(0)); None: found
        by bisection.
    strictly_concave : bool
        False for a law with flat pieces of b' (the definite-range law): its plan is greedy.
    """

    name: str
    pod: Callable[[np.ndarray], np.ndarray]
    dpod: Callable[[np.ndarray], np.ndarray]
    inverse_dpod: Callable[[np.ndarray], np.ndarray] | None = None
    strictly_concave: bool = True

    def __post_init__(self):
        if not (callable(self.pod) and callable(self.dpod)):
            raise BananagridError(f"law {self.name!r}: pod and dpod must be callables of the coverage")
        e = _CHECK_COVERAGES
        with np.errstate(all="ignore"):
            b, db = np.asarray(self.pod(e), dtype=float), np.asarray(self.dpod(e), dtype=float)
        if b.shape != e.shape or db.shape != e.shape:
            raise BananagridError(f"law {self.name!r}: pod and dpod must return one value per coverage")
        if not (np.isfinite(b).all() and np.isfinite(db).all()):
            raise BananagridError(f"law {self.name!r}: pod or dpod is not finite on coverages 0 to 50")
        if abs(b[0]) > 1e-15 or (b < -1e-15).any() or (b > 1.0 + 1e-15).any():
            raise BananagridError(f"law {self.name!r}: pod(0) must be 0 and pod within [0, 1]")
        if not db[0] > 0.0 or (db < 0.0).any():
            raise BananagridError(f"law {self.name!r}: dpod(0) must be positive and dpod never negative")
        # concave: b' non-increasing (a rounding's slack of 1e-12 of b'(0))
        if (np.diff(db) > 1e-12 * db[0]).any():
            raise BananagridError(f"law {self.name!r}: dpod increases somewhere on 0 to 50: the law is not "
                                  "concave, and a plan from the Lagrange condition would not be optimal")

    @property
    def initial_slope(self) -> float:
        """b'(0): a cell gets effort only where its density times b'(0) beats the multiplier."""
        return float(np.asarray(self.dpod(np.zeros(1)), dtype=float)[0])

    def coverage_at_log_slope(self, log_y: np.ndarray) -> np.ndarray:
        """The coverage e at which ln b'(e) = log_y (0 where log_y >= ln b'(0))."""
        log_y = np.asarray(log_y, dtype=float)
        top = math.log(self.initial_slope)
        if self.inverse_dpod is not None:
            return np.where(log_y >= top, 0.0, self.inverse_dpod(np.minimum(log_y, top)))
        # bisection on b' (non-increasing): bracket [0, hi] with ln b'(hi) <= log_y, then 200
        # halvings (to the last bit of any coverage below 2^64)
        y = np.exp(log_y)
        lo, hi = np.zeros_like(log_y), np.ones_like(log_y)
        for _ in range(64):
            short = np.asarray(self.dpod(hi), dtype=float) > y
            if not short.any():
                break
            hi = np.where(short, 2.0 * hi, hi)
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            above = np.asarray(self.dpod(mid), dtype=float) > y
            lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
        return np.where(log_y >= top, 0.0, hi)


EXPONENTIAL = DetectionLaw(
    "exponential", pod=lambda e: -np.expm1(-np.asarray(e, dtype=float)),
    dpod=lambda e: np.exp(-np.asarray(e, dtype=float)), inverse_dpod=lambda u: -u)

_HALF_SQRT_PI = 0.5 * math.sqrt(math.pi)
INVERSE_CUBE = DetectionLaw(
    "inverse_cube", pod=lambda e: special.erf(_HALF_SQRT_PI * np.asarray(e, dtype=float)),
    dpod=lambda e: np.exp(-0.25 * math.pi * np.asarray(e, dtype=float) ** 2),
    inverse_dpod=lambda u: np.sqrt(np.maximum(-4.0 / math.pi * u, 0.0)))

DEFINITE = DetectionLaw(
    "definite", pod=lambda e: np.minimum(np.asarray(e, dtype=float), 1.0),
    dpod=lambda e: np.where(np.asarray(e, dtype=float) < 1.0, 1.0, 0.0), strictly_concave=False)

LAWS = {law.name: law for law in (EXPONENTIAL, INVERSE_CUBE, DEFINITE)}


def detection_law(law) -> DetectionLaw:
    """The :class:`DetectionLaw` named by ``law`` (one of :data:`LAWS`), or ``law`` itself."""
    if isinstance(law, DetectionLaw):
        return law
    if isinstance(law, str) and law in LAWS:
        return LAWS[law]
    raise BananagridError(f"law = {law!r}: expected one of {', '.join(repr(k) for k in LAWS)} "
                          "or a bg.DetectionLaw")
