"""What the two motion models of the polar-banana paper share: the CAT parameters (initial
speed, elapsed time, acceleration and turn-rate SDs, heading error, pose), their validation,
their length scales and their scene keys.

:class:`~bananagrid.models.cat.CAT` (the exact density) and
:class:`~bananagrid.models.polar.PolarBanana` (its polar approximations) derive from
:class:`MotionModel`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ..domains.pose import Pose
from ..protocol import SceneKey
from ..validate import BananagridError, non_negative, positive
from .base import RANGE_SDS, Model
from .params import param

__all__ = ["MotionModel", "natural_scales", "MOTION_PARAMS", "motion_param", "pose_arguments", "pose_entries"]


#: Largest heading SD (rad): its square must stay a normal float64 number.
MAX_SIGMA_HEADING = 1e150

def _sinc_slope_max(phi_max: float) -> tuple[float, float]:
    """Largest |sinc'| and |scc'| on [0, phi_max] (scc of eq. (7))."""
    phi = np.linspace(1e-6, phi_max, 512)
    s, c = np.sin(phi), np.cos(phi)
    dsinc = (phi * c - s) / phi**2
    dscc = (4.0 * dsinc + s) / 3.0
    return float(np.max(np.abs(dsinc))), float(np.max(np.abs(dscc)))


def natural_scales(model: MotionModel) -> tuple[float, float]:
    """Range and bearing scales (m, rad) of a CAT banana: heading-table spacings are these over
    their resolutions, and rays sample the range scale.

    The range SD is about sigma_a t^2 / 2 scc(phi) (Section 4.3), smallest at the largest bearing
    that holds mass, phi_max = min(pi, 7 sigma_phi). On a circle the banana is as wide in
    bearing as its range SD over the slope of its ridge, |dr/dphi| <= v0 t max|sinc'| +
    3 sigma_a t^2 / 2 max|scc'| (from (3) with |a| <= 3 sigma_a), and never wider than sigma_phi.
    """
    sigma_phi = 0.5 * model.sigma_omega * model.t
    phi_max = min(math.pi, 7.0 * sigma_phi)
    scc = (4.0 * math.sin(phi_max) / phi_max - math.cos(phi_max)) / 3.0
    radial = 0.5 * model.sigma_a * model.t**2 * scc
    dsinc, dscc = _sinc_slope_max(phi_max)
    slope = model.v0 * model.t * dsinc + 1.5 * model.sigma_a * model.t**2 * dscc
    angular = min(sigma_phi, radial / slope) if slope > 0.0 else sigma_phi
    return radial, angular


class MotionModel(Model):
    """A target that left ``pose`` at speed ``v0`` and moved for ``t`` seconds with a normal
    acceleration (SD ``sigma_a``) and turn rate (SD ``sigma_omega``), its initial heading known
    to ``sigma_heading``. Subclasses are frozen dataclasses with these fields."""

    v0: float
    t: float
    sigma_a: float
    sigma_omega: float
    sigma_heading: float
    pose: Pose

    def _validate_motion(self) -> None:
        """What the declared checks (v0, t, sigma_a, sigma_omega > 0, sigma_heading >= 0,
        :data:`MOTION_PARAMS`) leave to every motion model: sigma_heading's upper bound, a Pose,
        and scales that stay normal float64 numbers."""
        if not self.sigma_heading <= MAX_SIGMA_HEADING:  # its square enters the heading law (12)
            raise BananagridError(
                f"sigma_heading = {self.sigma_heading!r}: must be at most {MAX_SIGMA_HEADING:g} rad "
                "(an SD of many turns is a uniform heading already)"
            )
        if not isinstance(self.pose, Pose):
            raise BananagridError(f"pose = {self.pose!r}: expected a bananagrid.Pose")
        self._check_scales()

    def _check_scales(self) -> None:
        """The derived scales the models compute with (the reach v0 t, the range SD sigma_a t^2,
        the turn sigma_omega t, (v0 / sigma_a)^2 of P_sigma (11), and their products) must be
        normal float64 numbers: values near 1e308 or 1e-308 would overflow or vanish in them.
        The squares the kernels' coefficients take (sigma_omega^2, (sigma_omega t)^2,
        sigma_a^2 t^3 / v0, and with heading noise (sigma_heading sigma_omega t)^2) must stay
        within [1e-300, 1e300]. Checked in log10, where nothing overflows."""
        v0, t, sa, sw, sh = self.v0, self.t, self.sigma_a, self.sigma_omega, self.sigma_heading
        lv, lt, la, lw = (math.log10(x) for x in (v0, t, sa, sw))
        derived = {  # log10 of each, and whether it must keep its square normal (1e-150..1e300)
            "v0 t": lv + lt, "sigma_a t^2": la + 2 * lt, "sigma_omega t": lw + lt, "t^2": 2 * lt,
            "(v0 / sigma_a)^2": 2 * (lv - la), "(v0 t)^2": 2 * (lv + lt),
        }
        squares = {
            "sigma_omega^2": 2 * lw, "(sigma_omega t)^2": 2 * (lw + lt), "sigma_a^2 t^3 / v0": 2 * la + 3 * lt - lv,
        }
        if sh > 0.0:
            squares["(sigma_heading sigma_omega t)^2"] = 2 * (math.log10(sh) + lw + lt)
        bad = [name for name, e in derived.items() if not -150.0 <= e <= 300.0]
        bad += [name for name, e in squares.items() if not -300.0 <= e <= 300.0 and not (
            name.startswith("(sigma_heading") and e < -300.0)]  # a vanishing heading term is no heading noise
        if bad:
            given = {"v0": v0, "t": t, "sigma_a": sa, "sigma_omega": sw}
            if any(name.startswith("(sigma_heading") for name in bad):
                given["sigma_heading"] = sh
            worst = max(given, key=lambda name: abs(math.log10(given[name])))  # the extreme one
            others = ", ".join(f"{name} = {value!r}" for name, value in given.items() if name != worst)
            raise BananagridError(
                f"{worst} = {given[worst]!r}: with {others}, {', '.join(bad)} overflow or vanish in "
                "float64; use units that keep them between 1e-150 and 1e300"
            )

    def polar_scales(self, origin=(0.0, 0.0)) -> tuple[float, float]:
        """Smallest widths of the banana's features about its own pose: ``(radial_m, angular_rad)``.

        The radial scale is half the range SD at phi = 0, ``sigma_a t^2 / 4``: the SD of r given
        phi is sigma_a t^2 / 2 scc(phi) (11), and half of sigma_a t^2 / 2 keeps scc >= 1/2
        (|phi| <= 2.4 rad) covered. The angular scale is ``min(sigma_omega t / 2, radial /
        (v0 t))``: the bearing SD, or the turn that moves the ridge r = P_mu(phi) by the radial
        scale (it moves by at most v0 t per radian, |d sinc / d phi| < 0.44). Heading noise only
        smooths and is ignored; so is ``origin`` (the scales are the banana's own).
        """
        radial = 0.25 * self.sigma_a * self.t**2
        angular = min(0.5 * self.sigma_omega * self.t, radial / (self.v0 * self.t))
        return radial, angular

    def feature_scale(self) -> float:
        """The radial scale, or the angular scale at the range where the mass lies (v0 t)."""
        radial, angular = self.polar_scales()
        return min(radial, angular * self.v0 * self.t)

    def radial_extent(self, pose: Pose) -> tuple[float, float]:
        """Range scale :func:`natural_scales` and the bound v0 t + 12 range SDs (sigma_a t^2 / 2),
        plus the distance from ``pose``'s origin to the model's."""
        sd = 0.5 * self.sigma_a * self.t**2
        bound = self.v0 * self.t + RANGE_SDS * sd
        if pose.origin != self.pose.origin:
            bound += math.dist(pose.origin, self.pose.origin)
        return natural_scales(self)[0], bound


def pose_arguments(params: Mapping) -> dict:
    """Keyword arguments of a motion model from scene parameters in SI units: ``origin`` and
    ``heading`` become its :class:`~bananagrid.Pose`."""
    kwargs = dict(params)
    pose = Pose(origin=kwargs.pop("origin", (0.0, 0.0)), heading=kwargs.pop("heading", 0.0))
    return {**kwargs, "pose": pose}


def pose_entries(model, pose: Pose) -> dict:
    """A pose's entries in ``parameters()``: ``origin_x``, ``origin_y`` and ``heading``."""
    return {"origin_x": pose.origin[0], "origin_y": pose.origin[1], "heading": pose.heading}


#: The parameters both motion models share, declared once (:func:`motion_param`).
MOTION_PARAMS = {
    "v0": dict(doc="Initial speed.", unit="m/s", check=positive),
    "t": dict(doc="Elapsed time.", unit="s", default_doc="required, unless `scene.times`", check=positive,
              domain="finite, > 0; refused with `scene.times`"),
    "sigma_a": dict(doc="Standard deviation of the acceleration.", unit="m/s^2", check=positive),
    "sigma_omega": dict(doc="Standard deviation of the turn rate.", unit="rad/s", check=positive, alias="deg"),
    "sigma_heading": dict(default=0.0, unit="rad", alias="deg", check=non_negative,
                          doc="Standard deviation sigma_0 of a normal error on the initial heading (Section 7 of "
                              "the polar-banana paper); 0 for none.",
                          domain="in [0, 1e150]: SD of a normal error on the initial heading (Section 7)"),
    "pose": dict(
        default_factory=Pose, py="Pose", default_doc="origin (0, 0), heading north", plain=pose_entries,
        doc="Places the local frame (origin at the last fix, +y along the initial heading) in the world.",
        domain="a bananagrid.Pose",
        scene=(
            SceneKey("origin", type="pair", unit="m", default="`[0, 0]`", allowed="finite: the last fix"),
            SceneKey("heading", unit="rad", default="`0` (north)", alias="deg", bearing_at="origin",
                     allowed="finite; the initial heading, a bearing clockwise from north (true north in a "
                             "geographic scene)"),
        ),
    ),
}


def motion_param(name: str, **changes):
    """The declared field (:func:`~bananagrid.models.params.param`) of motion parameter ``name``
    (a key of :data:`MOTION_PARAMS`), with ``changes`` (a model's own ``doc``)."""
    return param(**{**MOTION_PARAMS[name], **changes})
