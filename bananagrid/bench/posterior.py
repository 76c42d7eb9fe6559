"""``bananagrid bench``'s posterior rows: a map after two searches that found nothing, against
the prior's own map on the same grid, timed in the same run.

``cat-posterior``: the Figure 1 CAT (t = 10 s) on the Figure 1 frame at ``--step`` (4 m: 1500 x
900 cells); ``butterly-posterior``: the submarine scene's Butterly (``scenes/submarine.toml``:
a start of 2 km x 0.5 km at rho = 0.5, 5, 10 or 15 kn) 4 h after its fix on the scene's grid
(+-230 km at 400 m: 1150 x 1150 cells). Each takes two area searches that found nothing at
EARLIER times (``--evidence earlier``, the default: the CAT searched at 4 s and 7 s, the
submarine at 1 h and 2 h, each box over part of where the target was then), carried to the
map's time through the model's paths, or the same two boxes stretched to the map's time and
searched then (``--evidence same``: the update of the map at its own time).

Each row times ``bg.posterior`` (float64, its cell probabilities) against the prior's cell
probabilities (``rasterise(..., quantity="probability")``, the map the posterior weighs: the
ratio held to the targets, :data:`TARGETS`) and its densities at the cell centres, on one
thread and on ``--threads``, best of ``--repeat`` each, alternated.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from ..domains.grid import Grid
from ..engine.rasterise import rasterise
from ..evidence.posterior import posterior
from ..evidence.searches import AreaSearch
from ..models.registry import MODEL_KINDS
from ..validate import BananagridWarning

__all__ = ["ROWS", "TARGETS", "EVIDENCE", "posterior_case", "posterior_rows", "check_rows", "KNOT"]

#: One knot, m/s.
KNOT = 1852.0 / 3600.0

#: When the two searches were made: before the map's time, or at it.
EVIDENCE = ("earlier", "same")

#: Most the posterior may cost, as a multiple of the prior's cell probabilities on the same grid.
TARGETS = {"cat-posterior": 2.0, "butterly-posterior": 3.0}

#: The rows: registry kind, scene parameters (SI), the grid's bounds (None: the Figure 1 frame at
#: ``--step``) and step, and the two searches as (time s, box (x0, x1, y0, y1) m, keyword: value).
ROWS = {
    "cat-posterior": dict(
        kind="cat", params=dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.pi / 54.0),
        bounds=None,
        # at 4 s the target is about 1120 m out, +-130 m across (1 sigma): the western half of it;
        # at 7 s about 1960 m out, +-400 m across: the eastern part
        searches=((4.0, (-400.0, 0.0, 1000.0, 1250.0), dict(pod=0.7)),
                  (7.0, (0.0, 800.0, 1800.0, 2100.0), dict(coverage=1.2))),
    ),
    "butterly-posterior": dict(
        kind="butterly",
        params=dict(mean=(0.0, 0.0), sigma_x=2000.0, sigma_y=500.0, rho=0.5,
                    speeds=[5.0 * KNOT, 10.0 * KNOT, 15.0 * KNOT], weights=[0.2, 0.5, 0.3], t=4 * 3600.0),
        bounds=dict(x=(-230000.0, 230000.0), y=(-230000.0, 230000.0), step=400.0),
        # after 1 h the rings are 9.3, 18.5 and 27.8 km about the fix: a barrier east of it; after
        # 2 h 18.5, 37 and 56 km: a box north of it
        searches=((3600.0, (5000.0, 35000.0, -30000.0, 30000.0), dict(pod=0.5)),
                  (7200.0, (-40000.0, 40000.0, 10000.0, 60000.0), dict(coverage=0.8))),
    ),
}


def _box(x0, x1, y0, y1, scale=1.0):
    return [(scale * x0, scale * y0), (scale * x1, scale * y0), (scale * x1, scale * y1), (scale * x0, scale * y1)]


def posterior_case(name: str, step: float = 4.0, evidence: str = "earlier"):
    """``(prior, grid, searches)`` of row ``name``: the searches at their own (earlier) times, or
    (``evidence="same"``) each box stretched about the last fix by t / t_search and searched at
    the map's time t (where the paths through it have gone, to first order)."""
    row = ROWS[name]
    prior = MODEL_KINDS[row["kind"]].build(row["params"])
    bounds = row["bounds"] or dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=step)
    grid = Grid.from_bounds(**bounds)
    t = float(prior.t)
    searches = []
    for t_search, box, law in row["searches"]:
        scale = 1.0 if evidence == "earlier" else t / t_search
        searches.append(AreaSearch(_box(*box, scale=scale), t=t_search if evidence == "earlier" else t, **law))
    return prior, grid, searches


def check_rows(names, step: float, evidence: str) -> None:
    """Raise the ``BananagridError`` a row would raise (its evidence refused by this build's
    ``posterior``, say), from the same prior and searches on 2 x 2 cells of 1 m about a point the
    prior draws (a cell with prior mass, at the cost of a few points): before minutes of
    timing, not after."""
    for name in names:
        prior, _, searches = posterior_case(name, step, evidence)
        (x, y), = prior.sample(1, np.random.default_rng(0))
        with warnings.catch_warnings():  # such a grid misses most of the target, and says so
            warnings.simplefilter("ignore", BananagridWarning)
            posterior(prior, Grid(origin=(x - 1.0, y - 1.0), dx=1.0, dy=1.0, nx=2, ny=2), searches, threads=1)


def _alternated(repeat: int, fns: dict) -> dict:
    """Best of ``repeat`` wall-clock seconds of each of ``fns``, run in turn (the same machine's
    load for each)."""
    best = dict.fromkeys(fns, math.inf)
    for _ in range(repeat):
        for key, fn in fns.items():
            start = time.perf_counter()
            fn()
            best[key] = min(best[key], time.perf_counter() - start)
    return best


def posterior_rows(names, step: float, threads: int, repeat: int, evidence: str = "earlier", log=print) -> list[dict]:
    """Time each posterior row ``names`` on 1 and ``threads`` threads; log and return records
    with ``seconds`` (the posterior), ``prior_seconds`` (the prior's cell probabilities),
    ``density_seconds`` (its densities), their ratios, the target, POS and each search's POS."""
    records = []
    for name in names:
        prior, grid, searches = posterior_case(name, step, evidence)
        times = ", ".join(f"{s.time_span[0]:g}" for s in searches)
        log(f"{name}: {type(prior).__name__} on {grid.nx} x {grid.ny} cells, map at t = {prior.t:g} s, two area "
            f"searches at t = {times} s ({evidence} evidence), float64")
        check_rows([name], step, evidence)  # warm-up: every kernel loaded (and errors raised) on a few cells
        found = {}
        for n in sorted({1, threads}):
            best = _alternated(repeat, {
                "posterior": lambda: found.update(result=posterior(prior, grid, searches, threads=n)),
                "prior": lambda: rasterise(prior, grid, quantity="probability", threads=n),
                "density": lambda: rasterise(prior, grid, threads=n),
            })
            record = {
                "kernel": name, "dtype": "float64", "threads": n, "cells": grid.nx * grid.ny, "evidence": evidence,
                "search_times": [s.time_span[0] for s in searches], "t": float(prior.t),
                "seconds": best["posterior"], "prior_seconds": best["prior"], "density_seconds": best["density"],
                "ratio_to_prior": best["posterior"] / best["prior"],
                "ratio_to_density": best["posterior"] / best["density"], "target": TARGETS[name],
                "pos": found["result"].pos, "search_pos": list(found["result"].search_pos),
            }
            records.append(record)
            log(posterior_line(record))
    return records


def posterior_line(r: dict) -> str:
    """One row as printed."""
    verdict = "within" if r["ratio_to_prior"] <= r["target"] else "OVER"
    return (f"  {r['threads']} thr: posterior {r['seconds']:.3f} s, prior cell probabilities {r['prior_seconds']:.3f} s "
            f"-> {r['ratio_to_prior']:.2f}x ({verdict} the {r['target']:g}x target); prior densities "
            f"{r['density_seconds']:.3f} s ({r['ratio_to_density']:.1f}x); POS {r['pos']:.4f} "
            f"(each search {', '.join(f'{p:.4f}' for p in r['search_pos'])})")
