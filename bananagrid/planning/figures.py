"""A planner's picture (matplotlib, the ``plot`` extra): where the effort goes, and what more
effort would buy.

Left, the map: the allocation's coverage (effort per m^2, m^2 swept per m^2) in colour over the
map's probability-mass contours (50, 90 and 99 %, from the cell probabilities), and, for a
:class:`~bananagrid.planning.rectangles.SearchPlan`, its rectangles and their lawnmower tracks.
Right, the POS curve: the optimal probability of success against the total effort (km^2 swept),
the allocation's own point on it, and the rectangles' POS at the effort they fly (below the
curve: what flying rectangles loses).
"""

from __future__ import annotations

import numpy as np

from ..contours import contour_lines, focus_extent, mass_regions
from ..plotting import pyplot
from ..results import Raster
from ..validate import BananagridError
from .allocation import Allocation

#: Probability-mass contours drawn under the coverage.
PLAN_LEVELS = (0.5, 0.9, 0.99)


def plot_allocation(allocation: Allocation, plan=None, *, efforts=None, title: str = "", figure=None):
    """Draw an allocation on a grid map (and a plan of rectangles, if given) beside its POS
    curve; returns the matplotlib figure.

    Parameters
    ----------
    allocation : Allocation
        ``bg.allocate`` on a grid map.
    plan : SearchPlan, optional
        ``bg.search_rectangles(allocation, ...)``: its rectangles and tracks are drawn, and its
        POS marked on the curve.
    efforts : array of float, optional
        Efforts (m^2) of the curve; default 0 to 3 times the allocation's, 61 points.
    title : str
        Above both panels.
    figure : matplotlib Figure, optional
        Drawn into (cleared first); default a new figure.
    """
    if not isinstance(allocation, Allocation) or not isinstance(allocation.effort, Raster):
        raise BananagridError("plot_allocation: expected bg.allocate's result on a grid map")
    plt = pyplot(headless=True)
    fig = figure if figure is not None else plt.figure(figsize=(11.0, 5.0))
    fig.clear()
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.25, 1.0]})
    coverage = allocation.effort
    grid = coverage.grid
    x0, x1, y0, y1 = (v / 1000.0 for v in grid.extent)
    shown = np.where(coverage.values > 0, coverage.values, np.nan)
    image = left.imshow(shown, origin="lower", extent=(x0, x1, y0, y1), cmap="viridis", interpolation="nearest")
    fig.colorbar(image, ax=left, label="coverage (m$^2$ swept per m$^2$)", shrink=0.85)
    density = Raster(values=allocation.cells / grid.cell_area, grid=grid, mass=float(allocation.cells.sum()))
    regions = [r for r in mass_regions(density, PLAN_LEVELS) if r.reached]
    lines = contour_lines(density, [r.density for r in regions])
    for region, style in zip(regions, ("-", "--", ":")):
        for line in lines[region.density]:
            left.plot(line[:, 0] / 1000.0, line[:, 1] / 1000.0, color="black", lw=0.8, ls=style)
        left.plot([], [], color="black", lw=0.8, ls=style, label=f"{region.probability:.0%} of the target")
    if plan is not None:
        for index, r in enumerate(plan.rectangles):
            ring = np.vstack([r.corners, r.corners[:1]]) / 1000.0
            left.plot(ring[:, 0], ring[:, 1], color="red", lw=1.4, label="rectangles" if index == 0 else None)
            left.plot(r.track[:, 0] / 1000.0, r.track[:, 1] / 1000.0, color="orangered", lw=0.6,
                      label="tracks" if index == 0 else None)
    fx0, fx1, fy0, fy1 = (v / 1000.0 for v in focus_extent(density, mass_regions(density, PLAN_LEVELS)))
    left.set_xlim(fx0, fx1)
    left.set_ylim(fy0, fy1)
    left.set_aspect("equal")
    left.set_xlabel("x (km east)")
    left.set_ylabel("y (km north)")
    left.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3, fontsize=7, frameon=False)
    left.set_title(f"effort {allocation.total_effort / 1e6:.3g} km$^2$ ({allocation.law.name}): POS {allocation.pos:.3f}",
                   fontsize=9)
    z = np.linspace(0.0, 3.0 * allocation.total_effort, 61) if efforts is None else np.asarray(efforts, dtype=float)
    right.plot(z / 1e6, allocation.pos_curve(z), color="tab:blue", label="optimal allocation")
    right.plot([allocation.total_effort / 1e6], [allocation.pos], "o", color="tab:blue")
    if plan is not None:
        right.plot([plan.effort / 1e6], [plan.pos], "s", color="red",
                   label=f"{len(plan.rectangles)} rectangles: POS {plan.pos:.3f}")
    right.set_xlabel("effort (km$^2$ swept)")
    right.set_ylabel("probability of success")
    right.set_ylim(0.0, 1.0)
    right.set_xlim(0.0, float(z.max()) / 1e6)
    right.grid(alpha=0.3)
    right.legend(loc="lower right", fontsize=8)
    right.set_title(f"marginal gain {allocation.marginal_gain * 1e6:.3g} per km$^2$ at the plan", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
