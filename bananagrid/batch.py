"""Many hypotheses at once (a tracker's gating and association step).

:func:`rasterise_batch` rasterises thousands of PolarBanana hypotheses, each on its own small
grid framed about its banana, in one kernel over (hypothesis, row); :func:`pdf_batch` scores
every point against every hypothesis. Both run the same device function as
:func:`bananagrid.rasterise` and ``pdf``, so their values are bit-identical to one hypothesis
at a time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .grid import Grid
from .models import PolarBanana
from .validate import BananagridError, positive, positive_int

__all__ = ["BatchRaster", "frame", "rasterise_batch", "pdf_batch", "FRAME_SDS"]

#: A framed grid holds the banana to this many SDs in range and bearing.
FRAME_SDS = 4.0


@dataclass(frozen=True)
class BatchRaster:
    """Densities of H hypotheses on their own grids of one shape.

    Attributes
    ----------
    values : ndarray (H, ny, nx)
        Density per m^2 at each grid's cell centres (raw, not normalised).
    grids : tuple of Grid
    mass : ndarray (H,)
        Captured mass of each (sum of values times its cell area).
    """

    values: np.ndarray
    grids: tuple
    mass: np.ndarray


def frame(models, shape=(64, 64), *, sds: float = FRAME_SDS) -> list[Grid]:
    """Grids of ``shape`` = (ny, nx) cells framing each model's banana (vectorised over the
    models): the world bounding box of bearings within +-min(pi, sds sigma_theta) and ranges
    within v0 t sinc(theta) -+ sds s, with s = sigma_a t^2 / 2 + 0.44 v0 t sigma_bar a bound on
    the SD of r given the bearing (P_sigma <= sigma_a t^2 / 2 (1 + sigma_a^2 t^2 / (72 v0^2)),
    |P_mu - v0 t sinc| << s, and the heading blur adds |P_mu'| sigma_bar with
    |sinc'| <= 0.44), and the origin."""
    models = _models(models)
    ny, nx = (positive_int("shape[0]", shape[0]), positive_int("shape[1]", shape[1]))
    sds = positive("sds", sds)
    v0t = np.array([m.v0 * m.t for m in models])[:, None]
    spread = np.array([0.5 * m.sigma_a * m.t**2 * (1 + (m.sigma_a * m.t / m.v0) ** 2 / 72) for m in models])[:, None]
    spread = spread + 0.44 * v0t * np.array([m.sigma_bar for m in models])[:, None]
    top = np.minimum(math.pi, sds * np.array([m.sigma_theta for m in models]))[:, None]
    b = top * np.linspace(-1.0, 1.0, 129)[None, :]
    mean = v0t * np.sinc(b / math.pi)
    r = np.concatenate([np.maximum(0.0, mean - sds * spread), mean + sds * spread, np.zeros_like(mean[:, :1])], axis=1)
    b = np.concatenate([b, b, np.zeros_like(b[:, :1])], axis=1)
    lx, ly = r * np.sin(b), r * np.cos(b)
    heading = np.array([m.pose.heading for m in models])[:, None]
    origin = np.array([m.pose.origin for m in models])
    c, s = np.cos(heading), np.sin(heading)
    wx = origin[:, :1] + lx * c + ly * s
    wy = origin[:, 1:] - lx * s + ly * c
    grids = []
    for x0, x1, y0, y1 in zip(wx.min(axis=1), wx.max(axis=1), wy.min(axis=1), wy.max(axis=1)):
        grids.append(Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / nx, dy=(y1 - y0) / ny))
    return grids


def _models(models) -> list:
    models = list(models)
    if not models:
        raise BananagridError("models: expected at least one hypothesis")
    for k, m in enumerate(models):
        if not isinstance(m, PolarBanana):
            raise BananagridError(f"models[{k}] = {type(m).__name__}: batches take PolarBanana hypotheses")
    return models


def rasterise_batch(models: Sequence[PolarBanana], grids: Sequence[Grid] | None = None, *, shape=(64, 64),
                    dtype=np.float64, device: str = "cpu", threads=None) -> BatchRaster:
    """Rasterise every hypothesis on its own grid in one launch.

    ``grids``: one per hypothesis, all of one shape; by default :func:`frame` of the
    hypotheses at ``shape``.
    """
    from .raster import launch_polar_batch

    models = _models(models)
    if grids is None:
        grids = frame(models, shape)
    grids = tuple(grids)
    if len(grids) != len(models):
        raise BananagridError(f"grids: {len(grids)} grids for {len(models)} hypotheses")
    for k, g in enumerate(grids):
        if not isinstance(g, Grid):
            raise BananagridError(f"grids[{k}] = {g!r}: expected a bananagrid.Grid")
        if g.shape != grids[0].shape:
            raise BananagridError(f"grids[{k}]: shape {g.shape}, but grids[0] has {grids[0].shape}; one shape for all")
    xs = np.stack([g.x for g in grids])
    ys = np.stack([g.y for g in grids])
    values = launch_polar_batch(models, xs, ys, dtype=dtype, device=device, threads=threads)
    areas = np.array([g.cell_area for g in grids])
    mass = values.sum(axis=(1, 2), dtype=np.float64) * areas
    return BatchRaster(values, grids, mass)


def pdf_batch(models: Sequence[PolarBanana], x, y, *, dtype=np.float64, device: str = "cpu", threads=None) -> np.ndarray:
    """Density of every world point (x, y broadcast to N points) under every hypothesis: (H, N)."""
    from .raster import launch_polar_batch_points

    models = _models(models)
    try:
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    except ValueError:
        raise BananagridError(f"x and y: shapes {np.shape(x)} and {np.shape(y)} do not broadcast") from None
    if not (np.isfinite(bx).all() and np.isfinite(by).all()):
        raise BananagridError("x, y: points must be finite (NaN or inf given)")
    return launch_polar_batch_points(models, bx.ravel(), by.ravel(), dtype=dtype, device=device, threads=threads)
