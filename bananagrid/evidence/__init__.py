"""Evidence on the map: searches that found nothing, bearings, position reports and land, as
likelihood factors of the target's position, and the posterior map they give.

Modules: :mod:`~bananagrid.evidence.geometry` (polygons against cells, tracks against points),
:mod:`~bananagrid.evidence.searches` (``AreaSearch``, ``TrackSearch``, ``RasterSearch`` and the
lateral-range laws), :mod:`~bananagrid.evidence.packing` (earlier evidence as the kernels' time
nodes and channels), :mod:`~bananagrid.evidence.reports` (``PositionReport``, ``BearingReport``,
``Exclusion``), :mod:`~bananagrid.evidence.posterior` (``posterior`` at the map's own time).

Carrying earlier evidence forward (the plan for the kernels; not built yet)
---------------------------------------------------------------------------
A path is fixed by the map point x at t and the parameters the kernels already sum or
integrate over, so evidence at t1 < t is a weight w on those parameters, evaluated at the
path's position at t1, x1 = x(t1), and the map at t is the kernels' own integral with w inside:

    w = prod_k l_k(x1_k),   l_k = 1 - POD_k (a search), the report's likelihood, 0 on land.

* CAT: a root (a, omega) of x at t fixes the path, and x(t1; a, omega) is the motion model's
  closed form with the same pose. The density becomes sum over roots of w g(a) g(omega) /
  |det J|. The cell rule (exact in a along lines of constant omega, Gauss-Legendre in omega
  between corner passes) keeps its exactness for an area search or land: along a line, x(t1)
  is a curve in a, whose crossings with the polygon's edges split the a-interval into pieces
  of constant w (the Phi differences of each piece, weighted). Smooth factors (an inverse-cube
  track, reports) take Gauss-Legendre nodes in a on each piece. With heading noise the extra
  heading parameter joins (a, omega) the same way.
* Butterly: for a course c and speed V the start is s0 = x - V t e(c), so the position at t1
  is x1 = x - V (t - t1) e(c): no integral over the start is needed, only the weight inside the
  course integral, P_i(x) = int N(x - V_i t e(c); mean, cov) p(c) w(x - V_i (t - t1) e(c)) dc.
  The kernel's course integral (closed form over c today) becomes a quadrature over course
  nodes, split where x1(c), a circle of radius V_i (t - t1) about x, crosses a polygon edge
  (exact for polygons, as for the CAT), Gauss-Legendre between; the speed nodes stay.
* A search over an interval (t0, t1) or a track: the POD of a path is 1 - exp(-int gamma dt)
  along the relative motion (inverse cube: gamma = W^2 v_leg / (8 pi r(s)^3) on each leg, by
  Gauss-Legendre over the leg's time overlap with the path), an area search's coverage spread
  over its interval (the fraction of the interval the path spends inside times C), or its POD
  where the path is at the interval's end (a point-time search).
* What the kernels receive (:func:`~bananagrid.evidence.packing.pack`, an
  :class:`~bananagrid.protocol.EvidencePack`): time nodes, each with its factor, quadrature
  weight, kind and data (polygons as flat edge arrays, rasters, reports, bearings, the searcher's
  position and rate coefficient on a track's leg), and the channels (which factors each weight
  multiplies); the shared helpers in ``kernels/evidence.py`` add one path's contributions. Land
  holds at every time and is applied at the map's time, not carried. ``posterior`` takes earlier
  evidence for models that carry it (the CAT now, through ``bind_carried``); the polar banana
  keeps its refusal (no path per parameter).
"""

from .posterior import PolarPosterior, Posterior, posterior
from .reports import BearingReport, Exclusion, PositionReport
from .searches import AreaSearch, RasterSearch, TrackSearch, lateral_range

__all__ = ["AreaSearch", "TrackSearch", "RasterSearch", "lateral_range", "PositionReport", "BearingReport", "Exclusion",
           "posterior", "Posterior", "PolarPosterior"]
