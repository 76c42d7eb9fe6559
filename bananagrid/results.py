"""Results: values on a domain, with the captured mass and the provenance.

* :class:`Raster` — a density at the cell centres of a :class:`~bananagrid.Grid`;
* :class:`PolarRaster` — densities and cell probabilities on a :class:`~bananagrid.PolarLattice`;
* :class:`CellMap` — presence probabilities of the cells of an :class:`~bananagrid.AngularLattice`;
* :class:`GridPresence` — a planar mixture's density and exact cell probabilities on a grid;
* :class:`TiledRaster` — a density on a grid too large for memory, lazily in Dask blocks;
* :class:`BatchRaster` — many hypotheses, each on its own grid;
* :class:`ShardedBatch` — the same lazily, in shards of hypotheses computed by Dask.

Every array says what it holds: a density (per m^2, or per (m, rad) on a polar lattice) at a
cell centre, or a probability integrated over a cell.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from .domains.angular_lattice import AngularLattice
from .domains.grid import Grid
from .domains.polar_lattice import PolarLattice
from .domains.region import Region
from .geo.chart import chart as geo_chart
from .geo.dataset import cell_map_dataset, polar_dataset, raster_dataset
from .geo.zarr_store import write_batch_zarr, write_zarr
from .geo.frame import GeoFrame
from . import plotting
from .contours import DEFAULT_MASS_LEVELS
from .validate import BananagridError, finite

__all__ = ["Raster", "TiledRaster", "PolarRaster", "CellMap", "GridPresence", "BatchRaster", "ShardedBatch"]

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Raster:
    """A model's density sampled at the cell centres of a grid.

    Attributes
    ----------
    values : ndarray, shape (ny, nx)
        Density per square metre at each cell centre (``quantity == "density"``); rows south
        to north. After :meth:`normalise` the values are scaled so that they sum to one over the
        grid (times the cell area).
    grid : Grid
        The grid the values belong to.
    mass : float
        Probability mass captured by the grid before any normalisation: ``sum(values) * dx * dy``
        of the raw density (midpoint rule). A value well below one says the grid misses mass.
    normalised : bool
        Whether ``values`` were divided by ``mass``.
    provenance : dict
        Model name and parameters, kernel, dtype, device, threads, seconds, truncation.
    frame : GeoFrame or None
        Where the grid's local metres lie on the Earth (a geographic scene's ``[geo]``), for
        latitude and longitude, UTC times and the CRS of exported maps; None in local metres.
    """

    values: np.ndarray
    grid: Grid
    mass: float
    normalised: bool = False
    quantity: str = "density"
    provenance: dict = field(default_factory=dict)
    frame: GeoFrame | None = None

    @property
    def x(self) -> np.ndarray:
        return self.grid.x

    @property
    def y(self) -> np.ndarray:
        return self.grid.y

    @property
    def peak(self) -> float:
        return float(np.max(self.values))

    def __repr__(self) -> str:
        """Shape, extent, mass and peak; never the values."""
        g = self.grid
        x0, x1, y0, y1 = g.extent
        return (f"Raster({g.nx} x {g.ny} cells of {g.dx:g} x {g.dy:g} m, x {x0:g}..{x1:g} m, y {y0:g}..{y1:g} m, "
                f"mass {self.mass:.6f}{' normalised' if self.normalised else ''}, peak {self.peak:.4g} m^-2, "
                f"model {self.provenance.get('model', '?')})")

    def plot(self, ax=None, *, mass_levels=DEFAULT_MASS_LEVELS, title: str | None = None,
             t: float | None = None, markers=(), geometry: bool = True, colorbar: bool = True):
        """Draw the map with matplotlib (the ``plot`` extra) and return the axes.

        log10 density in km (x east, y north, north up), a colour bar, the probability-mass
        contours labelled with their areas, framed on the outermost region, and what the
        provenance names (a bearing fix's sensors, bearings and fix; a start and its heading).
        Arguments as for :func:`bananagrid.plotting.plot_raster`: ``mass_levels`` (in (0, 1)),
        ``title``, ``t`` (s, for the default title), ``markers`` (``(x, y, label)`` in metres),
        ``geometry``, ``colorbar``. A raster with a geographic :attr:`frame` is drawn as a chart
        (latitude and longitude lines and labels, the land: :mod:`bananagrid.geo.chart`).
        """
        drawn = None if self.frame is None else functools.partial(geo_chart, self.frame)
        return plotting.plot_raster(self, ax, mass_levels=mass_levels, title=title, t=t, markers=markers,
                                    geometry=geometry, colorbar=colorbar, chart=drawn)

    def _repr_png_(self) -> bytes | None:
        """The map as PNG bytes for notebooks (None without matplotlib: the HTML says why)."""
        try:
            return plotting.png_bytes(self)
        except plotting.MatplotlibMissing:
            return None

    def _repr_html_(self) -> str:
        """A table of the grid, mass, peak and probability-mass regions, and the map."""
        return plotting.raster_html(self)

    def to_xarray(self, frame: GeoFrame | None = None, name: str = "density", t: float | None = None):
        """The raster as a CF-1.10 :class:`xarray.Dataset` (the ``geo`` extra).

        One variable ``name`` (the density per m^2, dims (time, y, x)) at one time ``t``
        (s since the fix; default the provenance's ``t`` where the model has one, else 0),
        with ``name_mass`` and ``name_normalised``, projected ``x``/``y`` and, with a frame
        (default :attr:`frame`), ``lat``/``lon``, the ``crs`` grid mapping and UTC time. See
        :func:`bananagrid.geo.dataset.raster_dataset`; write it with
        :func:`bananagrid.geo.dataset.write_netcdf`.
        """
        t = _default_t(self.provenance) if t is None else t
        return raster_dataset([(name, t, self)], self.frame if frame is None else frame)

    def normalise(self) -> "Raster":
        """Return a copy whose values integrate to one over the grid; ``mass`` keeps the raw mass."""
        if not self.mass > 0.0:
            raise BananagridError(
                f"cannot normalise a raster that captured no mass (mass = {self.mass!r}): "
                "the grid misses the model's support"
            )
        if self.normalised:
            return self
        return replace(self, values=self.values / self.mass, normalised=True)


@dataclass(frozen=True)
class PolarRaster:
    """A model on a :class:`PolarLattice`: densities at the cell centres and cell probabilities.

    Attributes
    ----------
    density : ndarray, shape (n_range, n_bearing)
        Density per (m, rad) at each cell centre, ``r p(x, y)`` with p the model's density per
        m^2 (kernel dtype). ``sum(density) * dr * db`` is the midpoint-rule mass.
    probability : ndarray, shape (n_range, n_bearing), float64
        Probability of each cell: the integral of p over the cell, ``int int p r dr db``
        (Gauss-Legendre, accuracy in ``provenance["accuracy"]``).
    lattice : PolarLattice
    mass : float
        ``sum(probability)`` before any normalisation: the mass the lattice captures.
    normalised : bool
        Whether ``density`` and ``probability`` were divided by ``mass``.
    provenance : dict
        Model parameters, lattice, dtype, device, threads, seconds, nodes and the accuracy claim.
    frame : GeoFrame or None
        Where the lattice's local metres lie on the Earth, if known (see :class:`Raster`).
    """

    density: np.ndarray
    probability: np.ndarray
    lattice: PolarLattice
    mass: float
    normalised: bool = False
    provenance: dict = field(default_factory=dict)
    frame: GeoFrame | None = None

    @property
    def ranges(self) -> np.ndarray:
        """Range cell centres, m."""
        return self.lattice.range_centres

    @property
    def bearings(self) -> np.ndarray:
        """Bearing cell centres, rad clockwise from the lattice's heading."""
        return self.lattice.bearing_centres

    def to_xarray(self, frame: GeoFrame | None = None):
        """The densities and cell probabilities as an :class:`xarray.Dataset` on ``range`` and
        ``bearing`` (the ``geo`` extra); see :func:`bananagrid.geo.dataset.polar_dataset`.
        ``frame`` defaults to :attr:`frame` (adds latitude and longitude of the cell centres)."""
        return polar_dataset(self, self.frame if frame is None else frame)

    def normalise(self) -> "PolarRaster":
        """Return a copy whose probabilities sum to one; ``mass`` keeps the raw captured mass."""
        if not self.mass > 0.0:
            raise BananagridError(
                f"cannot normalise a polar raster that captured no mass (mass = {self.mass!r}): "
                "the lattice misses the model's support"
            )
        if self.normalised:
            return self
        return replace(
            self,
            density=self.density / np.asarray(self.mass, dtype=self.density.dtype),
            probability=self.probability / self.mass,
            normalised=True,
        )


@dataclass(frozen=True)
class CellMap:
    """Presence probability of each cell of an :class:`AngularLattice`.

    Attributes
    ----------
    prob : ndarray
        p(C | S) per cell, indexed [azimuth, elevation] (line: [azimuth]), float64.
    lattice : AngularLattice
    region : Region or None
        The conditioning region S (cells clipped to it), if any.
    region_probability : float
        p(S) (1 without a region).
    error : ndarray
        Estimated absolute error of each probability (0 for exact ones): the sum over components
        of |K15 - G7| divided by p(S), a conservative estimate of the Kronrod rule's error.
    clipped_sizes : ndarray or None
        Length, area or volume of each cell within S, if a region is given.
    provenance : dict
    frame : GeoFrame or None
        Where the array's frame lies on the Earth, if known (see :class:`Raster`).
    """

    prob: np.ndarray
    lattice: AngularLattice
    region: Region | None = None
    region_probability: float = 1.0
    error: np.ndarray | None = None
    clipped_sizes: np.ndarray | None = None
    provenance: dict = field(default_factory=dict)
    frame: GeoFrame | None = None

    @property
    def azimuth_edges(self) -> np.ndarray:
        return self.lattice.azimuth_edges

    @property
    def elevation_edges(self) -> np.ndarray:
        return self.lattice.elevation_edges

    @property
    def sizes(self) -> np.ndarray:
        return self.lattice.sizes

    @property
    def centroids(self) -> np.ndarray:
        return self.lattice.centroids

    def cell_polygons(self, n_arc: int = 8, far: float | None = None) -> np.ndarray:
        """Outlines on the target plane in world coordinates (see AngularLattice.cell_polygons)."""
        return self.lattice.cell_polygons(n_arc=n_arc, far=far)

    def to_xarray(self):
        """The cell probabilities, their errors and the cell sizes as an :class:`xarray.Dataset`
        on ``azimuth`` (and ``elevation``) with the cell edges as bounds (the ``geo`` extra);
        see :func:`bananagrid.geo.dataset.cell_map_dataset`."""
        return cell_map_dataset(self)

    def clutter_mask(self, threshold: float) -> np.ndarray:
        """True where a cell's presence probability is below ``threshold`` (detections there are
        treated as clutter, Section 11)."""
        t = finite("threshold", threshold)
        if not 0.0 <= t <= 1.0:
            raise BananagridError(f"threshold = {t!r}: a probability threshold must be in [0, 1]")
        return self.prob < t

    def degree_indices(self) -> tuple[np.ndarray, ...]:
        """The directions as integer degrees, uint16 (the paper's 16-bit angles, Section 2)."""
        out = []
        axes = [("azimuth", self.lattice.azimuths)]
        if self.lattice.geometry != "line":  # a line has azimuths only (no elevations to read)
            axes.append(("elevation", self.lattice.elevations))
        for name, values in axes:
            deg = np.degrees(values)
            rounded = np.round(deg)
            if np.max(np.abs(deg - rounded), initial=0.0) > 1e-6:
                raise BananagridError(f"{name}s are not whole degrees: the lattice has no integer-degree index")
            out.append((rounded % 360 if name == "azimuth" and self.lattice.geometry != "line" else rounded).astype(np.uint16))
        return tuple(out)

    def degree_table(self) -> np.ndarray:
        """The probabilities in an array indexed by integer degrees: ``table[az_deg, el_deg]``
        of shape (360, 181) (line: ``table[az_deg]``, 361), NaN for directions not in the lattice."""
        idx = self.degree_indices()
        if self.lattice.geometry == "line":
            table = np.full(361, np.nan)
            table[idx[0]] = self.prob
            return table
        table = np.full((360, 181), np.nan)
        table[np.ix_(idx[0], idx[1])] = self.prob
        return table

    def world_map(self, x, y) -> np.ndarray:
        """The presence map on the target plane z = -h in world coordinates: at each point
        (x, y) (broadcast), the probability of the cell holding it divided by the cell's size
        (clipped to S where a region is given); 0 outside the lattice (and S). Plane and frustum
        (for the frustum: per m^3, the cell through the point at depth h)."""
        if self.lattice.geometry == "line":
            raise BananagridError("world_map: a line lattice has no plane map; use prob and lattice.line_edges()")
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        lat = self.lattice
        phi = np.arctan2(by, bx)
        a0 = lat.azimuth_edges[0]
        rel = (phi - a0) % _TWO_PI
        ia = np.floor(rel / lat.azimuth_step).astype(int)
        theta = math.pi - np.arctan2(np.hypot(bx, by), lat.h)
        ie = np.searchsorted(lat.elevation_edges, theta, side="right") - 1
        ie = np.where(theta == lat.elevation_edges[-1], lat.n_elevation - 1, ie)
        ok = (ia >= 0) & (ia < lat.n_azimuth) & (ie >= 0) & (ie < lat.n_elevation)
        size = self.clipped_sizes if self.clipped_sizes is not None else lat.sizes
        with np.errstate(divide="ignore", invalid="ignore"):
            dens = np.where(size > 0, self.prob / size, 0.0)
        out = np.zeros(bx.shape)
        out[ok] = dens[ia[ok], ie[ok]]
        if self.region is not None:
            b = self.region.bounds
            out[(bx < b[0, 0]) | (bx > b[0, 1]) | (by < b[1, 0]) | (by > b[1, 1])] = 0.0
        return out


@dataclass(frozen=True)
class GridPresence:
    """A planar Gaussian mixture on a :class:`~bananagrid.Grid`.

    Attributes
    ----------
    density : ndarray, shape (ny, nx)
        Density per m^2 at each cell centre (rows south to north).
    probability : ndarray, shape (ny, nx)
        Exact probability of each rectangular cell (bivariate normal rectangle probabilities).
    grid : Grid
    mass : float
        ``sum(probability)``: the mixture's probability of the grid's extent.
    provenance : dict
    """

    density: np.ndarray
    probability: np.ndarray
    grid: Grid
    mass: float
    provenance: dict = field(default_factory=dict)


def _default_t(provenance: dict) -> float:
    given = provenance.get("t", 0.0)
    return float(given) if isinstance(given, (int, float)) and not isinstance(given, bool) else 0.0


@dataclass(frozen=True)
class TiledRaster:
    """A model's density at the cell centres of a grid, lazily, in blocks computed by Dask
    (:func:`bananagrid.rasterise` with ``chunks=``; :mod:`bananagrid.engine.tiles`).

    Attributes
    ----------
    values : dask.array.Array, shape (ny, nx)
        Density per square metre at each cell centre (raw), in blocks of ``chunks``. Nothing is
        computed until asked: :meth:`compute`, :meth:`to_zarr`, or Dask's own ``compute``.
    grid : Grid
    chunks : (int, int)
        Block shape, cells.
    skipped : ndarray of bool, (blocks in y, blocks in x)
        Blocks the model proved to be at most ``floor`` everywhere: zeros, never computed.
    floor : float
        Density per m^2 at or below which a block was skipped (``-inf``: none was).
    provenance : dict
        As a :class:`Raster`'s, with the chunks and the tiles computed and skipped.
    frame : GeoFrame or None
    """

    values: object
    grid: Grid
    chunks: tuple
    skipped: np.ndarray
    floor: float
    provenance: dict = field(default_factory=dict)
    frame: GeoFrame | None = None
    quantity: str = "density"
    normalised: bool = False

    @property
    def x(self) -> np.ndarray:
        return self.grid.x

    @property
    def y(self) -> np.ndarray:
        return self.grid.y

    @property
    def cells_skipped(self) -> int:
        """Cells in skipped blocks (never computed)."""
        return self.grid.nx * self.grid.ny - int(self.provenance["cells_computed"])

    def computed_blocks(self):
        """``(i, j, (row0, row1), (col0, col1))`` of every block that is not skipped."""
        edges = [np.concatenate(([0], np.cumsum(c))) for c in self.values.chunks]
        for i, j in zip(*np.nonzero(~self.skipped)):
            yield (int(i), int(j), (int(edges[0][i]), int(edges[0][i + 1])),
                   (int(edges[1][j]), int(edges[1][j + 1])))

    @property
    def lazy_mass(self):
        """The captured mass, ``sum(values) * dx * dy`` (each computed block summed in float64;
        the skipped ones are 0 and not even tasks), as a lazy Dask scalar, computed with the
        values by :meth:`to_zarr` in the same pass."""
        sums = [self.values.blocks[i, j].sum(dtype=np.float64) for i, j, _, _ in self.computed_blocks()]
        if not sums:
            return self.values[:0, :0].sum(dtype=np.float64)
        return np.stack(sums).sum() * self.grid.cell_area

    @property
    def mass(self) -> float:
        """The captured mass; computes every block that is not skipped."""
        return float(self.lazy_mass.compute())

    def compute(self) -> Raster:
        """The whole grid in memory, as a :class:`Raster` (at most
        :data:`~bananagrid.domains.grid.MAX_CELLS` cells)."""
        self.grid.check_in_memory()
        values = np.asarray(self.values.compute())
        mass = float(np.sum(values, dtype=np.float64) * self.grid.cell_area)
        return Raster(values=values, grid=self.grid, mass=mass, provenance=dict(self.provenance), frame=self.frame)

    def to_xarray(self, frame: GeoFrame | None = None, name: str = "density", t: float | None = None):
        """A lazy CF-1.10 :class:`xarray.Dataset` of the raster (as :meth:`Raster.to_xarray`, with
        Dask-backed values and mass)."""
        t = _default_t(self.provenance) if t is None else t
        return raster_dataset([(name, t, self)], self.frame if frame is None else frame)

    def to_zarr(self, path, *, name: str = "density", t: float | None = None, frame: GeoFrame | None = None,
                title: str = "", progress=None):
        """Write the raster to a Zarr store at ``path`` block by block (Dask's scheduler: a
        ``distributed.Client`` if one is active), skipping empty blocks, whole or not at all; see
        :func:`bananagrid.geo.zarr_store.write_zarr`. Returns the path."""
        t = _default_t(self.provenance) if t is None else t
        return write_zarr(path, [(name, t, self)], self.frame if frame is None else frame, title=title,
                          progress=progress)

    def __repr__(self) -> str:
        g = self.grid
        skipped = int(self.skipped.sum())
        return (f"TiledRaster({g.nx} x {g.ny} cells of {g.dx:g} x {g.dy:g} m in {self.skipped.size} blocks of "
                f"{self.chunks[0]} x {self.chunks[1]}, {skipped} skipped (proved <= {self.floor:.3g} m^-2), "
                f"model {self.provenance.get('model', '?')})")


@dataclass(frozen=True)
class BatchRaster:
    """Densities of H hypotheses on their own grids of one shape.

    Attributes
    ----------
    values : ndarray (H, ny, nx)
        Density per m^2 at each grid's cell centres (raw, not normalised).
    grids : tuple of Grid
    mass : ndarray (H,)
        Captured mass of each (sum of values times its cell area).
    """

    values: np.ndarray
    grids: tuple
    mass: np.ndarray


@dataclass(frozen=True)
class ShardedBatch:
    """Densities of H hypotheses on their own framed grids, lazily, in shards computed by Dask
    (:func:`bananagrid.engine.batch_shards.rasterise_batch_shards`).

    Attributes
    ----------
    values : dask.array.Array (H, ny, nx)
        Density per m^2 at each framed grid's cell centres (raw), in blocks of whole shards.
    bounds : ndarray (H, 4)
        Each hypothesis' grid, as its outer edges ``(x0, x1, y0, y1)``, m.
    shape : (int, int)
        ``(ny, nx)`` of every grid.
    """

    values: object
    bounds: np.ndarray
    shape: tuple

    @property
    def cell_areas(self) -> np.ndarray:
        """Each grid's cell area, m^2 (as its :class:`Grid` computes it)."""
        ny, nx = self.shape
        return ((self.bounds[:, 1] - self.bounds[:, 0]) / nx) * ((self.bounds[:, 3] - self.bounds[:, 2]) / ny)

    @property
    def lazy_mass(self):
        """Each hypothesis' captured mass, lazily (computed with the values by :meth:`to_zarr`)."""
        return self.values.sum(axis=(1, 2), dtype=np.float64) * self.cell_areas

    def compute(self) -> BatchRaster:
        """Gather everything into a :class:`BatchRaster` (the grids built from :attr:`bounds`)."""
        ny, nx = self.shape
        values = np.asarray(self.values.compute())
        grids = tuple(Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / nx, dy=(y1 - y0) / ny)
                      for x0, x1, y0, y1 in self.bounds)
        return BatchRaster(values, grids, values.sum(axis=(1, 2), dtype=np.float64) * np.array([g.cell_area for g in grids]))

    def to_zarr(self, path, *, progress: bool = False):
        """Write the values, frames and masses to the Zarr store ``path`` shard by shard, whole or
        not at all (:func:`bananagrid.geo.zarr_store.write_batch_zarr`). Returns the path."""
        return write_batch_zarr(path, self.values, self.bounds, self.lazy_mass, progress=progress)

    def __repr__(self) -> str:
        h = self.bounds.shape[0]
        return (f"ShardedBatch({h:,} hypotheses on {self.shape[0]} x {self.shape[1]} grids, "
                f"{len(self.values.chunks[0])} shards)")


def _short_repr(self) -> str:
    """Fields with arrays shown by shape and dtype, never their values."""
    parts = []
    for name in self.__dataclass_fields__:
        value = getattr(self, name)
        if isinstance(value, np.ndarray):
            shown = f"array{value.shape} {value.dtype}"
        elif isinstance(value, dict):
            shown = f"{{{len(value)} keys}}"
        else:
            shown = repr(value)
            shown = shown if len(shown) <= 80 else shown[:77] + "..."
        parts.append(f"{name}={shown}")
    return f"{type(self).__name__}({', '.join(parts)})"


for _cls in (PolarRaster, CellMap, GridPresence, BatchRaster):
    _cls.__repr__ = _short_repr
