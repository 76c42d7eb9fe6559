"""Evidence on the map: searches that found nothing, bearings, position reports and land, as
likelihood factors of the target's position, and the posterior map they give.

Modules: :mod:`~bananagrid.evidence.geometry` (polygons against cells, tracks against points),
:mod:`~bananagrid.evidence.searches` (``AreaSearch``, ``TrackSearch`` and the lateral-range
laws), :mod:`~bananagrid.evidence.reports` (``PositionReport``, ``BearingReport``,
``Exclusion``), :mod:`~bananagrid.evidence.posterior` (``posterior`` at the map's own time).

Carrying earlier evidence forward (the plan for the kernels; not built yet)
---------------------------------------------------------------------------
Evidence at t1 < t is a weight on the parameters that fix a path, evaluated where that path
is at t1; the map at t is then the kernels' own integral with that weight inside it:

* CAT: a root (a, omega) of the map at t fixes the whole path x(s; a, omega), s in [0, t]
  (the motion model's closed form, origin and pose as now). Its weight is
  w(a, omega) = prod_k (1 - POD_k(x(t_k; a, omega))) for point-time evidence, with
  POD_k = pod inside the polygon at t_k (area search), 1 - exp(-(W^2 / (8 pi)) int ds / r^3)
  along the relative motion of the target's path and the searcher's legs over the track's span
  (inverse cube; the legs' times give the searcher's position at each s: the exposure is an
  integral in time of W^2 v_leg / (8 pi r(s)^3), by Gauss-Legendre on each leg's overlap with
  the path), and the reports' likelihoods at x(t_k). The cell kernel's sum over roots of
  g(a) g(omega) / |det J| becomes the sum of w g(a) g(omega) / |det J|; the cell rule (exact in
  a) integrates w g(a) along its lines, so w must be evaluated at the same (a, omega) nodes. With
  heading noise the extra parameter joins (a, omega).
* Butterly: a course node theta (and speed node v) with start s0 gives the path
  s0 + v u(theta) s; w(s0, theta, v) is the same product at t_k. The start is integrated
  in closed form today (the normal convolved with the ring); with a weight that depends on s0
  it is not, so the kernel must integrate w over the start's normal too (a Gauss-Hermite rule
  in the start, per course node), which is the 3x budget of the bench row.
* What the kernels receive: polygons as flat edge arrays (x0, y0, x1, y1) with an offset per
  polygon, each polygon's time span and POD; tracks as leg arrays (x0, y0, t0, x1, y1, t1) with
  W and a law code; reports as (x, y, precision, t) and bearings as (sensor, bearing,
  1 / sigma, t); land as polygons without time. Searches with an interval (t0, t1) weight a
  path by the POD of its positions over the interval (the target moves while the area is
  searched: the fraction of the interval it spends inside, times the coverage rate).
* ``posterior`` then refuses nothing earlier for CAT and Butterly; the polar banana keeps its
  refusal (no path per parameter).
"""

from .posterior import PolarPosterior, Posterior, posterior
from .reports import BearingReport, Exclusion, PositionReport
from .searches import AreaSearch, TrackSearch, lateral_range

__all__ = ["AreaSearch", "TrackSearch", "lateral_range", "PositionReport", "BearingReport", "Exclusion",
           "posterior", "Posterior", "PolarPosterior"]
