"""Recording the conditional radial curves of the polar-banana paper (Figures 2-5 and 8).

For a motion layer (CAT or PolarBanana, with or without heading noise) under
``radial/LAYER``:

- ``density/BEARINGdeg/{exact, normal, closed_form[, closed_form_order4]}``: p(r | theta) per
  metre at whole metres, numerically from the layer's density (:func:`radial.radial_density`),
  the normal law with the same mean and SD (Figure 2), and the normal law with the improved
  approximation's closed-form moments, P_mu and P_sigma or (15)-(16) with heading noise
  (Figure 8, both orders when there is heading noise);
- ``mean/{exact, sinc, p_mu}``: E[r | theta] against the bearing in degrees (Figure 3), the
  rough v0 t sinc and the improved P_mu ((15) with heading noise);
  ``mean_error/{sinc, p_mu}``: those minus the exact mean, metres (Figure 4);
- ``sd/{exact, p_sigma}``: SD[r | theta] and the improved P_sigma ((16)) (Figure 5);
- ``summary``: the largest deviations, as ``AnyValues``.

Curves are ``BarChart`` archetypes with their abscissa (range in m, or bearing in degrees), so
they show in bar-chart views whatever the time cursor, one chart per approximation overlaid.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

import rerun.blueprint as rrb

from ..analysis.radial import radial_moments, ray_density
from ..models.motion import MotionModel
from ..models.polar import PolarBanana
from .core import entity_path, strict

__all__ = ["radial_curves", "log_radial_curves", "radial_groups", "radial_views", "CURVE_COLOURS"]

CURVE_COLOURS = {
    "exact": (60, 120, 255),
    "normal": (255, 60, 60),
    "closed_form": (40, 200, 90),
    "closed_form_order4": (255, 170, 0),
    "sinc": (255, 60, 60),
    "p_mu": (40, 200, 90),
    "p_sigma": (40, 200, 90),
}


def _closed_form_model(model: MotionModel, order: int = 2) -> PolarBanana:
    """The improved polar approximation with the model's parameters and heading noise."""
    return PolarBanana(
        v0=model.v0, t=model.t, sigma_a=model.sigma_a, sigma_omega=model.sigma_omega,
        variant="improved", sigma_heading=model.sigma_heading, heading_order=order, pose=model.pose,
    )


def _normal(r: np.ndarray, mean: float, sd: float) -> np.ndarray:
    return np.exp(-0.5 * ((r - mean) / sd) ** 2) / (sd * math.sqrt(2.0 * math.pi))


def radial_curves(model: MotionModel, density_bearings=(), moments_max=0.0, moments_step=math.radians(2.0), *,
                  threads=None) -> dict:
    """The curves of :mod:`bananagrid.recording.radial` as arrays, keyed by their entity paths
    below ``radial/LAYER`` (each an (abscissa, values) pair), and a ``summary`` dict."""
    if not getattr(getattr(model, "scene", None), "radial_curves", False):  # the kind's schema says
        raise TypeError(f"radial curves need a motion model (CAT, PolarBanana), not {type(model).__name__}")
    orders = (2, 4) if model.sigma_heading > 0.0 else (2,)
    closed = {order: _closed_form_model(model, order) for order in orders}
    curves: dict = {}
    summary: dict = {}
    if density_bearings:
        laws = radial_moments(model, np.asarray(density_bearings, dtype=float), threads=threads)
    for k, bearing in enumerate(density_bearings):
        mean_k, sd_k, mass_k = float(laws.mean[k]), float(laws.sd[k]), float(laws.mass[k])
        # whole metres over +-5 SD of the exact law
        r = np.arange(math.floor(max(0.0, mean_k - 5 * sd_k)), math.ceil(mean_k + 5 * sd_k) + 1, 1.0)
        density = ray_density(model, bearing, r, threads=threads) / mass_k
        normal = _normal(r, mean_k, sd_k)
        deg = f"{math.degrees(bearing):g}deg"
        curves[f"density/{deg}/exact"] = (r, density)
        curves[f"density/{deg}/normal"] = (r, normal)
        core = np.abs(r - mean_k) <= 3 * sd_k
        summary[f"density_{deg}_max_rel_dev_normal_3sd"] = float(np.max(np.abs(normal[core] / density[core] - 1)))
        for order, polar in closed.items():
            mean, sd = (float(v[0]) for v in polar.conditional_moments(np.array([bearing])))
            name = "closed_form" if order == 2 else "closed_form_order4"
            curves[f"density/{deg}/{name}"] = (r, _normal(r, mean, sd))
            summary[f"density_{deg}_{name}_mean_error_m"] = mean - mean_k
            summary[f"density_{deg}_{name}_sd_error_m"] = sd - sd_k
    if moments_max > 0.0:
        theta = np.arange(0.0, moments_max + 0.5 * moments_step, moments_step)
        deg = np.round(np.degrees(theta), 9)  # whole degrees stay whole after the round trip
        exact = radial_moments(model, theta, threads=threads)
        rough = PolarBanana(
            v0=model.v0, t=model.t, sigma_a=model.sigma_a, sigma_omega=model.sigma_omega, variant="rough",
            sigma_heading=model.sigma_heading, pose=model.pose,
        )
        sinc_mean = rough.conditional_moments(theta)[0]
        p_mu, p_sigma = closed[2].conditional_moments(theta)
        curves["mean/exact"] = (deg, exact.mean)
        curves["mean/sinc"] = (deg, sinc_mean)
        curves["mean/p_mu"] = (deg, p_mu)
        curves["mean_error/sinc"] = (deg, sinc_mean - exact.mean)
        curves["mean_error/p_mu"] = (deg, p_mu - exact.mean)
        curves["sd/exact"] = (deg, exact.sd)
        curves["sd/p_sigma"] = (deg, p_sigma)
        summary["max_abs_mean_error_sinc_m"] = float(np.max(np.abs(sinc_mean - exact.mean)))
        summary["max_abs_mean_error_p_mu_m"] = float(np.max(np.abs(p_mu - exact.mean)))
        summary["max_abs_sd_error_p_sigma_m"] = float(np.max(np.abs(p_sigma - exact.sd)))
    return {"curves": curves, "summary": summary}


def log_radial_curves(rec: rr.RecordingStream, entity: str, model: MotionModel, **options) -> dict:
    """Compute and log the radial curves of ``model`` under ``entity`` (``radial/LAYER``);
    returns the summary numbers."""
    result = radial_curves(model, **options)
    root = entity_path(entity)
    with strict():
        for path, (abscissa, values) in result["curves"].items():
            widths = np.full(len(abscissa), float(abscissa[1] - abscissa[0]) if len(abscissa) > 1 else 1.0)
            colour = CURVE_COLOURS.get(path.rsplit("/", 1)[1], (200, 200, 200))
            rec.log(
                f"{root}/{path}",
                rr.BarChart(np.asarray(values, dtype=np.float64), abscissa=np.asarray(abscissa, dtype=np.float64), widths=widths, color=colour),
            )
        if result["summary"]:
            rec.log(f"{root}/summary", rr.AnyValues(**result["summary"]))
    return result["summary"]


def radial_groups(density_bearings=(), moments_max=0.0) -> list[str]:
    """The groups of overlaid curves that :func:`log_radial_curves` logs for these options."""
    groups = [f"density/{math.degrees(b):g}deg" for b in density_bearings]
    if moments_max > 0.0:
        groups += ["mean", "mean_error", "sd"]
    return groups


def radial_views(entity: str, groups) -> list:
    """One bar-chart view per group of overlaid curves under ``entity``."""
    root = entity_path(entity)
    return [rrb.BarChartView(origin=f"/{root}/{group}", name=f"{root}/{group}") for group in groups]
