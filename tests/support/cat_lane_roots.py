"""How far the CAT's lane root search (``kernels/lanes.py``: ``lane_cat_roots``, the CPU's grid
and points kernels) may be from the scalar one (``kernels/cat.py``: ``cat_root_density``, the
GPU path's), cell by cell: the same roots of the same brackets, taken with other roundings
(polynomial sine and exp, reciprocals, fused multiply-adds)."""

import numpy as np

#: float64: each root's density takes a sine, an exp and a few reciprocals, each within a few
#: ulp of libm's, and 1 / |dF/domega| amplifies them where dF/domega cancels near a fold:
#: measured at most 1.5e-12 relative over the sweeps of ``tests/kernels``; 1e-11 allows ~7x.
#: Densities below 1e-290 (subnormal products: a few bits each) are held to that much absolutely.
RTOL64 = 1e-11
ATOL64 = 1e-290
#: float32: the CAT's stated float32 tolerance, 2e-4 relative (``tests/models/test_float32_sweep.py``),
#: and 1e-4 of the map's peak beside the folds, where float32's dF/domega at a root has few digits
#: left (that test holds float32 there to the density's change over a rounding, not to a relative
#: bound); measured at most 0.2 of this bound over the sweeps of ``tests/kernels``.
RTOL32 = 2e-4
PEAK32 = 1e-4


def lane_roots_agree(lanes: np.ndarray, scalar: np.ndarray) -> np.ndarray:
    """Cells where the lane kernel's densities ``lanes`` are within the bounds above of the
    scalar kernel's ``scalar`` (both of one dtype)."""
    lanes = lanes.astype(np.float64)
    reference = scalar.astype(np.float64)
    if scalar.dtype == np.float64:
        bound = RTOL64 * reference + ATOL64
    else:
        bound = RTOL32 * reference + PEAK32 * reference.max(initial=0.0)
    return np.abs(lanes - reference) <= bound
