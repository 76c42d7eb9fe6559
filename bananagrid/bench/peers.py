"""The polar kernel's peers in ``bananagrid bench``: the same density in Numba and in JAX.

A user who wants the polar-banana density fast on a CPU without bananagrid would write it in
Numba (a compiled loop over the cells) or in JAX (the NumPy expression under ``jax.jit``). The
bench times both against ``rasterise`` on the same grid in the same run, when the ``peers``
extra is installed (``pip install 'bananagrid[peers]'``):

- **Numba**: what a skilled user writes for speed (:func:`skilled_polar_source`): ``numba.njit(
  fastmath=True)`` over rows and columns, branch-free, with inline polynomials for atan2 (one
  division) and exp (2^n from its bits), sin and cos of the bearing as x / r and y / r, one
  reciprocal each for r and the range SD, every constant of the grid's dtype so that float32
  stays float32; not libm per cell.
- **JAX**: :func:`bananagrid.bench.baselines.polar_density` (the NumPy twin, written once for
  both array libraries) traced with ``jax.numpy`` and compiled by ``jax.jit``; float64 with
  ``jax_enable_x64``.

Every implementation's values are checked against ``rasterise`` before any is timed
(:func:`check_equal`). The rows are timed alternately (one run of each in turn, ``repeat``
rounds) on one core: the process is pinned to one CPU while JAX starts, so XLA's thread pool
lives on that core too, and the process CPU time per wall second of each row is reported to show
it (:func:`compare`).
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import os
import sys
import time
from contextlib import contextmanager

import numpy as np
from numpy.polynomial import chebyshev, polynomial

from ..domains.grid import Grid
from ..engine.rasterise import rasterise
from ..validate import BananagridError
from . import baselines

__all__ = ["PEERS_EXTRA", "PEERS", "installed", "NumbaPolar", "JaxPolar", "check_equal", "compare", "one_core"]

#: How a user installs the peers.
PEERS_EXTRA = "pip install 'bananagrid[peers]'"

#: Relative agreement asked of a peer where the density is at least ``AGREE_FLOOR`` of the peak,
#: by dtype. Every implementation rounds differently (fastmath, libm, the lanes' atan2 and exp),
#: and r - mu cancels: its rounding, eps r, over sd, times |z_r| (up to 6.8 at 1e-10 of the peak)
#: is the error of the exponent, r / sd up to ~40 on the bench's Figure 1 grid: expected 3e-13
#: (float64) and 1e-4 (float32); measured at most 1.7e-13 and 9.3e-5 (both variants, NumPy, Numba
#: and JAX). The bounds leave 10x; a wrong formula or parameter is off by far more.
AGREE_RTOL = {np.dtype(np.float64): 5e-12, np.dtype(np.float32): 1e-3}
AGREE_FLOOR = 1e-10


def installed() -> list[str]:
    """Names of the peers whose library is installed (``numba``, ``jax``), in bench order."""
    return [name for name in PEERS if importlib.util.find_spec(name) is not None]


def _model_constants(model, dtype) -> dict:
    """The density's constants for one model, as ``dtype`` scalars (so that float32 stays float32)."""
    sigma_phi = 0.5 * model.sigma_omega * model.t
    c, s = math.cos(model.pose.heading), math.sin(model.pose.heading)
    values = dict(
        ox=model.pose.origin[0], oy=model.pose.origin[1], c=c, s=s,
        a=model.v0 * model.t,  # v0 t: the mean's sinc term (8)
        k=model.sigma_a**2 * model.t**3 / (12 * model.v0),  # (8)'s correction
        half_s=0.5 * model.sigma_a * model.t**2,  # (11)'s scale
        curv=model.sigma_a**2 / (6 * model.v0**2), t_term=model.t**2 / 12, inv_sw2=1 / model.sigma_omega**2,
        inv_sphi=1 / sigma_phi, norm=1 / (2 * math.pi * sigma_phi),
    )
    return {key: dtype.type(value) for key, value in values.items()}


#: Terms of the skilled Numba peer's polynomials, by dtype: atan(a) / a in a^2 for |a| up to
#: tan(pi / 8), and exp on [-ln 2 / 2, ln 2 / 2] (Taylor). The atan fits reach 6.7e-16 (float64)
#: and 1.8e-8 (float32) relative (:func:`atan_coefficients`, measured on 400,001 points); the
#: exp series' first omitted term is 4e-18 and 2e-9 of the result.
ATAN_TERMS = {np.dtype(np.float64): 11, np.dtype(np.float32): 5}
EXP_TERMS = {np.dtype(np.float64): 14, np.dtype(np.float32): 8}
TAN_PI_8 = math.tan(math.pi / 8)


def atan_coefficients(terms: int) -> np.ndarray:
    """Power-basis coefficients c_k of atan(a) ~ a sum_k c_k a^(2k) for |a| <= tan(pi / 8): a
    Chebyshev least-squares fit of atan(sqrt(u)) / sqrt(u) in u = a^2 on 2,000 Chebyshev nodes
    (well conditioned, near-minimax), converted to powers of u."""
    top = TAN_PI_8**2
    u = top * (0.5 + 0.5 * np.cos(np.pi * (np.arange(2000) + 0.5) / 2000))
    fit = chebyshev.Chebyshev.fit(u, np.arctan(np.sqrt(u)) / np.sqrt(u), terms - 1, domain=[0.0, top])
    return fit.convert(kind=polynomial.Polynomial, domain=polynomial.Polynomial.domain,
                       window=polynomial.Polynomial.window).coef


def _horner(variable: str, coefficients, literal) -> str:
    """``c0 + v * (c1 + v * (...))`` with each coefficient a literal of the dtype."""
    text = literal(coefficients[-1])
    for c in coefficients[-2::-1]:
        text = f"({literal(c)} + {variable} * {text})"
    return text


def skilled_polar_source(dtype) -> str:
    """Source of the skilled user's Numba kernel for ``dtype``: branch-free (selects, no
    ``if``), inline polynomials for atan2 and exp (one division for atan2: numerator and
    denominator selected first, min / max of |x| and |y| or, above tan(pi / 8), (min - max) /
    (min + max) with pi / 4 added), sin and cos of the bearing as x / r and y / r (no trigonometric call),
    one reciprocal each for r and the range SD, and 2^n for exp's scaling built from its bits
    (no table: a gather stops the loop from vectorising, measured 3.7x slower)."""
    dtype = np.dtype(dtype)
    name = "float64" if dtype == np.float64 else "float32"

    def literal(value) -> str:
        return f"np.{name}({float(value)!r})"

    atan = _horner("a2", atan_coefficients(ATAN_TERMS[dtype]), literal)
    exp = _horner("f", [1.0 / math.factorial(k) for k in range(EXP_TERMS[dtype])], literal)
    # the exponent's floor: 2^n stays a normal number (its bits built from n)
    lowest, bias, shift, int_type = (-708.0, 1023, 52, "int64") if dtype == np.float64 else (-87.0, 127, 23, "int32")
    return f"""
def skilled_polar(xs, ys, ox, oy, c, s, a, k, half_s, curv, t_term, inv_sw2, inv_sphi, norm, improved, out):
    zero, one, half = np.{name}(0.0), np.{name}(1.0), np.{name}(0.5)
    half_pi, pi = np.{name}({math.pi / 2!r}), np.{name}({math.pi!r})
    quarter_pi, tan_pi_8 = np.{name}({math.pi / 4!r}), np.{name}({TAN_PI_8!r})
    log2e, ln2 = np.{name}({1 / math.log(2)!r}), np.{name}({math.log(2)!r})
    third, four = np.{name}({1 / 3!r}), np.{name}(4.0)
    lowest = np.{name}({lowest!r})
    for i in range(ys.shape[0]):
        dy = ys[i] - oy
        for j in range(xs.shape[0]):
            dx = xs[j] - ox
            x = dx * c - dy * s
            y = dx * s + dy * c
            ax, ay = abs(x), abs(y)
            lo, hi = min(ax, ay), max(ax, ay)
            reduce = lo > tan_pi_8 * hi
            ratio = (lo - hi if reduce else lo) / ((lo + hi if reduce else hi) if hi > zero else one)
            a2 = ratio * ratio
            t = ratio * {atan} + (quarter_pi if reduce else zero)
            t = half_pi - t if ax > ay else t
            t = pi - t if y < zero else t
            phi = -t if x < zero else t
            r = np.sqrt(x * x + y * y)
            inv_r = one / (r if r > zero else one)
            sinc = (x * inv_r) / (phi if phi != zero else one) if phi != zero else one
            scc = (four * sinc - y * inv_r) * third
            z = phi * inv_sphi
            mean = a * sinc + (k * (z * z - one) * scc if improved else zero)
            sd = half_s * (one + curv * (t_term - phi * phi * inv_sw2)) * scc if improved else half_s
            inv_sd = one / (sd if sd > zero else one)
            zr = (r - mean) * inv_sd
            e = max(-half * (z * z + zr * zr), lowest)
            n = np.floor(e * log2e + half)
            f = e - n * ln2
            scale = np.{int_type}((np.{int_type}(n) + {bias}) << {shift}).view(np.{name})  # 2^n
            value = norm * inv_sd * inv_r * {exp} * scale
            out[i, j] = value if (r > zero and sd > zero) else zero
"""


class NumbaPolar:
    """The polar-banana density on a grid by a skilled user's Numba loop, one core
    (:func:`skilled_polar_source`: branch-free, inline polynomials, ``fastmath``).

    Parameters
    ----------
    model : PolarBanana
        Without heading noise (the peers compute (8) and (11) only).
    grid : Grid
    dtype : float32 or float64
    """

    def __init__(self, model, grid: Grid, dtype):
        numba = importlib.import_module("numba")
        self.dtype = np.dtype(dtype)
        self.xs, self.ys = grid.x.astype(self.dtype), grid.y.astype(self.dtype)
        self.constants = _model_constants(model, self.dtype)
        self.improved = model.variant != "rough"
        namespace = {"np": np}
        exec(compile(skilled_polar_source(self.dtype), f"<skilled numba polar {self.dtype.name}>", "exec"), namespace)
        self.kernel = numba.njit(fastmath=True, cache=False, nogil=True, error_model="numpy")(namespace["skilled_polar"])
        self()  # compile now: the first call is not timed

    def __call__(self) -> np.ndarray:
        out = np.empty((len(self.ys), len(self.xs)), dtype=self.dtype)
        k = self.constants
        self.kernel(self.xs, self.ys, k["ox"], k["oy"], k["c"], k["s"], k["a"], k["k"], k["half_s"], k["curv"],
                    k["t_term"], k["inv_sw2"], k["inv_sphi"], k["norm"], self.improved, out)
        return out


class JaxPolar:
    """The polar-banana density on a grid by ``jax.jit`` of the NumPy twin's expression."""

    def __init__(self, model, grid: Grid, dtype):
        jax = importlib.import_module("jax")
        jnp = importlib.import_module("jax.numpy")
        self.dtype = np.dtype(dtype)
        if self.dtype == np.float64:
            jax.config.update("jax_enable_x64", True)
        self.jax = jax
        m = model
        ox, oy = m.pose.origin
        c, s = math.cos(m.pose.heading), math.sin(m.pose.heading)

        def density(xs, ys):
            dx, dy = xs[None, :] - ox, ys[:, None] - oy
            return baselines.polar_density(dx * c - dy * s, dx * s + dy * c, m.v0, m.t, m.sigma_a, m.sigma_omega,
                                           m.variant, xp=jnp)

        self.xs = jax.device_put(grid.x.astype(self.dtype))
        self.ys = jax.device_put(grid.y.astype(self.dtype))
        self.kernel = jax.jit(density)
        self()  # compile now: the first call is not timed

    def __call__(self) -> np.ndarray:
        out = self.kernel(self.xs, self.ys)
        out.block_until_ready()
        return np.asarray(out)


#: Every peer: its library's module name and its implementation.
PEERS = {"numba": NumbaPolar, "jax": JaxPolar}


def check_equal(name: str, values: np.ndarray, reference: np.ndarray) -> float:
    """The largest relative difference of ``values`` from ``reference`` where the reference is at
    least ``AGREE_FLOOR`` of its peak; raise if it exceeds ``AGREE_RTOL`` or if anything is
    non-finite or differs by more than that bound times the peak elsewhere."""
    dtype = reference.dtype
    if values.shape != reference.shape or values.dtype != dtype:
        raise BananagridError(f"peer {name}: {values.dtype}{values.shape}, expected {dtype}{reference.shape}")
    values64, reference64 = values.astype(np.float64), reference.astype(np.float64)
    peak = float(reference64.max())
    inside = reference64 >= AGREE_FLOOR * peak
    rel = float(np.max(np.abs(values64[inside] - reference64[inside]) / reference64[inside]))
    outside = float(np.max(np.abs(values64[~inside] - reference64[~inside]), initial=0.0))
    bound = AGREE_RTOL[dtype]
    if not (np.all(np.isfinite(values64)) and rel <= bound and outside <= bound * peak):
        raise BananagridError(f"peer {name} ({dtype.name}) disagrees with rasterise: relative difference {rel:.3g} "
                              f"inside 1e-10 of the peak, {outside:.3g} (absolute) outside; allowed {bound:g}")
    return rel


@contextmanager
def one_core():
    """Pin this thread (and every thread it starts meanwhile, such as XLA's pool at JAX's first
    use) to one CPU; restore the affinity after. Yields the CPU's number (None where the platform
    has no affinity call: nothing is pinned)."""
    if not hasattr(os, "sched_setaffinity"):  # pragma: no cover - non-Linux
        yield None
        return
    before = os.sched_getaffinity(0)
    cpu = min(before)
    os.sched_setaffinity(0, {cpu})
    try:
        yield cpu
    finally:
        os.sched_setaffinity(0, before)


def compare(model, grid: Grid, dtype, repeat: int, log=print) -> list[dict]:
    """Time ``rasterise`` (one thread), the NumPy twin and every installed peer on ``grid``,
    alternately, ``repeat`` rounds, pinned to one core; each peer checked for equal values first.

    Returns one record per implementation: best, median and worst seconds, the spread
    (worst / best - 1), Mcells/s at the best, the speed of rasterise over this one at the best,
    process CPU seconds per wall second (1 on one core), and for peers the agreement measured.
    """
    dtype = np.dtype(dtype)
    cells = grid.nx * grid.ny
    jax_started_before = "jax" in sys.modules
    with one_core() as cpu:
        reference = rasterise(model, grid, dtype=dtype, threads=1).values
        xx, yy = np.meshgrid(grid.x, grid.y)
        k = _model_constants(model, np.dtype(np.float64))
        dx, dy = xx - k["ox"], yy - k["oy"]
        local = (dx * k["c"] - dy * k["s"], dx * k["s"] + dy * k["c"])  # world to the model's frame
        runs = {
            "bananagrid": lambda: rasterise(model, grid, dtype=dtype, threads=1),
            "numpy": lambda: baselines.polar_density(*local, model.v0, model.t, model.sigma_a, model.sigma_omega,
                                                     model.variant).astype(dtype, copy=False),
        }
        agreement = {}
        for name in installed():
            peer = PEERS[name](model, grid, dtype)
            agreement[name] = check_equal(name, peer(), reference)
            runs[name] = peer
        agreement["numpy"] = check_equal("numpy", runs["numpy"](), reference)
        wall = {name: [] for name in runs}
        cpu_seconds = dict.fromkeys(runs, 0.0)
        for _ in range(repeat):
            for name, run in runs.items():  # alternated: drifts of clock or load hit every row alike
                c0, w0 = time.process_time(), time.perf_counter()
                run()
                wall[name].append(time.perf_counter() - w0)
                cpu_seconds[name] += time.process_time() - c0
    ours = min(wall["bananagrid"])
    records = []
    for name, times in wall.items():
        best = min(times)
        record = {
            "kernel": "", "implementation": name, "dtype": dtype.name, "cells": cells, "cpu": cpu,
            "best_seconds": best, "median_seconds": float(np.median(times)), "worst_seconds": max(times),
            "spread": max(times) / best - 1.0, "mcells_per_s": cells / best / 1e6, "bananagrid_speedup": best / ours,
            "cpu_per_wall": cpu_seconds[name] / sum(times), "max_rel_difference": agreement.get(name),
        }
        if name == "jax" and jax_started_before:
            record["note"] = "JAX was started before the pin: its thread pool may use other cores"
        records.append(record)
    return records


PEER_HEADER = (f"{'kernel':<16} {'dtype':<8} {'implementation':<14} {'best s':>9} {'median s':>9} {'spread':>7} "
               f"{'Mcells/s':>9} {'ours x':>7} {'cpu/wall':>8} {'max rel diff':>12}")


def peer_row(record: dict) -> str:
    """One line of the peers table."""
    diff = "-" if record["max_rel_difference"] is None else f"{record['max_rel_difference']:.1e}"
    return (f"{record['kernel']:<16} {record['dtype']:<8} {record['implementation']:<14} {record['best_seconds']:>9.4f} "
            f"{record['median_seconds']:>9.4f} {100 * record['spread']:>6.1f}% {record['mcells_per_s']:>9.1f} "
            f"{record['bananagrid_speedup']:>7.2f} {record['cpu_per_wall']:>8.2f} {diff:>12}")
