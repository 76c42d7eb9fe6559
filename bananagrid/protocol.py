"""The model protocol: what a model provides so that everything else can compute it.

The engine, the polar lattices, the radial laws, batches, scenes and recordings talk to a model
only through :class:`DensityModel`; none of them asks a model for its type. A model owns what
differs between models:

* its parameters, validated at construction, and their plain-data form (:meth:`parameters`);
* its densities: the Warp kernels and arguments it hands the engine (:meth:`bind`, returning a
  :class:`KernelBinding`), through which ``pdf`` and ``rasterise`` run;
* its generative story (:meth:`sample`), the Monte Carlo oracle;
* its length scales (:meth:`polar_scales`, :meth:`feature_scale`) and radial bounds
  (:meth:`radial_extent`), from which lattices size their quadrature and rays their support;
* its scene keys (:attr:`scene`, a :class:`SceneSchema`) and its stated float32 agreement.

:class:`bananagrid.models.base.Model` implements the parts that most models share (``pdf``
through the engine, ``parameters`` from dataclass fields, rays through ``pdf``).

This module sits below the engine and the models: the engine implements
:class:`KernelContext` (Warp arrays and launches for the run's dtype and device) and consumes
:class:`KernelBinding`; models build bindings through the context and never import Warp.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from .domains.pose import Pose

__all__ = [
    "DensityModel", "PresenceModel", "BatchModel", "CarryingModel", "EvidencePack", "KernelBinding", "CellPlan",
    "KernelContext", "Extent", "SceneKey", "SceneSchema",
    "KEY_TYPES",
    "LATLON",
]


class KernelContext(Protocol):
    """Warp arrays and launches in one dtype on one device: the engine's half of a binding.

    Attributes
    ----------
    dtype : numpy.dtype
        The kernels' scalar type (float32 or float64).
    device : str
        Warp device (``"cpu"``, ``"cuda"``).
    threads : int
        CPU threads the run may use.
    """

    dtype: np.dtype
    device: str
    threads: int

    def scalar(self, value: float) -> Any:
        """``value`` as the kernels' scalar type."""

    def array(self, values, *, dtype=None) -> Any:
        """A device array of ``values`` in the kernels' scalar type (or ``dtype``: numpy
        float64, int32, or a Warp vector type)."""

    def zeros(self, shape, *, dtype=None) -> Any:
        """A zeroed device array (scalar type unless ``dtype``)."""

    def empty(self, shape, *, dtype=None) -> Any:
        """An uninitialised device array (scalar type unless ``dtype``)."""

    def vector(self, length: int) -> Any:
        """The Warp vector type of ``length`` lanes of the scalar type (e.g. SIMD scratch)."""

    def struct(self, params, /, **values) -> Any:
        """An instance of a family's parameter struct (``params``:
        :class:`bananagrid.kernels.generate.Params`) in the scalar type, fields from ``values``."""

    def structs(self, params, count: int, /, **columns) -> Any:
        """A device array of ``count`` parameter structs, field ``name`` of the ``h``-th from
        ``columns[name][h]``."""

    def launch(self, kernel, *, dim, inputs) -> None:
        """Launch ``kernel`` over ``dim`` with ``inputs`` on this context's device."""

    def numpy(self, array) -> np.ndarray:
        """A device array as a NumPy array (waits for the device)."""

    def bands(self, n: int, per_thread: int = 1, align: int = 1) -> list[tuple[int, int]]:
        """Contiguous bands ``(start, stop)`` of ``n`` rows: ``per_thread`` per CPU thread, one on
        a GPU; each starts on a multiple of ``align`` rows."""

    def run_bands(self, launch_band, bands: list[tuple[int, int]]) -> None:
        """Call ``launch_band(start, stop)`` for every band, on the context's threads (the
        kernel's module loaded first with :meth:`load`)."""

    def load(self, kernel) -> None:
        """Compile or load ``kernel``'s module before concurrent launches need it."""


class Extent(Protocol):
    """Where the points of one engine call lie, seen from a model's frame."""

    def radii(self, origin: tuple[float, float]) -> tuple[float, float]:
        """Least and greatest distance from ``origin`` to the points that will be queried."""


@dataclass(frozen=True)
class KernelBinding:
    """A model bound to its kernels, ready for the engine to launch.

    The kernels are generated from the family's density and parameter struct
    (:func:`bananagrid.kernels.generate.density_kernels`, which states their arguments and
    layout); a model hands over the family and the parameters and writes no launch code.

    Attributes
    ----------
    kernels : DensityKernels
        The family's kernels (grid, points, batch) and their layout.
    params : struct
        The parameter struct (:meth:`KernelContext.struct`); for a batch, a device array of them
        (:meth:`KernelContext.structs`).
    notes : dict
        Provenance entries of this binding (scan nodes, truncated mass, ...).
    """

    kernels: Any
    params: Any
    notes: dict = field(default_factory=dict)

    @property
    def kernel_name(self) -> str:
        """``module.kernel`` of the grid kernel, for provenance."""
        return self.kernels.name


@dataclass(frozen=True)
class CellPlan:
    """A model's own way to the probabilities of a domain's cells (instead of the engine's
    rule for that domain), sized before anything runs: the one form of cell plans for every
    domain and model family (:meth:`DensityModel.cell_plan`, :meth:`PresenceModel.cell_plan`).

    Attributes
    ----------
    seconds : float or None
        Estimated seconds of one CPU core, checked like :meth:`DensityModel.work_estimate`;
        None where the domain's size bounds the work (an angular lattice's cells).
    run : callable
        ``run(ctx) -> (cells, notes)``, ``ctx`` a :class:`KernelContext`: on a
        :class:`~bananagrid.Grid`, the probability of every cell, float64 of shape ``(ny, nx)``,
        which the engine sums and narrows into a :class:`~bananagrid.Raster`; on an
        :class:`~bananagrid.AngularLattice`, the complete :class:`~bananagrid.CellMap`. ``notes``:
        provenance entries (method, nodes, the error claim).
    method : str
        One line naming the method, for provenance and messages.
    """

    seconds: float
    run: Callable
    method: str


#: Value types of scene keys and how a scene writes them.
KEY_TYPES = {
    "number": "number",
    "numbers": "array of numbers",
    "pair": "`[x, y]`",
    "pairs": "array of `[x, y]`",
    "matrix": "2 x 2 array",
    "choice": "string",
}

#: Alternative units a scene may use under ``NAME_ALIAS`` (converted to SI when it is loaded).
ALIASES = {"deg": "degrees", "kn": "knots"}
#: Suffix of a position given as ``[latitude, longitude]`` in degrees (geographic scenes).
LATLON = "latlon"


@dataclass(frozen=True)
class SceneKey:
    """One parameter a scene layer may set.

    Attributes
    ----------
    name : str
        The parameter's name (SI units), also its scene key.
    type : str
        One of :data:`KEY_TYPES`.
    unit : str
        SI unit, for documentation ("" for none).
    default : str
        What holds when the key is absent, for documentation ("required" for required keys).
    allowed : str
        The domain, for documentation (the model checks it).
    alias : str or None
        ``"deg"``: the key may be given as ``NAME_deg`` in degrees; ``"kn"``: as ``NAME_kn`` in
        knots.
    choices : tuple of str
        The allowed strings of a ``"choice"`` key.
    bearing_at : str or None
        For a bearing (rad, clockwise from north): the position parameter (a ``"pair"`` or
        ``"pairs"`` key, one position per bearing) where it is measured, or ``""`` for the
        local origin. A geographic scene gives true bearings; the scene turns them into grid
        bearings there (:meth:`bananagrid.geo.frame.GeoFrame.grid_bearing`).
    """

    name: str
    type: str = "number"
    unit: str = ""
    default: str = "required"
    allowed: str = "finite"
    alias: str | None = None
    choices: tuple = ()
    bearing_at: str | None = None

    def __post_init__(self):
        if self.type not in KEY_TYPES:
            raise ValueError(f"SceneKey {self.name}: type {self.type!r} not in {tuple(KEY_TYPES)}")
        if self.alias is not None and self.alias not in ALIASES:
            raise ValueError(f"SceneKey {self.name}: alias {self.alias!r} not in {tuple(ALIASES)}")

    @property
    def position(self) -> bool:
        """Whether it holds positions in metres (``"pair"`` or ``"pairs"``): then a geographic
        scene may give it as ``NAME_latlon`` in degrees of latitude and longitude."""
        return self.type in ("pair", "pairs") and self.unit == "m"

    @property
    def keys(self) -> tuple[str, ...]:
        """The scene keys that set it: its name, ``NAME_ALIAS`` with an alias, and
        ``NAME_latlon`` for a position."""
        names = (self.name,) if self.alias is None else (self.name, f"{self.name}_{self.alias}")
        return (*names, f"{self.name}_{LATLON}") if self.position else names


@dataclass(frozen=True)
class SceneSchema:
    """How scene layers of one model kind are written.

    Attributes
    ----------
    keys : tuple of SceneKey
        Every parameter a layer may give, in documentation order (derived from the declared
        fields of a :func:`~bananagrid.models.params.modelclass` when left empty).
    required : tuple of str, optional
        Parameters every layer needs (from its table or ``[defaults]``); a timed kind also
        needs ``t`` unless the scene gives ``scene.times``. None: derived from the declared
        fields (those without a default), or none.
    timed : bool
        Whether the density depends on the elapsed time ``t`` (then ``scene.times`` applies).
    build : callable, optional
        ``build(params) -> model`` from the parameters in SI units (no aliases); a
        ``modelclass`` calls itself with them when left out.
    missing : callable, optional
        ``missing(given) -> list of str``: further keys a layer lacks, for rules the key list
        cannot say (one of two ways to give a value; keys that depend on another's value).
        ``given`` maps each parameter to ``(key path, value as written, value in SI)``. It raises
        :class:`~bananagrid.BananagridError` for keys that contradict each other.
    message_keys : Mapping
        Names in the model's error messages that are not scene keys, mapped to the key that
        sets them (e.g. a speed law's fields).
    radial_curves : bool
        Whether layers of this kind can record the conditional radial curves (``[radial]``).
    summary : str
        One line for the scene documentation.
    options : Mapping
        Scene-wide ``[output]`` switches (true or false, default false) this kind adds, by name,
        with what each adds; the kind's recording module acts on them
        (:func:`bananagrid.recording.layers.log_scene_extras`).
    """

    keys: tuple = ()
    required: tuple | None = None
    timed: bool = False
    build: Callable | None = None
    missing: Callable | None = None
    message_keys: Mapping = field(default_factory=dict)
    radial_curves: bool = False
    summary: str = ""
    options: Mapping = field(default_factory=dict)

    @property
    def key_names(self) -> tuple[str, ...]:
        """Every scene key, aliases included, in documentation order."""
        return tuple(k for key in self.keys for k in key.keys)

    def key(self, name: str) -> SceneKey:
        """The :class:`SceneKey` of parameter ``name``."""
        for key in self.keys:
            if key.name == name:
                return key
        raise KeyError(name)


@runtime_checkable
class DensityModel(Protocol):
    """A model of where a target is: a density per m^2 in the world plane (x east, y north).

    Class attributes
    ----------------
    kind : str
        Its scene name (``model = "KIND"``).
    scene : SceneSchema
        Its scene keys.
    float32_rtol : float
        Stated agreement of float32 with float64 kernels, relative, where the density exceeds
        1e-6 of its peak (tested over every registered model), beyond the float64 density's
        own change over the float32 rounding of the point's coordinates, which no float32
        kernel can resolve (tests/models/test_float32_sweep.py).
    """

    kind: ClassVar[str]
    scene: ClassVar[SceneSchema]
    float32_rtol: ClassVar[float]

    @property
    def pose(self) -> Pose | None:
        """The model's local frame (origin at the last fix, +y along the initial heading), or
        None for a model without one."""

    def parameters(self) -> dict:
        """Plain-data parameters for provenance and recordings (``{"model": NAME, ...}``)."""

    def bind(self, ctx: KernelContext, extent: Extent, *, grid: bool) -> KernelBinding:
        """The kernels and arguments that compute the density at points within ``extent``
        (``grid``: for the grid kernel, which may skip cells the model proves negligible)."""

    def pdf(self, x, y, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
        """Density per m^2 at world points (``x``, ``y`` broadcast), through the kernels."""

    def sample(self, n: int, rng) -> np.ndarray:
        """``n`` world positions from the model's generative story, shape ``(n, 2)``."""

    @property
    def integrates_to_one(self) -> bool:
        """Whether the density is a probability density (its integral over the plane is 1), so
        that a grid's captured mass above 1 can only be the cells' error; False for a map that
        integrates to about one (the exact bearing likelihood)."""

    def landmarks(self) -> dict[str, np.ndarray]:
        """Where the model is anchored in the world, for maps (world metres): ``"fix"``, shape
        ``(1, 2)`` (a last fix, a start's mean, an estimated position), and for a model built on
        sensors ``"stations"`` ``(n, 2)`` and ``"bearings"`` ``(n, 2, 2)`` (line segments);
        empty for a model anchored nowhere."""

    def work_estimate(self, cells: int, extent: Extent) -> float:
        """Estimated seconds of one CPU core (float64 kernels) to compute ``cells`` cells within
        ``extent``, from the model's own work sizes (scan nodes, speed nodes, tables), calibrated
        on cells where the density is not negligible and rounded up; checked before any launch
        (:mod:`bananagrid.engine.work`)."""

    def cell_plan(self, domain, region=None) -> CellPlan | None:
        """The model's own method for the probabilities of the cells of ``domain``, or None for
        the engine's rule there: the quadrature of the density over a
        :class:`~bananagrid.Grid`'s cells (:func:`bananagrid.engine.grid_cells.probability_raster`)
        or a :class:`~bananagrid.PolarLattice`'s (:mod:`bananagrid.engine.polar_cells`). A domain
        the model has no cells of (an :class:`~bananagrid.AngularLattice`'s directions, for a
        density in the world plane) raises :class:`~bananagrid.BananagridError` in one line;
        ``region`` conditions an angular lattice's cells only."""

    def density_bound(self, x0: float, x1: float, y0: float, y1: float) -> float:
        """A proved (not sampled) upper bound of the density the model's grid kernel computes, in
        float32 or float64, at any point of the closed rectangle ``[x0, x1] x [y0, y1]`` (world
        metres): ``0.0`` where the kernel provably computes exact zeros, ``math.inf`` where the
        model proves nothing (a rectangle holding a singular point, a model without a bound).
        Tiled rasterising leaves a tile whose bound is at most :meth:`density_floor` at 0
        without computing it (:mod:`bananagrid.engine.tiles`)."""

    def density_floor(self) -> float:
        """The density per m^2 at or below which tiled rasterising may leave a whole tile at 0:
        :data:`bananagrid.models.base.ZERO_BELOW` times a lower bound of the density's maximum
        (:meth:`peak_lower_bound`)."""

    def peak_lower_bound(self) -> float:
        """A lower bound of the density's maximum per m^2 (the largest of values the kernels
        computed at chosen points)."""

    def singular_points(self) -> np.ndarray:
        """World points ``(k, 2)`` where the density is infinite like 1 / r (the origin of a polar
        density), which the engine's quadrature integrates in polar coordinates about them;
        empty for none."""

    def seams(self) -> np.ndarray:
        """World rays ``(k, 3)``, rows ``(x, y, bearing)`` (a half-line from ``(x, y)`` at a
        bearing clockwise from north), along which the density has a kink or a jump (where an
        angle wraps at +-pi behind a start or a station, where the domain of an approximation
        ends), and where a ray starts, a point about which the density changes with the
        direction; empty for none. The engine's quadrature makes them breaks of its rules
        (:mod:`bananagrid.engine.grid_cells`, :mod:`bananagrid.engine.polar_cells`)."""

    def polar_law(self, origin: tuple[float, float]) -> Callable | None:
        """Where the density, in polar coordinates (r, theta) about ``origin`` (theta a bearing
        clockwise from north), is g(theta) N(r; mu(theta), sd(theta)) / r for r > 0 (a polar
        banana about its start): ``law(theta) -> (g, mu, sd)``, float64 arrays of theta's shape
        (sd <= 0: no mass at that bearing), so that the engine integrates cells swept about
        ``origin`` exactly in r; else None."""

    def polar_scales(self, origin: tuple[float, float]) -> tuple[float, float]:
        """Smallest widths of the density's features seen from ``origin`` (or from the model's
        own pose, if it has one): ``(radial_m, angular_rad)``."""

    def feature_scale(self) -> float:
        """Smallest width of the density's features in metres, in any direction."""

    def radial_extent(self, pose: Pose) -> tuple[float, float]:
        """``(range scale, greatest range worth scanning)`` of rays from ``pose``: the scale
        bounds the range SD from below, beyond the range the density is negligible."""

    def ray_values(self, pose: Pose, radii: np.ndarray, angles: np.ndarray, *, threads=None) -> np.ndarray:
        """p(r, theta) at ``radii`` x ``angles`` (bearings clockwise from ``pose``'s heading),
        shape ``(len(radii), len(angles))``."""


@runtime_checkable
class BatchModel(Protocol):
    """A model kind whose hypotheses can be computed many at a time
    (:mod:`bananagrid.engine.batch`): one launch over (hypothesis, row) of their own grids."""

    @classmethod
    def frame_bounds(cls, models: Sequence[DensityModel], sds: float) -> np.ndarray:
        """World boxes ``(x0, x1, y0, y1)``, shape ``(H, 4)``, each holding its hypothesis to
        ``sds`` standard deviations."""

    @classmethod
    def batch_binding(cls, ctx: KernelContext, models: Sequence[DensityModel]) -> KernelBinding:
        """The family's kernels with a device array of the hypotheses' parameter structs
        (:meth:`KernelContext.structs`): the engine launches their batch kernels."""


@runtime_checkable
class PresenceModel(Protocol):
    """A presence law in the array frame (x, y horizontal, z up; Pessentheiner): a density in
    1, 2 or 3 dimensions whose cells are those of an angular lattice, conditioned on a region.

    It shares :class:`DensityModel`'s face where the two meet (``kind``, ``scene``,
    ``float32_rtol``, ``parameters``, ``pdf``, ``sample``, ``cell_plan``); its cells come from
    the law's own plan (:meth:`cell_plan`), which :func:`bananagrid.rasterise` runs for an
    :class:`~bananagrid.AngularLattice`.
    """

    kind: ClassVar[str]
    scene: ClassVar[SceneSchema]
    float32_rtol: ClassVar[float]

    @property
    def dim(self) -> int:
        """Its dimension D: 1 (a line), 2 (a plane) or 3 (a room)."""

    def parameters(self) -> dict:
        """Plain-data parameters for provenance and recordings (``{"model": NAME, ...}``)."""

    def pdf(self, x, y=None, z=None, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
        """Density per m^D at points (``x``, ``y``, ``z`` broadcast, as many as D; ``pdf(x, y)``
        of a 3-D law is its (x, y) marginal per m^2)."""

    def sample(self, n: int, rng) -> np.ndarray:
        """``n`` positions from the law, shape ``(n, D)``."""

    def region_probability(self, region) -> float:
        """p(S): the law's probability of the box ``region`` (a :class:`~bananagrid.Region`)."""

    def cell_plan(self, domain, region=None) -> CellPlan:
        """The law's plan for p(C | S) of every cell of ``domain`` (an
        :class:`~bananagrid.AngularLattice`), conditioned on ``region`` (None: the whole space),
        whose ``run(ctx)`` gives the :class:`~bananagrid.CellMap`; any other domain raises
        :class:`~bananagrid.BananagridError` in one line saying where the law's cells are."""

    @classmethod
    def scene_table(cls, table, *, path: str, lattice, room) -> tuple[dict, tuple]:
        """``(parameters, part names)`` from a scene's presence table ``table`` (whose ``kind``
        names this law; ``path``: its key path) on ``lattice``, the scene's room ``room`` (a
        :class:`~bananagrid.Region` or None): how the law's scene is written, so that the
        parser names no kind. Raises :class:`~bananagrid.BananagridError` naming the key."""


@dataclass(frozen=True, eq=False)
class EvidencePack:
    """Evidence at times before a map's, as the flat arrays the kernels read (built and
    validated by :func:`bananagrid.evidence.packing.pack`; what each column means:
    ``bananagrid/kernels/evidence.py``). Float arrays are float64 here; the engine casts them
    to the kernels' dtype (:func:`bananagrid.engine.carried.evidence_struct`).

    Attributes
    ----------
    t : float
        The map's time (s since the last fix); every node is at or before it.
    time, q : ndarray (N,)
        Node times (sorted) and quadrature weights.
    data : ndarray (N, DATA_COLUMNS)
        Each node's numbers (its kind's: polygon value and box, report mean and precision, ...).
    ints : ndarray (N, INT_COLUMNS), int32
        Each node's kind, factor, offset and count.
    edges : ndarray (E, 4)
        Polygon edges (x0, y0, x1, y1), world metres (at least one row).
    raster : ndarray (R,)
        Raster values (at least one).
    channels : ndarray (C, F), int32
        1 where factor k is in channel c (the channels' weights multiply their factors').
    channel_names : tuple of str
        ``"prior"`` (no factor), ``"all"``, ``"searches"``, ``"others"`` (reports),
        ``"search:K"`` (search K with the reports), K as in ``factor_keys``.
    factor_keys : tuple of str
        The evidence each factor comes from (``"evidence[K]"``), in factor order.
    factor_kinds : tuple of str
        ``"search"`` or ``"report"`` for each factor.
    slots : int
        Scratch values per path beyond the factors' log-weights (a definite-range track's chain
        keeps the path's previous position in two); :attr:`scratch` is the row's width.
    """

    t: float
    time: np.ndarray
    q: np.ndarray
    data: np.ndarray
    ints: np.ndarray
    edges: np.ndarray
    raster: np.ndarray
    channels: np.ndarray
    channel_names: tuple
    factor_keys: tuple
    factor_kinds: tuple
    slots: int = 0

    @property
    def nodes(self) -> int:
        return len(self.time)

    @property
    def scratch(self) -> int:
        """Width of a path's scratch row ``lw``: the factors, then the slots (at least 1)."""
        return max(self.factors + self.slots, 1)

    @property
    def factors(self) -> int:
        return self.channels.shape[1]

    def channel(self, name: str) -> int:
        """Index of the channel ``name``."""
        return self.channel_names.index(name)


@runtime_checkable
class CarryingModel(Protocol):
    """A model whose kernels carry earlier evidence along its paths (CAT, Butterly): the hook
    by which :func:`bananagrid.posterior` gets maps weighted by evidence at times before the
    model's ``t``.

    The engine (:func:`bananagrid.engine.carried.evaluate_carried`) calls :meth:`bind_carried`
    and launches the binding's ``kernels.points`` as

        ``points(xs, ys, start, p, ev, lw, out)`` over a chunk of points from ``start``:
        ``p`` the binding's params, ``ev`` the pack's struct (``kernels/evidence.py``'s
        ``EVIDENCE``), ``lw`` a scratch array (points, ``pack.scratch``): the factors'
        log-weights, then the pack's slots,
        ``out`` (points, C) the channels, zeroed by the kernel for each of its points before it
        adds, per path through the point, density(path) x weight_c(path) with
        ``evidence_reset`` / ``evidence_node`` / ``evidence_add`` (``kernels/evidence.py``).

    So a family writes one ``@wp.kernel`` of that signature (its own paths, the shared weight
    helpers; :func:`bananagrid.kernels.generate.carried_points_kernel` writes it around a
    ``@wp.func carried(x, y, p, ev, lw, out)``) and overloads it for both scalars.

    Optional: ``carried_cell_plan(domain, pack) -> CellPlan | None``, a model's own rule for the
    cells' channel masses (the CAT's lines exact in the acceleration, Butterly's cells):
    ``run(ctx)`` returns ``(cells, notes)``, cells float64 of shape ``(C, ny, nx)`` (channel c's
    weighted probability of each cell, unnormalised). :func:`bananagrid.posterior` uses it where
    a model has it (None: the sub-cell rule on :meth:`bind_carried`'s densities), passing the
    prior's cell probabilities as ``prior_cells`` where the method takes that keyword.
    """

    def bind_carried(self, ctx: KernelContext, extent: Extent, pack: EvidencePack) -> KernelBinding:
        """The carried points kernel (above) and its parameters, for points within ``extent``."""
