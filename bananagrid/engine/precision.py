"""The dtype a kernel computes in: float32 only where float32 coordinates resolve the model.

A float32 kernel receives its points' world coordinates rounded to float32, 2^-24 of their
size: far from the world origin (a projected chart's northings, a pose kilometres away) that
rounding can exceed a fine feature of the density (a thin banana, a sharp start), and no
float32 arithmetic can give the density at the point asked for. There the engine computes in
float64 and rounds the result to float32, so a float32 map is always the float64 map to within
the model's ``float32_rtol`` and the density's change over its coordinates' rounding.
"""

from __future__ import annotations

import numpy as np

from ..protocol import DensityModel

__all__ = ["FLOAT32_RESOLUTION", "working_dtype"]

#: float32 is used only where the rounding of the farthest coordinate, 2^-24 of its size, is at
#: most this fraction of the model's smallest feature (``feature_scale``): the density then
#: moves by about this fraction times its log-slope in feature units over the rounding, within
#: the float32 bounds the models state (2e-4 and below).
FLOAT32_RESOLUTION = 1e-4
_FLOAT32_ULP = 2.0**-24


def working_dtype(model: DensityModel, dtype, farthest: float) -> np.dtype:
    """The dtype to compute ``model`` in when ``dtype`` is asked for and the points lie within
    ``farthest`` metres of the world origin: ``dtype``, except float64 for float32 where
    ``2^-24 farthest > FLOAT32_RESOLUTION feature_scale``."""
    dtype = np.dtype(dtype)
    if dtype != np.float32:
        return dtype
    if _FLOAT32_ULP * farthest > FLOAT32_RESOLUTION * float(model.feature_scale()):
        return np.dtype(np.float64)
    return dtype
