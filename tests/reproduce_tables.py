"""Reproduce Tables 1 and 2 and the Section 6.1 goodness figure of Langholm & Totland with the
independent float64 oracle in tests/support/oracles.py, check grid convergence, and sanity-check the
oracle by Monte Carlo.

    python tests/reproduce_tables.py            # everything (several minutes on 2 cores)
    python tests/reproduce_tables.py --quick    # no 2 m grid, smaller Monte Carlo

Grid: x in [-3000, 3000] m, y in [-200, 3400] m, 4 m cells, centres -2998, -2994, ...
(1500 x 900 cells).  The exact grid is saved to /tmp/cat_fig1_oracle_4m.npy with shape
(900, 1500) = (ny, nx): row i is y = -198 + 4 i, column j is x = -2998 + 4 j.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np
from scipy.stats import chi2 as chi2_dist

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "support"))
import oracles  # noqa: E402

V0, T, SA, SW = 280.0, 10.0, 5.0 / 3.0, math.pi / 54.0
LEVELS = [1e-6, 1e-7, 1e-8, 1e-9, 1e-10]
PAPER = {
    "mass": [0.58, 0.96, 0.996, 0.9996, 0.99997],
    "rough": [0.014, 0.08, 0.26, 0.57, 1.08],
    "improved": [0.0006, 0.0022, 0.0064, 0.026, 0.066],
    "goodness": 0.99992,
}
X0, X1, Y0, Y1 = -3000.0, 3000.0, -200.0, 3400.0


def centres(lo, hi, h):
    n = int(round((hi - lo) / h))
    return lo + h * (np.arange(n) + 0.5)


def grids(h, params=(V0, T, SA, SW), window=(X0, X1, Y0, Y1), **kw):
    x = centres(window[0], window[1], h)
    y = centres(window[2], window[3], h)
    X, Y = np.meshgrid(x, y)  # (ny, nx)
    t0 = time.time()
    ex = oracles.cat_density(X, Y, *params, **kw)
    t_ex = time.time() - t0
    ro = oracles.polar_density(X, Y, *params, "rough")
    im = oracles.polar_density(X, Y, *params, "improved")
    return x, y, ex, ro, im, t_ex


def report(ex, ro, im, h, label):
    area = h * h
    total = ex.sum() * area
    print(f"\n[{label}] grid mass sum(exact)*cell_area = {total:.10f}  (1 - {1 - total:.2e})")
    out = {}
    for name, ap in (("rough", ro), ("improved", im)):
        rows = oracles.table_stats(ex, ap, area, LEVELS)
        rows_u = oracles.table_stats(ex, ap, area, LEVELS, normalise=False)
        print(f"  {'level':>7s} {'mass(norm)':>13s} {'mass(raw)':>13s} {'paper':>8s} "
              f"{'max err ' + name:>18s} {'paper':>7s} {'cells':>8s}")
        for r, ru, pm, pe in zip(rows, rows_u, PAPER["mass"], PAPER[name]):
            print(f"  {r['level']:7.0e} {100 * r['mass']:12.5f}% {100 * ru['mass']:12.5f}% "
                  f"{100 * pm:7.3f}% {100 * r['max_rel_err']:17.4f}% {100 * pe:6.2f}% {r['ncells']:8d}")
        out[name] = rows
    g = oracles.goodness(ex, im, area, 0.05)
    gu = oracles.goodness(ex, im, area, 0.05, normalise=False)
    gr = oracles.goodness(ex, ro, area, 0.05)
    # footnote 3: whole region (any shape) where the error stays within 5 %
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(im / ex - 1)
    whole = ex[err <= 0.05].sum() / ex.sum()
    print(f"  goodness(improved, 5%) = {g:.7f} (raw {gu:.7f}; paper {PAPER['goodness']})"
          f"   goodness(rough, 5%) = {gr:.6f}   mass of all cells with err<=5% = {whole:.7f}"
          f" (footnote 3: 0.99999)")
    out["goodness"] = g
    return out


def monte_carlo(n, params, window, bin_m, h_oracle, seed, label, ex=None):
    v0, t, sa, sw = params
    rng = np.random.default_rng(seed)
    xe = np.arange(window[0], window[1] + 0.5 * bin_m, bin_m)
    ye = np.arange(window[2], window[3] + 0.5 * bin_m, bin_m)
    H = np.zeros((ye.size - 1, xe.size - 1))
    inside = 0
    for i in range(0, n, 2_000_000):
        m = min(2_000_000, n - i)
        a = rng.normal(0.0, sa, m)
        w = rng.normal(0.0, sw, m)
        x, y = oracles.cat_position(a, w, v0, t)  # literal eq. (1)
        hh, _, _ = np.histogram2d(y, x, bins=(ye, xe))
        H += hh
        inside += hh.sum()
    t0 = time.time()
    if ex is None:
        xc = centres(window[0], window[1], h_oracle)
        yc = centres(window[2], window[3], h_oracle)
        X, Y = np.meshgrid(xc, yc)
        ex = oracles.cat_density(X, Y, *params)
    r = int(round(bin_m / h_oracle))
    E = ex.reshape(ex.shape[0] // r, r, ex.shape[1] // r, r).sum(axis=(1, 3)) * h_oracle**2 * n
    use = E >= 20
    chi2 = np.sum((H[use] - E[use]) ** 2 / E[use])
    dof = int(use.sum())
    z = (H[use] - E[use]) / np.sqrt(E[use])
    print(f"\n[MC {label}] N = {n:.1e}, {bin_m:.0f} m bins, oracle on {h_oracle:g} m cells "
          f"({time.time() - t0:.1f} s)")
    print(f"  fraction in window: MC {inside / n:.6f}  oracle {E.sum() / n:.6f}")
    print(f"  bins with E>=20: {dof}, chi2 = {chi2:.1f}, chi2/dof = {chi2 / dof:.3f}, "
          f"p = {chi2_dist.sf(chi2, dof):.3f}, max|z| = {np.max(np.abs(z)):.2f}; "
          f"counts in E<20 bins: MC {H[~use].sum():.0f} vs oracle {E[~use].sum():.1f}")
    return chi2 / dof


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="skip the 2 m grid, smaller MC")
    args = ap.parse_args()
    t_all = time.time()
    print("self-check of oracle building blocks:")
    oracles.self_check()

    x4, y4, ex4, ro4, im4, t4 = grids(4.0)
    np.save("/tmp/cat_fig1_oracle_4m.npy", ex4)
    print(f"\nexact CAT oracle on the 4 m grid {ex4.shape[::-1]} (nx x ny): {t4:.1f} s; "
          "saved /tmp/cat_fig1_oracle_4m.npy (shape (ny, nx))")
    r4 = report(ex4, ro4, im4, 4.0, "4 m grid")

    # oracle-parameter sensitivity (finer scan, larger truncation) on a sub-window
    win = (-1200.0, 1200.0, 1800.0, 3000.0)
    xs = centres(win[0], win[1], 4.0)
    ys = centres(win[2], win[3], 4.0)
    X, Y = np.meshgrid(xs, ys)
    a = oracles.cat_density(X, Y, V0, T, SA, SW)
    b = oracles.cat_density(X, Y, V0, T, SA, SW, k=10.0, scan_step=0.0025)
    print(f"\noracle sensitivity (k 8->10, scan 0.01->0.0025) on {win}: "
          f"max rel diff {np.max(np.abs(b / a - 1)):.2e}")

    if not args.quick:
        x2, y2, ex2, ro2, im2, t2 = grids(2.0)
        print(f"\nexact CAT oracle on the 2 m grid {ex2.shape[::-1]}: {t2:.1f} s")
        r2 = report(ex2, ro2, im2, 2.0, "2 m grid")
        print("\nconvergence 4 m -> 2 m:")
        for name in ("rough", "improved"):
            for p, q in zip(r4[name], r2[name]):
                print(f"  {name:8s} L={p['level']:.0e}: mass {100 * p['mass']:.5f}% -> "
                      f"{100 * q['mass']:.5f}%   max err {100 * p['max_rel_err']:.4f}% -> "
                      f"{100 * q['max_rel_err']:.4f}%")
        print(f"  goodness {r4['goodness']:.7f} -> {r2['goodness']:.7f}")
        del ex2, ro2, im2

    n_mc = 4_000_000 if args.quick else 20_000_000
    monte_carlo(n_mc, (V0, T, SA, SW), (X0, X1, Y0, Y1), 100.0, 4.0, 12345,
                "Figure 1 setting", ex=ex4)
    # folded banana: sigma_w t = 120 deg, several roots per point
    monte_carlo(n_mc, (V0, T, SA, 2 * math.pi / 3 / T), (-3200.0, 3200.0, -3200.0, 3400.0),
                100.0, 10.0, 54321, "folded, sigma_w t = 120 deg")
    print(f"\ntotal runtime {time.time() - t_all:.0f} s")


if __name__ == "__main__":
    main()
