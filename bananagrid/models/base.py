"""What most models share: ``pdf`` through the engine, plain-data parameters, rays through
``pdf``, and the checks of ``sample``'s arguments.

A model class derives from :class:`Model` and implements the rest of
:class:`bananagrid.protocol.DensityModel`: ``kind``, ``scene``, ``float32_rtol``, ``bind``,
``sample``, ``polar_scales``, ``feature_scale`` and ``radial_extent``.
"""

from __future__ import annotations

import math

import numpy as np

from ..domains.angular_lattice import AngularLattice
from ..domains.pose import Pose
from ..engine import memory
from ..engine.points import evaluate_points
from ..protocol import CellPlan
from ..validate import BananagridError
from .params import plain_parameters

__all__ = ["Model", "check_n", "check_rng", "RANGE_SDS", "ZERO_BELOW", "PEAK_PROBES", "SAMPLE_BYTES"]

#: Rays scan a model out to this many of its widest SDs beyond where its mass lies (the density
#: there is below e^-72 of its peak along the ray).
RANGE_SDS = 12.0

#: Tiled rasterising may leave a tile at 0 where the model proves its density at most this
#: fraction of the density's maximum (10x below the 1e-12 under which no kernel promises
#: relative accuracy; Butterly's grid kernel zeroes single cells at the same level).
ZERO_BELOW = 1e-13

#: Samples of the model's own story at which :meth:`Model.peak_lower_bound` evaluates the density.
PEAK_PROBES = 1024


def check_rng(rng) -> np.random.Generator:
    """``rng`` as a NumPy Generator (an integer seeds a new one)."""
    if rng is None:
        raise BananagridError("rng: pass a numpy.random.Generator (e.g. numpy.random.default_rng(seed))")
    if isinstance(rng, (int, np.integer)):
        return np.random.default_rng(int(rng))
    if not isinstance(rng, np.random.Generator):
        raise BananagridError(f"rng = {rng!r}: expected a numpy.random.Generator or an integer seed")
    return rng


#: Peak bytes per sample of a model's ``sample`` when its class does not say (``sample_bytes``):
#: the largest measured, BearingFix's 448 (three bearings; tracemalloc's peak over
#: ``sample(10**6)``, which counts NumPy's arrays), rounded up.
SAMPLE_BYTES = 512


def check_n(n, sample_bytes: float = SAMPLE_BYTES) -> int:
    """``n`` as a non-negative int whose ``n * sample_bytes`` fit in the memory available.

    Raises
    ------
    BananagridError
        Not a count, or samples that would not fit: one line with the bytes they would take
        (an allocation that cannot be had is a MemoryError deep inside NumPy, or swapping).
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise BananagridError(f"n = {n!r}: expected a non-negative integer")
    n = int(n)
    need = float(n) * sample_bytes
    available = memory.available_bytes()
    if available is not None and need > available:
        raise BananagridError(
            f"n = {n:,}: sample(n) would take about {memory.format_bytes(need)} ({sample_bytes:g} bytes a sample), "
            f"more than the {memory.format_bytes(available)} available: draw fewer samples at a time"
        )
    return n


class Model:
    """Shared parts of the model protocol (:class:`bananagrid.protocol.DensityModel`)."""

    #: The model's local frame; None for models without one (motion models have a ``pose`` field).
    pose: Pose | None = None

    #: A probability density (see :attr:`bananagrid.protocol.DensityModel.integrates_to_one`).
    integrates_to_one: bool = True

    #: Peak bytes per sample of :meth:`sample` (measured; :func:`check_n` refuses what would not fit).
    sample_bytes: float = SAMPLE_BYTES

    #: Seconds of one CPU core per cell assumed by the default :meth:`work_estimate`, for a model
    #: that gives none of its own (every bundled model does): above what the closed-form kernels
    #: take (polar and bearing 2-90 ns a cell, ``bananagrid bench``).
    seconds_per_cell: float = 1e-6

    def work_estimate(self, cells: int, extent) -> float:
        """``cells * seconds_per_cell`` (:meth:`bananagrid.protocol.DensityModel.work_estimate`)."""
        return float(cells) * self.seconds_per_cell

    def cell_plan(self, domain, region=None) -> CellPlan | None:
        """None: the engine integrates the density over each cell of a grid or polar lattice
        (:meth:`bananagrid.protocol.DensityModel.cell_plan`); an angular lattice's directions
        hold no cells of a density in the world plane."""
        if isinstance(domain, AngularLattice):
            raise BananagridError(
                f"{type(self).__name__}: a density in the world plane has no cells of an array's directions; "
                "an AngularLattice takes a presence law (GaussianMixture, UniformPresence)"
            )
        return None

    def density_bound(self, x0: float, x1: float, y0: float, y1: float) -> float:
        """No bound proved: ``math.inf`` (:meth:`bananagrid.protocol.DensityModel.density_bound`);
        tiled rasterising then computes every tile."""
        return math.inf

    def density_floor(self) -> float:
        """ZERO_BELOW times :meth:`peak_lower_bound`
        (:meth:`bananagrid.protocol.DensityModel.density_floor`)."""
        return ZERO_BELOW * self.peak_lower_bound()

    def peak_lower_bound(self) -> float:
        """The largest density the kernels compute at PEAK_PROBES positions drawn from the model's
        own story (a fixed seed) and at its last fix: any computed value is at most the maximum
        (to rounding). Computed once per model."""
        cached = self.__dict__.get("_peak_lower_bound")
        if cached is not None:
            return cached
        points = [self.sample(PEAK_PROBES, np.random.default_rng(20261125))]
        points += [np.asarray(v, dtype=float).reshape(-1, 2) for k, v in self.landmarks().items() if k == "fix"]
        points = np.concatenate(points)
        peak = float(np.max(self.pdf(points[:, 0], points[:, 1]), initial=0.0))
        if not peak > 0.0:  # every probe underflowed: no floor
            peak = float(np.finfo(float).smallest_subnormal)
        self.__dict__["_peak_lower_bound"] = peak  # a frozen dataclass: its __dict__ caches
        return peak

    def bind_once(self, ctx, make, *key):
        """``make()``, a :class:`~bananagrid.protocol.KernelBinding` that depends on the model, the
        context's dtype and device and ``key`` only (never on the extent), made once and kept for
        later calls: a frozen model's parameter struct and arrays are the same every call, and
        making them cost 20-140 us, as much as a small grid's kernel. Kept in the instance (not
        pickled: a copy in another process makes its own)."""
        bindings = self.__dict__.setdefault("_bindings", {})
        index = (np.dtype(ctx.dtype), str(ctx.device), *key)
        binding = bindings.get(index)
        if binding is None:  # two threads may both make it: the same binding, the last one kept
            binding = bindings[index] = make()
        return binding

    def __getstate__(self):
        """The instance's state without the kept bindings (Warp structs and arrays do not
        pickle, and belong to this process's devices)."""
        state = dict(self.__dict__)
        state.pop("_bindings", None)
        return state

    def singular_points(self) -> np.ndarray:
        """No point of infinite density (:meth:`bananagrid.protocol.DensityModel.singular_points`)."""
        return np.zeros((0, 2))

    def seams(self) -> np.ndarray:
        """No ray of kinks (:meth:`bananagrid.protocol.DensityModel.seams`)."""
        return np.zeros((0, 3))

    def polar_law(self, origin):
        """None: no closed radial law (:meth:`bananagrid.protocol.DensityModel.polar_law`)."""
        return None

    def landmarks(self) -> dict[str, np.ndarray]:
        """The last fix, the origin of the model's pose; nothing for a model without a pose
        (:meth:`bananagrid.protocol.DensityModel.landmarks`)."""
        if self.pose is None:
            return {}
        return {"fix": np.reshape(np.asarray(self.pose.origin, dtype=np.float64), (1, 2))}

    def parameters(self) -> dict:
        """Plain-data parameters for provenance and recordings: the class name, then every
        field's entries (a declared parameter's own, :func:`bananagrid.models.params.param`'s
        ``plain``; else its name and value).

        A model is frozen, so entries that are all plain scalars are made once, kept in the
        instance and copied for each caller (making them cost 2-6 us of a small grid's call);
        any others (lists) are made afresh each time, so no caller shares them."""
        kept = self.__dict__.get("_parameters")
        if kept is None:
            kept = plain_parameters(self)
            if not all(isinstance(v, (str, int, float, type(None))) for v in kept.values()):
                return kept
            self.__dict__["_parameters"] = kept
        return dict(kept)

    def pdf(self, x, y, *, dtype=np.float64, device="cpu"):
        """Density per m^2 at world points (broadcast x, y), through the same kernels as rasterise."""
        return evaluate_points(self, x, y, dtype=dtype, device=device)

    def ray_values(self, pose: Pose, radii: np.ndarray, angles: np.ndarray, *, threads=None) -> np.ndarray:
        """p(r, theta) at ranges x bearings from ``pose``, shape (len(radii), len(angles)),
        through the points kernel."""
        local_x = radii[:, None] * np.sin(angles)[None, :]
        local_y = radii[:, None] * np.cos(angles)[None, :]
        world = pose.to_world(np.column_stack((local_x.ravel(), local_y.ravel())))
        values = evaluate_points(self, world[:, 0], world[:, 1], threads=threads)
        return values.reshape(local_x.shape)
