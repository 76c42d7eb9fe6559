"""The polar kernel's peers in ``bananagrid bench``: the same density in Numba and in JAX.

A user who wants the polar-banana density fast on a CPU without bananagrid would write it in
Numba (a compiled loop over the cells) or in JAX (the NumPy expression under ``jax.jit``). The
bench times both against ``rasterise`` on the same grid in the same run, when the ``peers``
extra is installed (``pip install 'bananagrid[peers]'``):

- **Numba**: ``numba.njit(fastmath=True)`` over rows and columns, ``math.atan2``/``exp``/``sin``
  per cell, every constant cast to the grid's dtype so that float32 stays float32.
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


class NumbaPolar:
    """The polar-banana density on a grid by a Numba loop, one core.

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
        self.kernel = numba.njit(fastmath=True, cache=False, nogil=True)(_numba_polar)
        self()  # compile now: the first call is not timed

    def __call__(self) -> np.ndarray:
        out = np.empty((len(self.ys), len(self.xs)), dtype=self.dtype)
        k = self.constants
        zero, one, four, third, half = (self.dtype.type(v) for v in (0.0, 1.0, 4.0, 1.0 / 3.0, 0.5))
        self.kernel(self.xs, self.ys, k["ox"], k["oy"], k["c"], k["s"], k["a"], k["k"], k["half_s"], k["curv"],
                    k["t_term"], k["inv_sw2"], k["inv_sphi"], k["norm"], self.improved, zero, one, four, third, half,
                    out)
        return out


def _numba_polar(xs, ys, ox, oy, c, s, a, k, half_s, curv, t_term, inv_sw2, inv_sphi, norm, improved,
                 zero, one, four, third, half, out):  # pragma: no cover - runs compiled by Numba
    """(8) and (11) at every cell centre: local frame, r, phi, mean, sd, the two normals over r."""
    for i in range(ys.shape[0]):
        dy = ys[i] - oy
        for j in range(xs.shape[0]):
            dx = xs[j] - ox
            x, y = dx * c - dy * s, dx * s + dy * c
            r = math.sqrt(x * x + y * y)
            phi = math.atan2(x, y)
            sinc = math.sin(phi) / phi if phi != zero else one
            mean, sd = a * sinc, half_s
            if improved:
                scc = (four * sinc - math.cos(phi)) * third
                z = phi * inv_sphi
                mean = mean + k * (z * z - one) * scc
                sd = half_s * (one + curv * (t_term - phi * phi * inv_sw2)) * scc
            if r > zero and sd > zero:
                z_phi, z_r = phi * inv_sphi, (r - mean) / sd
                out[i, j] = norm / (sd * r) * math.exp(-half * (z_phi * z_phi + z_r * z_r))
            else:
                out[i, j] = zero


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
