"""Comparing an approximation with a reference density: Tables 1 and 2 and Section 6.1 of the
polar-banana paper, and the Bhattacharyya coefficient.

With the reference p and the model q sampled at points with areas A_k (cell areas of a grid, or
the area elements of any lattice), and M = sum_k p_k A_k the reference's captured mass:

- for each density level L (per m^2), the reference's mass inside its contour,
  sum over {p >= L} of p_k A_k / M, and the maximal relative error max |q_k / p_k - 1| there
  (Tables 1 and 2);
- the goodness of Section 6.1: with the points sorted by p, the first point whose relative
  error is at least ``threshold`` (5%) fixes a contour level; the goodness is the mass strictly
  above that level over M (M / M = 1 if no point errs that much);
- the Bhattacharyya coefficient sum_k sqrt(p_k q_k) A_k / sqrt(M M_q), with M_q the model's
  captured mass: 1 for identical densities, 0 for disjoint ones.

The contour levels are applied to the reference as given (not normalised): on the paper's
frame the exact CAT captures 1 - 7e-9 of its mass, so this is the paper's reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..results import Raster
from ..validate import BananagridError, positive
from ..contours import DEFAULT_LEVELS

__all__ = ["Comparison", "ContourRow", "compare", "compare_samples", "DEFAULT_THRESHOLD"]

#: Relative error that ends the goodness contour (Section 6.1).
DEFAULT_THRESHOLD = 0.05


@dataclass(frozen=True)
class ContourRow:
    """One column of Tables 1 and 2: the reference's ``level`` contour, the reference's
    probability ``mass`` inside it (fraction of its captured mass), the model's largest
    relative error ``max_rel_error`` inside it and how many ``points`` it holds."""

    level: float
    mass: float
    max_rel_error: float
    points: int


@dataclass(frozen=True)
class Comparison:
    """The comparison of a model with a reference (see the module notes).

    Attributes
    ----------
    rows : tuple of ContourRow
        One per level, in the order given.
    goodness : float
        Mass inside the largest reference contour within which the model's relative error stays
        below ``threshold``.
    threshold : float
    bhattacharyya : float
    relative_error : ndarray or None
        q / p - 1 at every point (NaN where p = 0), shaped like the inputs.
    """

    rows: tuple
    goodness: float
    threshold: float
    bhattacharyya: float
    relative_error: np.ndarray | None = None

    def table(self) -> str:
        """Tables 1 and 2 as text, with the goodness and the Bhattacharyya coefficient."""
        head = f"{'contour [m^-2]':<28}" + "".join(f"{r.level:>12.3g}" for r in self.rows)
        mass = f"{'mass inside [%]':<28}" + "".join(f"{100 * r.mass:>12.6g}" for r in self.rows)
        error = f"{'max relative error [%]':<28}" + "".join(f"{100 * r.max_rel_error:>12.5g}" for r in self.rows)
        return "\n".join((
            head, mass, error,
            f"goodness ({100 * self.threshold:g}% error): {self.goodness:.7f}",
            f"Bhattacharyya coefficient: {self.bhattacharyya:.9f}",
        ))

    def summary(self) -> dict:
        """Flat numbers for recordings and JSON."""
        out = {"goodness": self.goodness, "threshold": self.threshold, "bhattacharyya": self.bhattacharyya}
        for r in self.rows:
            out[f"mass_inside_{r.level:g}"] = r.mass
            out[f"max_rel_error_{r.level:g}"] = r.max_rel_error
        return out


def _levels(levels) -> tuple[float, ...]:
    try:
        values = tuple(levels)
    except TypeError:
        raise BananagridError(f"levels = {levels!r}: expected a sequence of densities (m^-2)") from None
    if not values:
        raise BananagridError("levels = (): expected at least one density level (m^-2)")
    return tuple(positive(f"levels[{k}]", v) for k, v in enumerate(values))


def _threshold(threshold) -> float:
    value = positive("threshold", threshold)
    if not value < 1.0:
        raise BananagridError(f"threshold = {value!r}: must be in (0, 1) (a relative error)")
    return value


def compare_samples(reference: ArrayLike, model: ArrayLike, areas: ArrayLike, *, levels=DEFAULT_LEVELS, threshold=DEFAULT_THRESHOLD) -> Comparison:
    """Compare densities sampled at the same points, each with its area element.

    Parameters
    ----------
    reference, model : array_like
        Densities per m^2 (any shape, the same for both), finite and >= 0.
    areas : float or array_like
        Area (m^2) each point stands for; broadcast against the densities.
    levels : sequence of float
        Reference contour levels, per m^2.
    threshold : float
        Relative error ending the goodness contour, in (0, 1).
    """
    p = np.asarray(reference, dtype=np.float64)
    q = np.asarray(model, dtype=np.float64)
    if p.shape != q.shape:
        raise BananagridError(f"reference and model: shapes {p.shape} and {q.shape} differ")
    for name, values in (("reference", p), ("model", q)):
        if not np.all(np.isfinite(values)) or (values < 0).any():
            raise BananagridError(f"{name}: densities must be finite and >= 0")
    area = np.broadcast_to(np.asarray(areas, dtype=np.float64), p.shape)
    if not np.all(np.isfinite(area)) or not (area > 0).all():
        raise BananagridError("areas: must be finite and > 0")
    levels = _levels(levels)
    threshold = _threshold(threshold)
    weight = p * area
    total = float(weight.sum())
    if not total > 0.0:
        raise BananagridError("reference: captured no mass (all densities are 0)")
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.where(p > 0.0, q / p - 1.0, np.nan)
    rows = []
    for level in levels:
        inside = p >= level
        rows.append(ContourRow(
            level=level,
            mass=float(weight[inside].sum() / total),
            max_rel_error=float(np.max(np.abs(relative[inside]))) if inside.any() else math.nan,
            points=int(inside.sum()),
        ))
    goodness = _goodness(p.ravel(), relative.ravel(), weight.ravel(), total, threshold)
    model_total = float((q * area).sum())
    bhattacharyya = float(np.sum(np.sqrt(p * q) * area) / math.sqrt(total * model_total)) if model_total > 0 else 0.0
    return Comparison(tuple(rows), goodness, threshold, bhattacharyya, relative)


def _goodness(p, relative, weight, total, threshold) -> float:
    """Mass strictly above the reference level of the densest point that errs by threshold or
    more (where p = 0 the error is undefined and counts as a failure)."""
    order = np.argsort(-p, kind="stable")
    bad = ~(np.abs(relative[order]) < threshold)
    if not bad.any():
        return 1.0
    level = p[order][np.argmax(bad)]
    return float(weight[p > level].sum() / total)


def compare(reference: Raster, model: Raster, *, levels=DEFAULT_LEVELS, threshold=DEFAULT_THRESHOLD) -> Comparison:
    """Compare two rasters of one grid (Tables 1 and 2, Section 6.1, Bhattacharyya).

    Both are used as given (raw or normalised); see the module notes for the definitions.
    """
    for name, raster in (("reference", reference), ("model", model)):
        if not isinstance(raster, Raster):
            raise BananagridError(f"{name} = {type(raster).__name__}: expected a bananagrid.Raster")
    if reference.grid != model.grid:
        raise BananagridError(
            f"model: its grid {model.grid.describe()} is not the reference's {reference.grid.describe()}"
        )
    return compare_samples(
        reference.values, model.values, reference.grid.cell_area, levels=levels, threshold=threshold
    )
