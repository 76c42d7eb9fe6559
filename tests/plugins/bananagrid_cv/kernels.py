"""Warp kernels of the constant-velocity target: a bivariate normal density per cell or point.

``params`` = (mean_x, mean_y, a, b, c, norm): the mean at t, the inverse covariance
[[a, b], [b, c]] and 1 / (2 pi sqrt(det)).
"""

from typing import Any

import warp as wp


@wp.func
def cv_density(x: Any, y: Any, params: wp.array(dtype=Any)):
    dx = x - params[0]
    dy = y - params[1]
    q = params[2] * dx * dx + type(x)(2.0) * params[3] * dx * dy + params[4] * dy * dy
    return params[5] * wp.exp(type(x)(-0.5) * q)


@wp.kernel
def cv_grid(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), row0: int, params: wp.array(dtype=Any),
            out: wp.array2d(dtype=Any)):
    i, j = wp.tid()
    out[row0 + i, j] = cv_density(xs[j], ys[row0 + i], params)


@wp.kernel
def cv_points(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), start: int, params: wp.array(dtype=Any),
              out: wp.array(dtype=Any)):
    k = start + wp.tid()
    out[k] = cv_density(xs[k], ys[k], params)


for _scalar in (wp.float32, wp.float64):
    _vec = wp.array(dtype=_scalar)
    wp.overload(cv_grid, {"xs": _vec, "ys": _vec, "params": _vec, "out": wp.array2d(dtype=_scalar)})
    wp.overload(cv_points, {"xs": _vec, "ys": _vec, "params": _vec, "out": _vec})
