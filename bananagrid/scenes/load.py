"""Scene files: parse a TOML scene, validate every key once, and build grids and models.

A scene names its domain, its model layers and how to record them; see ``docs/scenes.md``
for the schema. The domain is a ``[grid]`` (one or more ``[layers]`` of planar densities) or an
``[array]`` (the angular cells of a ceiling array, whose one layer is the ``[presence]`` law
conditioned on the ``[room]``, :mod:`bananagrid.scenes.presence`); both give one
:class:`Scene`, run by :func:`bananagrid.scenes.run.run_scene`.

:func:`load_scene` and :func:`parse_scene` raise :class:`BananagridError` with one line that
names the file, the key path (``layers.exact.sigma_a``), the value given and what is allowed;
nothing downstream has to check a scene again. The model kinds and their keys come from the
installed model kinds (:func:`bananagrid.models.registry.installed_kinds`: this package's and
those other packages register by entry point); pass ``kinds=`` to parse scenes with models of
your own.
"""

from __future__ import annotations

import math
import os
import re
import tomllib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType

from ..analysis.coverage import DEFAULT_MIN_MASS, min_mass
from ..contours import DEFAULT_MASS_LEVELS, mass_levels
from ..domains.angular_lattice import AngularLattice
from ..domains.grid import Grid
from ..domains.region import Region
from ..engine.carried import carries
from ..evidence.posterior import NO_PATHS
from ..geo.frame import DEFAULT_MAX_SCALE_ERROR, GeoFrame
from ..geo.inputs import PASS_MMSI, read_bearings, read_track
from ..models.registry import MODEL_KINDS, ModelKind, Registry, installed_kinds
from ..planning.detection import LAWS
from ..planning.periods import TOL
from ..planning.rectangles import MAX_RECTANGLES
from ..planning.regions import MAX_BANDS
from ..protocol import DensityModel
from ..recording.core import MAX_ELAPSED_S, colormaps
from ..validate import DEGREES_MEANT, BananagridError, BananagridWarning, positive
from . import keys
from .evidence import parse_evidence
from .keys import DTYPES, NAME_PATTERN, SceneKeyError, check_keys, show
from .presence import LAYER_NAME, array_scene_fields

__all__ = [
    "Layer", "Scene", "RadialOutput", "PlanSpec", "load_scene", "parse_scene", "MODEL_KINDS", "PARAMETER_KEYS",
    "TOP_KEYS", "RADIAL_KEYS", "SCENE_KEYS", "GRID_KEYS", "OUTPUT_KEYS", "GEO_KEYS", "PLAN_KEYS", "PLAN_TABLE",
    "SEVERAL_PERIODS",
]

#: Scene keys of every registered model kind of grid layers.
PARAMETER_KEYS = MappingProxyType({kind: spec.scene.key_names for kind, spec in MODEL_KINDS.on("grid").items()})

TOP_KEYS = ("scene", "grid", "geo", "output", "defaults", "layers", "radial", "plan", "evidence")
GEO_KEYS = ("origin_latlon", "time", "crs", "max_scale_error", "fix_file", "fix_mmsi", "bearings_file")
#: What a ``[geo] fix_file``'s last fix gives a layer that sets neither the parameter nor its
#: ``[defaults]``: the motion models' initial heading (its course over ground, true) and speed.
FIX_PARAMETERS = {"heading": "course", "v0": "speed"}
#: What a ``[geo] bearings_file`` gives a layer (a bearing fix's stations, bearings and errors).
BEARING_PARAMETERS = ("sensors", "bearings", "sigmas")
RADIAL_KEYS = ("layers", "density_bearings_deg", "moments_max_deg", "moments_step_deg")
SCENE_KEYS = ("name", "title", "description", "times")
GRID_KEYS = ("x", "y", "step", "dx", "dy")
#: Keys of ``[output]`` that every scene takes; a model kind may add switches of its own
#: (:attr:`~bananagrid.protocol.SceneSchema.options`, e.g. the bearing fix's ``bearing_validation``).
OUTPUT_KEYS = ("mass_levels", "contour_levels", "min_mass", "normalise", "dtype", "colormap", "cell_probabilities")
#: ``[plan]``: where to look next on one layer's map at one time, ``(key, type, unit, default,
#: allowed)`` each; ``docs/scenes.md`` is generated from it (:mod:`bananagrid.scenes.docs`).
PLAN_TABLE = (
    ("effort", "number or list", "m^2", "required (or `effort_km2`)",
     "finite and > 0: the effort of one period, sweep width times track length; a list: one per period "
     "(with `t` a list as long), a moving target's plan over the periods (cat and butterly layers)"),
    ("effort_km2", "number or list", "km^2", "instead of `effort`", "as `effort`, in km^2"),
    ("sweep_width", "number", "m", "required with `rectangles` or `bands`",
     "finite and > 0: the sensor's sweep width W; an area's track spacing is W / its coverage"),
    ("law", "string", "", '`"exponential"`', ", ".join(f'`"{name}"`' for name in LAWS)
     + ": the detection law of the coverage (random search, parallel sweeps under the inverse-cube law, definite range)"),
    ("rectangles", "integer", "", "`0` (none)", f"0 to {MAX_RECTANGLES}: rectangles a crew can fly, any orientation"),
    ("bands", "integer", "", "`0` (none)", f"0 to {MAX_BANDS}: bands of cells by coverage, each at one track spacing"),
    ("t", "number or list", "s", "the scene's last time",
     "a time of the scene's timeline (`scene.times`, or the layer's `t`); a list: each period's, increasing"),
    ("layer", "string", "", "the first layer", "the name of a layer of the scene"),
    ("tol", "number", "", "`1e-9`", "several periods only: finite and > 0, the iteration stops when a sweep over the "
     "periods raises the total POS by less than this"),
)
PLAN_KEYS = tuple(row[0] for row in PLAN_TABLE)
#: Why a plan over several periods is refused after ``[[evidence]]``.
SEVERAL_PERIODS = ("a plan over several periods starts from the layer's prior (the searches already flown are not yet "
                   "carried into it); drop the [[evidence]] or give one effort and one t")


@dataclass(frozen=True)
class Layer:
    """One model layer of a scene, validated.

    Attributes
    ----------
    name : str
        Layer name (the table name under ``[layers]``); its entity is ``layers/NAME``.
    kind : str
        Its model kind, a key of the registry (``"cat"``, ``"polar"``, ``"bearing_fix"``,
        ``"butterly"``, or one of your own).
    params : Mapping
        Model parameters in SI units (m, s, m/s) and radians, ``[defaults]`` merged in, under
        their scene names without ``_deg`` / ``_kn`` (``t`` absent when the scene has
        ``times``).
    model_kind : ModelKind, optional
        The registry entry of ``kind`` (default: looked up in the installed kinds,
        :func:`~bananagrid.models.registry.installed_kinds`).
    """

    name: str
    kind: str
    params: Mapping = field(default_factory=dict)
    model_kind: ModelKind | None = None

    def __post_init__(self):
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        if self.model_kind is None:
            object.__setattr__(self, "model_kind", installed_kinds()[self.kind])

    def model(self, t: float | None = None) -> DensityModel:
        """The layer's model at elapsed time ``t`` (s); by default the layer's own ``t``.
        A model that does not change with time (a bearing fix) ignores ``t``.

        Raises
        ------
        BananagridError
            If no ``t`` is known, or a parameter is out of its domain.
        """
        kwargs = dict(self.params)
        if self.model_kind.scene.timed:
            if t is not None:
                kwargs["t"] = t
            if "t" not in kwargs:
                raise BananagridError(f"layer {self.name}: no elapsed time t; pass model(t=...)")
        with warnings.catch_warnings():
            # the scene says so once, naming the key and its _deg form (_radian_doubts)
            warnings.filterwarnings("ignore", message=".*" + re.escape(DEGREES_MEANT), category=BananagridWarning)
            return self.model_kind.build(kwargs)


@dataclass(frozen=True)
class RadialOutput:
    """``[radial]``: the conditional radial curves of Figures 2-5 and 8 of the polar-banana
    paper, for some motion layers (see :mod:`bananagrid.recording.radial`).

    Attributes
    ----------
    layers : tuple of str
        Names of the cat or polar layers that get curves.
    density_bearings : tuple of float
        Bearings (rad) at which p(r | theta) is drawn, exact beside its normal approximations.
    moments_max : float
        E[r | theta] and SD[r | theta] are drawn for theta in [0, moments_max] (rad); 0 for none.
    moments_step : float
        Bearing step of those curves (rad).
    """

    layers: tuple
    density_bearings: tuple = ()
    moments_max: float = 0.0
    moments_step: float = math.radians(2.0)


@dataclass(frozen=True)
class PlanSpec:
    """``[plan]``: search effort spread over one layer's cell probabilities at one time, and the
    areas a crew can fly (:func:`bananagrid.allocate`, :func:`bananagrid.search_rectangles`,
    :func:`bananagrid.search_regions`); or, with several periods, a moving target's plan over
    them (:func:`bananagrid.plan_periods`), each period's areas from its own allocation.

    Attributes
    ----------
    layer : str
        The layer whose map is searched.
    t : float
        Its time, s (a time of the scene's timeline); with several periods, the last one's.
    effort : float
        Total effort of the period, m^2 (sweep width times track length); with several
        periods, their sum.
    law : str
        The detection law's name.
    sweep_width : float or None
        W, m (None when no areas are asked for).
    rectangles, bands : int
        How many rectangles and bands (0 for none; per period).
    times, efforts : tuple of float
        Several periods: each one's time (increasing, on the timeline) and effort (m^2); empty
        for one period.
    tol : float
        Several periods: the iteration's convergence (:func:`bananagrid.plan_periods`'s ``tol``).
    """

    layer: str
    t: float
    effort: float
    law: str = "exponential"
    sweep_width: float | None = None
    rectangles: int = 0
    bands: int = 0
    times: tuple = ()
    efforts: tuple = ()
    tol: float = TOL

    @property
    def areas(self) -> bool:
        """Whether the plan has areas a crew can fly (rectangles or bands)."""
        return self.rectangles > 0 or self.bands > 0

    @property
    def several(self) -> bool:
        """Whether the plan is over several periods (:func:`bananagrid.plan_periods`)."""
        return len(self.times) > 1

    @property
    def periods(self) -> tuple:
        """``(t, effort)`` of each period (one for a one-period plan)."""
        return tuple(zip(self.times, self.efforts)) if self.several else ((self.t, self.effort),)


@dataclass(frozen=True)
class Scene:
    """A validated scene: a domain (a grid, or an array's angular lattice), model layers and
    recording options.

    A ``[grid]`` scene has model layers (``[layers]``) computed on its grid; an ``[array]``
    scene has one layer, its ``[presence]`` law, computed on the lattice's cells conditioned on
    its ``[room]`` (:mod:`bananagrid.scenes.presence`). Both run through
    :func:`bananagrid.scenes.run.run_scene`.

    Attributes
    ----------
    name : str
        Scene name, ``[A-Za-z0-9_-]+``; the output files are ``NAME.rrd`` and ``NAME.npz``.
    title, description : str
        Free text (title defaults to the name, description to "").
    text : str
        The scene file as written (logged into the recording).
    source : str
        Where the text came from (file path or ``"<string>"``), used in messages.
    domain : Grid or AngularLattice
        Where every layer is computed (:attr:`grid` for a grid scene).
    bounds : ((float, float), (float, float)) or None
        The ``x`` and ``y`` bounds as written, m; :meth:`with_step` rebuilds the grid from them
        (None for an array scene).
    layers : tuple of Layer
        In file order.
    times : tuple of float or None
        Elapsed times, s, strictly increasing; every layer is computed at each. None when the
        layers give their own ``t``.
    levels : tuple of float
        Fixed contour levels, density per m^2 (empty unless the scene gives ``contour_levels``).
    normalise : bool
        Whether rasters are normalised over the grid before they are recorded.
    dtype : str
        Kernel precision, ``"float64"`` or ``"float32"``.
    colormap : str
        rerun colormap of the density images (lower case).
    options : Mapping
        The ``[output]`` switches that model kinds add (:attr:`SceneSchema.options`), by name,
        as given (e.g. ``bearing_validation``: the Walsh linearisation validation table).
    kinds : Registry
        The model kinds the scene was parsed with (their recording hooks act on ``options``).
    radial : RadialOutput or None
        The conditional radial curves to record, if the scene asks for them (``[radial]``).
    mass_levels : tuple of float
        Probability-mass levels in (0, 1) whose highest-density regions are drawn and reported.
    min_mass : float
        Captured mass below which a layer warns that the grid misses the target (0: never).
    warnings : tuple of str
        Likely mistakes found while loading (e.g. an angle that looks like degrees given in
        radians); each was also issued as a :class:`~bananagrid.BananagridWarning`.
    geo : GeoFrame or None
        The geographic frame (``[geo]``): where the local origin is on the Earth, the UTC time
        of t = 0 and the projection; None for a scene in local metres only.
    scale_error : float
        The projection's largest relative scale error over the grid (0 without ``[geo]``).
    cell_probabilities : bool
        Whether every layer's cell probabilities are computed too (``output.cell_probabilities``:
        recorded, exported to the .npz, and the source of the captured mass).
    region : Region or None
        An array scene's S: the room's ranges on the law's axes, on which its cells are
        conditioned; None without ``[room]`` (and for a grid scene).
    room_z : (float, float) or None
        An array scene's room z range as written (drawn; part of S for the frustum only).
    component_names : tuple of str
        An array scene's mixture component names in file order (empty otherwise).
    far : float or None
        m: where an array scene's cells are cut in the drawing when there is no room (default 10 h).
    log10_floor : float
        Bottom of an array scene's recorded colour scale, log10 of a probability.
    plan : PlanSpec or None
        Where to look next (``[plan]``); None without it.
    evidence : tuple of EvidenceSpec
        Searches that found nothing, reports and land (``[[evidence]]``,
        :mod:`bananagrid.scenes.evidence`); each map takes those that began by its time, and
        the run computes its posterior (:func:`bananagrid.posterior`).
    """

    name: str
    title: str
    description: str
    text: str
    source: str
    domain: Grid | AngularLattice
    bounds: tuple | None
    layers: tuple
    times: tuple | None
    levels: tuple
    normalise: bool
    dtype: str
    colormap: str
    options: Mapping = field(default_factory=dict)
    kinds: Registry = MODEL_KINDS
    radial: RadialOutput | None = None
    mass_levels: tuple = DEFAULT_MASS_LEVELS
    min_mass: float = DEFAULT_MIN_MASS
    warnings: tuple = ()
    geo: GeoFrame | None = None
    scale_error: float = 0.0
    cell_probabilities: bool = False
    region: Region | None = None
    room_z: tuple | None = None
    component_names: tuple = ()
    far: float | None = None
    log10_floor: float = -12.0
    plan: PlanSpec | None = None
    evidence: tuple = ()

    @property
    def gridded(self) -> bool:
        """Whether the scene's domain is a grid (an ``[array]`` scene's is an angular lattice)."""
        return isinstance(self.domain, Grid)

    @property
    def grid(self) -> Grid:
        """The grid of a ``[grid]`` scene.

        Raises
        ------
        BananagridError
            For an ``[array]`` scene: commands that need a grid say so in one line.
        """
        if not self.gridded:
            raise BananagridError(
                f"{self.source}: a presence scene ([array]) has no grid layers; only `bananagrid run` takes it"
            )
        return self.domain

    def with_step(self, step: float, *, tiled: bool = False) -> "Scene":
        """A copy whose grid covers the same bounds with square cells of ``step`` metres (larger
        than memory takes only when ``tiled``). ``--step`` sets grid cells in metres: an array
        scene (an angular lattice, no grid) is returned unchanged, with a warning."""
        if not self.gridded:
            warnings.warn(
                f"{self.source}: --step {step:g} does not apply to a presence scene (angular lattice, "
                "no grid); it runs at its own array steps", BananagridWarning, stacklevel=2,
            )
            return self
        step = positive("step", step)
        x, y = self.bounds
        try:
            grid = Grid.from_bounds(x=x, y=y, step=step)
            if not tiled:
                grid.check_in_memory()
        except BananagridError as exc:
            raise BananagridError(f"{self.source}: grid at step {step:g} m: {exc}") from None
        return replace(self, domain=grid)

    def jobs(self) -> list[tuple[Layer, float]]:
        """Every (layer, elapsed time) to compute, time-major when the scene has times. A
        bearing fix, timeless, is logged at t = 0 unless the scene has times."""
        if self.times is None:
            return [(layer, layer.params.get("t", 0.0)) for layer in self.layers]
        return [(layer, t) for t in self.times for layer in self.layers]


# --- entry points -----------------------------------------------------------------------------


def load_scene(path: str | os.PathLike, *, kinds: Registry | None = None, tiled: bool = False) -> Scene:
    """Read and validate the scene file at ``path`` (``kinds`` and ``tiled`` as for :func:`parse_scene`).

    Raises
    ------
    BananagridError
        If the file cannot be read, is not UTF-8 TOML, or breaks the schema.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise BananagridError(f"{path}: no such scene file") from None
    except IsADirectoryError:
        raise BananagridError(f"{path}: is a directory, expected a scene .toml file") from None
    except OSError as exc:
        raise BananagridError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BananagridError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    return parse_scene(text, source=str(path), kinds=kinds, tiled=tiled, directory=path.parent)


def parse_scene(text: str, source: str = "<string>", *, kinds: Registry | None = None,
                tiled: bool = False, directory: str | os.PathLike | None = None) -> Scene:
    """Parse and validate scene TOML ``text``; ``source`` names it in error messages.

    ``directory``: where the files a scene names (``[geo] fix_file``, ``bearings_file``) are
    found when their paths are relative (default: the current directory; :func:`load_scene`
    passes the scene file's own).

    ``tiled``: the scene will be computed in tiles (``bananagrid run --zarr``), so its grid may
    exceed :data:`~bananagrid.domains.grid.MAX_CELLS` (up to ``MAX_TILED_CELLS``).

    ``kinds``: the model kinds layers may use (default: the installed ones, this package's and
    those other packages register by entry point, :func:`~bananagrid.models.registry.installed_kinds`;
    ``MODEL_KINDS.with_kinds(ModelKind("mine", Mine))`` adds a model of your own).
    """
    kinds = installed_kinds() if kinds is None else kinds
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BananagridError(f"{source}: invalid TOML: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays recursively
        raise BananagridError(f"{source}: invalid TOML: arrays or tables nested too deeply") from None
    try:
        if "array" in doc:  # the [array] domain instead of [grid]: bananagrid.scenes.presence
            return _build_array(doc, text, source, kinds)
        return _build(doc, text, source, kinds, tiled, Path.cwd() if directory is None else Path(directory))
    except SceneKeyError as exc:
        raise BananagridError(f"{source}: {exc}") from None


# --- building the scene -----------------------------------------------------------------------


def _build_array(doc: dict, text: str, source: str, kinds: Registry) -> Scene:
    """An ``[array]`` scene: the lattice as the domain and the ``[presence]`` law as the one layer."""
    fields = array_scene_fields(doc, kinds)
    kind, params = fields.pop("layer")
    layer = Layer(name=LAYER_NAME, kind=kind, params=params, model_kind=kinds[kind])
    return Scene(text=text, source=source, bounds=None, layers=(layer,), times=None, levels=(), normalise=False,
                 colormap="viridis", **fields)


def _build(doc: dict, text: str, source: str, kinds: Registry, tiled: bool = False,
           directory: Path | None = None) -> Scene:
    """Validate the parsed document table by table and assemble the Scene."""
    check_keys(doc, TOP_KEYS, "")
    geo, max_scale_error, supplied = (_geo(keys.table(doc, "geo"), directory or Path.cwd()) if "geo" in doc
                                      else (None, 0.0, {}))
    head = keys.table(doc, "scene", required=True)
    check_keys(head, SCENE_KEYS, "scene")
    name = keys.name(head.get("name"), "scene.name", required=True)
    title = keys.text(head, "title", "scene", default=name)
    description = keys.text(head, "description", "scene", default="")
    times = _times(head["times"]) if "times" in head else None
    bounds, grid = _grid(keys.table(doc, "grid", required=True), tiled)
    scale_error = 0.0
    if geo is not None:
        try:  # the CRS's round trip over the grid, then its scale error
            x0, x1, y0, y1 = grid.extent
            scale_error = geo.check_extent((x0, x1), (y0, y1), max_scale_error)
        except BananagridError as exc:
            raise SceneKeyError(_geo_message(str(exc), "")) from None
    output = _output(keys.table(doc, "output"), kinds)
    defaults = keys.table(doc, "defaults")
    scene_kinds = kinds
    kinds = kinds.on("grid")  # the kinds of [layers]; an [array] scene's law is in [presence]
    every_key = tuple(dict.fromkeys(k for kind in kinds.values() for k in kind.scene.key_names))
    check_keys(defaults, every_key, "defaults")
    if times is not None and "t" in defaults:
        raise SceneKeyError(
            f"defaults.t = {show(defaults['t'])}: not allowed when scene.times is given "
            "(every layer is computed at every time)"
        )
    shared = keys.parameters(defaults, "defaults", keys.merged_keys(kind.scene.keys for kind in kinds.values()), geo)
    found: list[str] = []
    layers = _layers(keys.table(doc, "layers", required=True), shared, times, kinds, found, geo, supplied)
    if any(where.startswith("geo.bearings_file") for where, _, _ in supplied.values()) and not any(
            all(p in layer.model_kind.scene.key_names for p in BEARING_PARAMETERS) for layer in layers):
        raise SceneKeyError("geo.bearings_file: no layer takes bearings (sensors, bearings, sigmas: model "
                            "\"bearing_fix\"); drop the key or add such a layer")
    radial = _radial(doc["radial"], layers) if "radial" in doc else None
    plan = _plan(doc["plan"], layers, times) if "plan" in doc else None
    timeline = times or tuple(layer.params.get("t", 0.0) for layer in layers)
    evidence = (parse_evidence(doc["evidence"], timeline, geo, directory or Path.cwd()) if "evidence" in doc
                else ())
    if plan is not None and plan.several and evidence:
        raise SceneKeyError(f"plan.t = {show(list(plan.times))}: {SEVERAL_PERIODS}")
    if geo is not None:  # every UTC time of the scene inside the calendar
        try:
            geo.check_elapsed(times or [layer.params.get("t", 0.0) for layer in layers])
        except BananagridError as exc:
            raise SceneKeyError(_geo_message(str(exc), "")) from None
    for message in found:
        warnings.warn(f"{source}: {message}", BananagridWarning, stacklevel=3)
    return Scene(
        name=name, title=title, description=description, text=text, source=source,
        domain=grid, bounds=bounds, layers=layers, times=times, radial=radial, warnings=tuple(found), **output,
        geo=geo, scale_error=scale_error, kinds=scene_kinds, plan=plan, evidence=evidence,
    )


def _plan(value, layers, times) -> PlanSpec:
    """``[plan]``: one period's effort on one layer's map at one time of the timeline, or one
    effort per period at increasing times of it (a CAT or Butterly layer's moving-target plan),
    the detection law, the sweep width and how many rectangles and bands."""
    table = keys.table({"plan": value}, "plan")
    check_keys(table, PLAN_KEYS, "plan")
    if "effort" in table and "effort_km2" in table:
        raise SceneKeyError(f"plan: give effort (m^2) or effort_km2 (km^2), not both (effort = {show(table['effort'])}, "
                            f"effort_km2 = {show(table['effort_km2'])})")
    if "effort" not in table and "effort_km2" not in table:
        raise SceneKeyError("plan.effort: missing; expected the effort of the period in m^2 (or effort_km2 in km^2), "
                            "sweep width times track length")
    key = "effort" if "effort" in table else "effort_km2"
    several = isinstance(table[key], list) or isinstance(table.get("t"), list)
    efforts = [_plan_effort(v, f"plan.{key}[{k}]" if isinstance(table[key], list) else f"plan.{key}", key)
               for k, v in enumerate(table[key] if isinstance(table[key], list) else [table[key]])]
    law = table.get("law", "exponential")
    if not isinstance(law, str) or law not in LAWS:
        raise SceneKeyError(f"plan.law = {show(law)}: must be one of {', '.join(map(show, LAWS))}")
    counts = {}
    for name, top in (("rectangles", MAX_RECTANGLES), ("bands", MAX_BANDS)):
        count = table.get(name, 0)
        if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count <= top:
            raise SceneKeyError(f"plan.{name} = {show(count)}: expected an integer from 0 (none) to {top}")
        counts[name] = count
    width = None
    if "sweep_width" in table:
        width = keys.number(table["sweep_width"], "plan.sweep_width")
        if not (math.isfinite(width) and width > 0.0):
            raise SceneKeyError(f"plan.sweep_width = {show(table['sweep_width'])}: must be finite and > 0 (m)")
    elif counts["rectangles"] or counts["bands"]:
        raise SceneKeyError("plan.sweep_width: missing; the rectangles and bands are flown at track spacings "
                            "of the sweep width (m)")
    names = [layer.name for layer in layers]
    name = table.get("layer", names[0])
    if name not in names:
        raise SceneKeyError(f"plan.layer = {show(name)}: not a layer of this scene (those are: "
                            f"{', '.join(map(show, names))})")
    layer = layers[names.index(name)]
    timeline = times if times is not None else (layer.params.get("t", 0.0),)
    where = "scene.times" if times is not None else f"layers.{name}.t"
    if not several:
        if "t" in table:
            t = keys.number(table["t"], "plan.t")
            if t not in timeline:
                raise SceneKeyError(f"plan.t = {show(table['t'])}: not a time of the scene's timeline ({where}: "
                                    f"{', '.join(f'{v:g}' for v in timeline)} s)")
        else:
            t = max(timeline)
        if "tol" in table:
            raise SceneKeyError(f"plan.tol = {show(table['tol'])}: only for a plan over several periods (t and effort "
                                "as lists); one period's allocation is exact")
        return PlanSpec(layer=name, t=float(t), effort=efforts[0], law=law, sweep_width=width, **counts)
    if "t" not in table:
        raise SceneKeyError(f"plan.t: missing; {len(efforts)} efforts (plan.{key}) need a list of as many increasing "
                            "times of the scene's timeline (one per period)")
    if not isinstance(table["t"], list):
        raise SceneKeyError(f"plan.t = {show(table['t'])}: {len(efforts)} efforts (plan.{key}) need a list of as many "
                            "increasing times of the scene's timeline (one per period)")
    if not isinstance(table[key], list):
        raise SceneKeyError(f"plan.{key} = {show(table[key])}: {len(table['t'])} times (plan.t) need a list of as "
                            "many efforts (one per period)")
    if len(table["t"]) != len(efforts):
        raise SceneKeyError(f"plan.t: {len(table['t'])} times for {len(efforts)} efforts (plan.{key}); expected one "
                            "time per period")
    plan_times = []
    for k, item in enumerate(table["t"]):
        t = keys.number(item, f"plan.t[{k}]")
        if t not in timeline:
            raise SceneKeyError(f"plan.t[{k}] = {show(item)}: not a time of the scene's timeline ({where}: "
                                f"{', '.join(f'{v:g}' for v in timeline)} s)")
        if plan_times and not t > plan_times[-1]:
            raise SceneKeyError(f"plan.t[{k}] = {show(item)}: not after plan.t[{k - 1}] = {plan_times[-1]:g}; the "
                                "periods' times must increase")
        plan_times.append(t)
    tol = TOL
    if "tol" in table:
        tol = keys.number(table["tol"], "plan.tol")
        if not (math.isfinite(tol) and tol > 0.0):
            raise SceneKeyError(f"plan.tol = {show(table['tol'])}: must be finite and > 0 (a change of POS)")
    if len(plan_times) == 1:  # a list of one period: the one-period plan
        return PlanSpec(layer=name, t=plan_times[0], effort=efforts[0], law=law, sweep_width=width, **counts)
    if layer.kind in NO_PATHS:
        raise SceneKeyError(f"plan.layer = {show(name)}: a {layer.kind} layer, an approximation with no path per "
                            f"parameter, so the periods' searches cannot be carried between their times; use "
                            f"{NO_PATHS[layer.kind]} (model = \"cat\")")
    if not carries(layer.model(plan_times[0])):
        raise SceneKeyError(f"plan.layer = {show(name)}: a {layer.kind} layer; plans over several periods need a "
                            "motion model whose paths carry the searches (a cat or butterly layer)")
    return PlanSpec(layer=name, t=plan_times[-1], effort=math.fsum(efforts), law=law, sweep_width=width, **counts,
                    times=tuple(plan_times), efforts=tuple(efforts), tol=tol)


def _plan_effort(value, path: str, key: str) -> float:
    """One period's effort in m^2 from ``plan.effort`` (m^2) or ``plan.effort_km2`` (km^2)."""
    effort = keys.number(value, path)
    if not (math.isfinite(effort) and effort > 0.0):
        raise SceneKeyError(f"{path} = {show(value)}: must be finite and > 0 ({'m^2' if key == 'effort' else 'km^2'})")
    effort = effort if key == "effort" else effort * 1.0e6
    if not math.isfinite(effort):  # a finite km^2 beyond the largest float in m^2
        raise SceneKeyError(f"{path} = {show(value)}: too large (not finite in m^2)")
    return effort


def _radial(value, layers) -> RadialOutput:
    """``[radial]``: which motion layers get radial curves, at which bearings (degrees)."""
    table = keys.table({"radial": value}, "radial")
    check_keys(table, RADIAL_KEYS, "radial")
    motion = [layer.name for layer in layers if layer.model_kind.scene.radial_curves]  # models with a pose
    names = table.get("layers", motion)
    if not isinstance(names, list) or not names:
        raise SceneKeyError(f"radial.layers = {show(names)}: expected a non-empty list of cat or polar layer names")
    for k, name in enumerate(names):
        if name not in motion:
            raise SceneKeyError(
                f"radial.layers[{k}] = {show(name)}: not a cat or polar layer of this scene "
                f"(those are: {', '.join(map(show, motion)) or 'none'})"
            )
    bearings = ()
    if "density_bearings_deg" in table:
        bearings = tuple(keys.numbers(table["density_bearings_deg"], "radial.density_bearings_deg"))
        for k, b in enumerate(bearings):
            if not (math.isfinite(b) and -180.0 < b <= 180.0):
                raise SceneKeyError(
                    f"radial.density_bearings_deg[{k}] = {show(table['density_bearings_deg'][k])}: "
                    "must be in (-180, 180] degrees"
                )
    top = keys.number(table.get("moments_max_deg", 0.0), "radial.moments_max_deg")
    if not (0.0 <= top <= 180.0):
        raise SceneKeyError(f"radial.moments_max_deg = {show(table['moments_max_deg'])}: must be in [0, 180] degrees")
    step = keys.number(table.get("moments_step_deg", 2.0), "radial.moments_step_deg")
    if not (math.isfinite(step) and 0.0 < step <= 90.0):
        raise SceneKeyError(f"radial.moments_step_deg = {show(table['moments_step_deg'])}: must be in (0, 90] degrees")
    if not bearings and top == 0.0:
        raise SceneKeyError("radial: give density_bearings_deg or moments_max_deg (> 0), or drop [radial]")
    return RadialOutput(
        layers=tuple(names), density_bearings=tuple(math.radians(b) for b in bearings),
        moments_max=math.radians(top), moments_step=math.radians(step),
    )


#: Why an elapsed time cannot exceed MAX_ELAPSED_S.
TIMELINE_LIMIT = f"must be below {MAX_ELAPSED_S:.3g} s (292 years: the recording's timeline counts nanoseconds in 64 bits)"


def _times(value) -> tuple[float, ...]:
    """``scene.times``: a non-empty list of finite elapsed times > 0, strictly increasing."""
    path = "scene.times"
    if not isinstance(value, list) or not value:
        raise SceneKeyError(f"{path} = {show(value)}: expected a non-empty list of elapsed times in s")
    times = tuple(keys.number(v, f"{path}[{k}]") for k, v in enumerate(value))
    for k, t in enumerate(times):
        if not (math.isfinite(t) and t > 0.0):
            raise SceneKeyError(f"{path}[{k}] = {show(value[k])}: must be finite and > 0 (s)")
        if t >= MAX_ELAPSED_S:
            raise SceneKeyError(f"{path}[{k}] = {show(value[k])}: {TIMELINE_LIMIT}")
        if k and not t > times[k - 1]:
            raise SceneKeyError(
                f"{path} = {show(value)}: must be strictly increasing "
                f"({show(value[k - 1])} then {show(value[k])})"
            )
    return times


def _grid(table: dict, tiled: bool = False) -> tuple[tuple, Grid]:
    """``[grid]``: bounds ``x``, ``y`` and ``step`` (or ``dx`` and ``dy``), all metres; a grid
    larger than memory takes only when ``tiled``."""
    check_keys(table, GRID_KEYS, "grid")
    x = keys.pair(table, "x", "grid", required=True)
    y = keys.pair(table, "y", "grid", required=True)
    steps = {k: keys.number(table[k], f"grid.{k}") for k in ("step", "dx", "dy") if k in table}
    if "step" in steps and len(steps) > 1:
        raise SceneKeyError("grid: give either step or both dx and dy, not both")
    if "step" not in steps and len(steps) != 2:
        raise SceneKeyError("grid: step (m) is required (or both dx and dy)")
    try:
        grid = Grid.from_bounds(x=x, y=y, **steps)
        if not tiled:
            grid.check_in_memory()
        return (x, y), grid
    except BananagridError as exc:
        raise SceneKeyError(keys.prefixed(str(exc), "grid", GRID_KEYS)) from None


def _output(table: dict, kinds: Registry) -> dict:
    """``[output]``: contour levels (probability mass and fixed densities), the captured-mass
    threshold, normalisation, dtype, colormap, whether to compute cell probabilities, and the
    switches of ``kinds`` (:attr:`SceneSchema.options`), with defaults; as keyword arguments of
    :class:`Scene`."""
    switches = tuple(dict.fromkeys(name for kind in kinds.values() for name in kind.scene.options))
    check_keys(table, (*OUTPUT_KEYS, *switches), "output")
    levels: tuple = ()
    if "contour_levels" in table:
        value = table["contour_levels"]
        if not isinstance(value, list) or not value:
            raise SceneKeyError(
                f"output.contour_levels = {show(value)}: expected a non-empty list of densities (m^-2)"
            )
        levels = tuple(keys.number(v, f"output.contour_levels[{k}]") for k, v in enumerate(value))
        for k, level in enumerate(levels):
            if not (math.isfinite(level) and level > 0.0):
                raise SceneKeyError(
                    f"output.contour_levels[{k}] = {show(value[k])}: must be finite and > 0 (m^-2)"
                )
    probabilities = DEFAULT_MASS_LEVELS
    if "mass_levels" in table:
        value = table["mass_levels"]
        if not isinstance(value, list):
            raise SceneKeyError(f"output.mass_levels = {show(value)}: expected a list of probabilities in (0, 1)")
        try:
            probabilities = mass_levels(value, key="output.mass_levels")
        except BananagridError as exc:
            raise SceneKeyError(str(exc)) from None
    threshold = DEFAULT_MIN_MASS
    if "min_mass" in table:
        try:
            threshold = min_mass(table["min_mass"], key="output.min_mass")
        except BananagridError as exc:
            raise SceneKeyError(str(exc)) from None
    normalise = table.get("normalise", True)
    if not isinstance(normalise, bool):
        raise SceneKeyError(f"output.normalise = {show(normalise)}: expected true or false")
    dtype = table.get("dtype", "float64")
    if dtype not in DTYPES:
        raise SceneKeyError(f"output.dtype = {show(dtype)}: must be one of {', '.join(map(show, DTYPES))}")
    colormap = table.get("colormap", "viridis")
    allowed = _colormaps()
    if not isinstance(colormap, str) or colormap.lower() not in allowed:
        raise SceneKeyError(f"output.colormap = {show(colormap)}: must be one of {', '.join(allowed)}")
    options = {}
    for name in switches:
        value = table.get(name, False)
        if not isinstance(value, bool):
            raise SceneKeyError(f"output.{name} = {show(value)}: expected true or false")
        options[name] = value
    cells = table.get("cell_probabilities", False)
    if not isinstance(cells, bool):
        raise SceneKeyError(f"output.cell_probabilities = {show(cells)}: expected true or false")
    return {
        "levels": tuple(float(v) for v in levels), "mass_levels": probabilities, "min_mass": threshold,
        "normalise": normalise, "dtype": dtype, "colormap": colormap.lower(), "options": MappingProxyType(options),
        "cell_probabilities": cells,
    }


def _colormaps() -> tuple[str, ...]:
    """The colormap names rerun knows, in lower case."""
    return colormaps()


def _layers(tables: dict, shared: dict, times, kinds: Registry, found: list[str], geo=None,
            supplied: Mapping | None = None) -> tuple[Layer, ...]:
    """``[layers.NAME]`` tables in file order, each merged over ``[defaults]`` and checked.

    ``shared`` holds the ``[defaults]`` parameters as returned by :func:`keys.parameters`, and
    ``supplied`` those that ``[geo]``'s files give (below ``[defaults]``), in the same form;
    likely mistakes are appended to ``found``.
    """
    if not tables:
        raise SceneKeyError("layers: at least one [layers.NAME] table is required")
    layers = []
    for layer_name, body in tables.items():
        path = f"layers.{layer_name}"
        if not NAME_PATTERN.fullmatch(layer_name):
            raise SceneKeyError(f"layers.{show(layer_name)}: a layer name must be letters, digits, _ and -")
        if not isinstance(body, dict):
            raise SceneKeyError(f"{path} = {show(body)}: expected a table [layers.{layer_name}]")
        layers.append(_layer(layer_name, body, shared, times, kinds, found, geo, supplied))
    return tuple(layers)


def _layer(layer_name: str, body: dict, shared: dict, times, kinds: Registry, found: list[str], geo=None,
           supplied: Mapping | None = None) -> Layer:
    """Validate one layer: its keys, its values, and its model at every elapsed time; likely
    mistakes (:func:`_radian_doubts`) are appended to ``found``. In a geographic scene its
    bearings are true bearings, turned into grid bearings where they are measured."""
    path = f"layers.{layer_name}"
    kind_name = body.get("model")
    if isinstance(kind_name, str) and kind_name in kinds.broken:  # an entry point that failed to load
        raise SceneKeyError(f"{path}.model = {show(kind_name)}: {kinds.broken[kind_name]}")
    if not isinstance(kind_name, str) or kind_name not in kinds:
        shown = "missing" if kind_name is None else f"= {show(kind_name)}"
        raise SceneKeyError(f"{path}.model {shown}: must be one of {', '.join(map(show, kinds))}")
    kind = kinds[kind_name]
    schema = kind.scene
    allowed = schema.key_names
    check_keys(body, ("model", *allowed), path, note=f" (model {show(kind_name)})")
    if times is not None and "t" in body and schema.timed:
        raise SceneKeyError(
            f"{path}.t = {show(body['t'])}: not allowed when scene.times is given "
            "(every layer is computed at every time)"
        )
    # Where each parameter comes from: {param: (key path, value as written, value in SI)}.
    # Defaults of another model kind (k_sigma, variant) do not apply to this layer.
    own = {key.name: key for key in schema.keys}
    given = {p: v for p, v in (supplied or {}).items() if p in own and _takes_supplied(own, p, body, shared)}
    given.update({p: v for p, v in shared.items() if p in own})
    for param, (where, _, si) in list(given.items()):
        if si is None:  # a file that cannot give what the layer takes from it
            alias = f" (or {param}_{own[param].alias})" if own[param].alias else ""
            raise SceneKeyError(f"{path}: {param}: {where}; give {param}{alias} in [{path}] or [defaults]")
    given.update(keys.parameters({k: v for k, v in body.items() if k != "model"}, path, own, geo))
    required = schema.required or ()
    needed = required if times is not None or not schema.timed else (*required, "t")
    missing = [p for p in needed if p not in given]
    if schema.missing is not None:
        try:
            missing += schema.missing(given, path)
        except BananagridError as exc:
            raise SceneKeyError(str(exc)) from None
    if missing:
        listed = ", ".join(
            f"{p} (or {p}_{own[p].alias})" if p in own and own[p].alias else p for p in missing
        )
        raise SceneKeyError(f"{path}: missing {listed}: give each in [{path}] or [defaults]")
    params = {p: si for p, (_, _, si) in given.items()}
    if geo is not None:
        params = _grid_bearings(params, own, geo)
    layer = Layer(name=layer_name, kind=kind_name, params=params, model_kind=kind)
    latest = max(times) if times is not None else given["t"][2] if "t" in given else None
    found += _radian_doubts(given, own, latest)
    if "t" in given and given["t"][2] >= MAX_ELAPSED_S:
        where, written, _ = given["t"]
        raise SceneKeyError(f"{where} = {show(written)}: {TIMELINE_LIMIT}")
    for k, t in enumerate(times or (None,)):
        try:
            layer.model(t)
        except BananagridError as exc:
            # a time from scene.times is that key's value, not the layer's
            at = {} if t is None else {"t": (f"scene.times[{k}]", t, t)}
            raise SceneKeyError(_model_error(str(exc), path, {**given, **at}, schema.message_keys)) from None
    return layer


def _grid_bearings(params: dict, own: Mapping, geo: GeoFrame) -> dict:
    """Turn the true bearings of a geographic scene into grid bearings, each at the position
    where it is measured (its key's ``bearing_at``; the local origin when that is not given)."""
    out = dict(params)
    for name, spec in own.items():
        if spec.bearing_at is None or name not in params:
            continue
        at = params.get(spec.bearing_at, (0.0, 0.0)) if spec.bearing_at else (0.0, 0.0)
        if spec.type == "numbers":
            places = at if isinstance(at, list) else [at] * len(params[name])
            # a count mismatch or a non-finite value is the model's to report; convert the rest
            out[name] = [_grid_bearing(geo, b, p) for b, p in zip(params[name], places)] + list(params[name][len(places):])
        else:
            out[name] = _grid_bearing(geo, params[name], at)
    return out


def _grid_bearing(geo: GeoFrame, bearing: float, at) -> float:
    """:meth:`GeoFrame.grid_bearing`, leaving non-finite values to the model's checks."""
    if not (math.isfinite(bearing) and all(math.isfinite(v) for v in at)):
        return bearing
    return geo.grid_bearing(bearing, *at)


def _takes_supplied(own: Mapping, param: str, body: dict, shared: dict) -> bool:
    """Whether a layer takes a value of ``[geo]``'s files for ``param``: it sets neither the
    parameter nor, for the bearing fix's three lists, any of them (a layer's own stations
    with the file's bearings would mix two sources)."""
    group = BEARING_PARAMETERS if param in BEARING_PARAMETERS else (param,)
    written = {keys.base_key(k) for k in body} | set(shared)
    return not any(p in written for p in group)


def _geo(table: dict, directory: Path) -> tuple[GeoFrame, float, dict]:
    """``[geo]``: the origin in latitude and longitude, the UTC time of t = 0, the projection
    and the largest scale error it may have over the grid; with them the parameters the files
    it names give the layers (``{param: (key path, written, SI value)}``): a ``fix_file``'s
    course and speed (:data:`FIX_PARAMETERS`), a ``bearings_file``'s stations, bearings and
    errors (:data:`BEARING_PARAMETERS`)."""
    check_keys(table, GEO_KEYS, "geo")
    fix = _fix_file(table, directory) if "fix_file" in table else None
    if "fix_mmsi" in table and fix is None:
        raise SceneKeyError(f"geo.fix_mmsi = {show(table['fix_mmsi'])}: picks a vessel of geo.fix_file's AIS reports; "
                            "give geo.fix_file too")
    bearings = _bearings_file(table, directory) if "bearings_file" in table else None
    supplied: dict = {}
    if fix is not None:
        for key in ("origin_latlon", "time"):
            if key in table:
                raise SceneKeyError(
                    f"geo.{key} = {show(table[key])}: given with geo.fix_file, whose last fix is the origin and whose "
                    "time is t = 0; give one or the other"
                )
        if abs(fix.lat) == 90.0:
            raise SceneKeyError(f"geo.fix_file = {show(table['fix_file'])}: its last fix ({fix.source}) lies at a "
                                "pole, where true north has no direction; a scene's origin needs a latitude in (-90, 90)")
        where = f"geo.fix_file ({show(table['fix_file'])})"  # a value's key path in messages: the file's field
        table = {**table, "origin_latlon": [fix.lat, fix.lon], "time": fix.time}
        supplied["heading"] = ((f"{where}: course_deg", math.degrees(fix.course), fix.course) if fix.course is not None
                               else (f"{where} gives no course (one point, or its last two at one place)", None, None))
        supplied["v0"] = ((f"{where}: speed (m/s)", fix.speed, fix.speed) if fix.speed is not None
                          else (f"{where} gives no speed (one point without one)", None, None))
    elif bearings is not None and "time" not in table:
        table = {**table, "time": max(bearings.times)}  # the bearings' own time, as a fix's
    if "origin_latlon" not in table:
        raise SceneKeyError("geo.origin_latlon: missing; expected [latitude, longitude] in degrees of the local origin")
    lat, lon = keys.pair(table, "origin_latlon", "geo", unit="degrees")
    if abs(lat) == 90.0 and -180.0 <= lon <= 180.0:
        raise SceneKeyError(
            f"geo.origin_latlon = {show(table['origin_latlon'])}: latitude {lat:g} is a pole, where true north (of "
            "the scene's courses and bearings) has no direction; give a latitude in (-90, 90), e.g. "
            f"{math.copysign(89.9999, lat):g} (a grid about it may hold the pole)"
        )
    if not (-90.0 < lat < 90.0 and -180.0 <= lon <= 180.0):
        raise SceneKeyError(
            f"geo.origin_latlon = {show(table['origin_latlon'])}: expected [latitude in (-90, 90), "
            "longitude in [-180, 180]] degrees"
        )
    limit = keys.number(table.get("max_scale_error", DEFAULT_MAX_SCALE_ERROR), "geo.max_scale_error")
    if not 0.0 < limit < 1.0:
        raise SceneKeyError(f"geo.max_scale_error = {show(table['max_scale_error'])}: must lie in (0, 1)")
    try:  # GeoFrame checks the crs (a string it knows) and the time
        frame = GeoFrame(lat, lon, time=table.get("time"), crs=table.get("crs", "aeqd"))
    except BananagridError as exc:
        raise SceneKeyError(_geo_message(str(exc))) from None
    if bearings is not None:
        where = f"geo.bearings_file ({show(table['bearings_file'])})"
        try:
            x, y = frame.local(bearings.lat, bearings.lon)
        except BananagridError as exc:
            raise SceneKeyError(f"{where}: a station: {exc}") from None
        stations = [[float(a), float(b)] for a, b in zip(bearings.lat, bearings.lon)]
        supplied["sensors"] = (f"{where}: stations", stations, [(float(a), float(b)) for a, b in zip(x, y)])
        supplied["bearings"] = (f"{where}: bearing_deg", [math.degrees(b) for b in bearings.bearings],
                                bearings.bearings.tolist())
        supplied["sigmas"] = (f"{where}: sigma_deg", [math.degrees(s) for s in bearings.sigmas], bearings.sigmas.tolist())
    return frame, limit, supplied


def _input_path(table: dict, key: str, directory: Path) -> Path:
    """The file ``[geo] KEY`` names, relative to the scene's directory."""
    value = table[key]
    if not isinstance(value, str) or not value.strip():
        raise SceneKeyError(f"geo.{key} = {show(value)}: expected a file name (relative to the scene file)")
    return directory / value


def _fix_file(table: dict, directory: Path):
    """The last fix of ``geo.fix_file`` (of ``geo.fix_mmsi``'s AIS reports where given)."""
    mmsi = table.get("fix_mmsi")
    if mmsi is not None and (isinstance(mmsi, bool) or not isinstance(mmsi, int) or not 0 < mmsi < 10**9):
        raise SceneKeyError(f"geo.fix_mmsi = {show(mmsi)}: expected a vessel's MMSI, an integer of up to 9 digits")
    path = _input_path(table, "fix_file", directory)
    try:
        return read_track(path, mmsi=mmsi).last_fix()
    except BananagridError as exc:
        rest = str(exc).removeprefix(f"{path}: ")
        if rest.startswith("mmsi = "):  # the vessel asked for: that key's error
            raise SceneKeyError(f"geo.fix_mmsi = {show(mmsi)}: {rest.partition(': ')[2]}") from None
        message = _file_message(str(exc), path).replace(PASS_MMSI, "give geo.fix_mmsi, the MMSI of the vessel wanted")
        raise SceneKeyError(f"geo.fix_file = {show(table['fix_file'])}: {message}") from None


def _bearings_file(table: dict, directory: Path):
    """The bearings of ``geo.bearings_file``."""
    path = _input_path(table, "bearings_file", directory)
    try:
        return read_bearings(path)
    except BananagridError as exc:
        raise SceneKeyError(f"geo.bearings_file = {show(table['bearings_file'])}: {_file_message(str(exc), path)}") from None


def _file_message(message: str, path: Path) -> str:
    """A reader's ``PATH: line N: ...`` without the path the key already names (kept where the
    file itself is missing or unreadable: the path says where it was looked for)."""
    rest = message.removeprefix(f"{path}: ")
    return rest if rest.startswith("line ") else message


def _geo_message(message: str, other: str = "[geo]: ") -> str:
    """A :class:`GeoFrame` message as a scene's: the frame's own messages start with its
    argument (lat, lon, time, crs), a key of ``[geo]``; others get ``other`` in front."""
    return ("geo." if message.split(" ", 1)[0] in ("lat", "lon", "time", "crs") else other) + message


def _radian_doubts(given: dict, own: Mapping, t: float | None) -> list[str]:
    """Radian values that look like degrees: the key has a ``_deg`` form, the radian form was
    written, and the value is implausible in radians.

    An angle (unit ``rad``) beyond a full turn, ``|value| > 2 pi``, or a rate (``rad/s``) whose
    spread over the latest elapsed time is more than a full turn, ``value * t > 2 pi``: both
    are what a number meant in degrees gives, and neither describes a plausible target.
    """
    doubts = []
    for param, (where, written, si) in given.items():
        spec = own.get(param)
        if spec is None or spec.alias != "deg" or where.endswith("_deg") or where.startswith("geo."):
            continue
        values = si if isinstance(si, list) else [si]
        if spec.unit == "rad" and any(abs(v) > 2.0 * math.pi for v in values):
            doubts.append(
                f"{where} = {show(written)} rad is more than a full turn: were degrees meant? "
                f"Give {param}_deg for degrees"
            )
        elif spec.unit == "rad/s" and t is not None and any(abs(v) * t > 2.0 * math.pi for v in values):
            doubts.append(
                f"{where} = {show(written)} rad/s spreads over more than a full turn in t = {t:g} s "
                f"({math.degrees(max(map(abs, values)) * t):.3g} deg): were degrees meant? Give {param}_deg for degrees/s"
            )
    return doubts


def _model_error(message: str, path: str, given: dict, message_keys: Mapping) -> str:
    """A model's ``name = value: rule`` (or ``name[k] = value: rule``) message restated with
    the scene key and its value as written (``message_keys`` maps names in the model's
    messages that are not scene keys to the keys that set them)."""
    param, sep, rest = message.partition(" = ")
    param = message_keys.get(param, param)
    index = re.fullmatch(r"(\w+)\[(\d+)\]", param)
    if sep and index and index.group(1) in given and ": " in rest:
        where, written, _ = given[index.group(1)]
        k = int(index.group(2))
        shown = show(written[k]) if isinstance(written, list) and k < len(written) else rest.split(": ", 1)[0]
        return f"{where}[{k}] = {shown}: {rest.split(': ', 1)[1]}"
    if sep and param in given and ": " in rest:
        where, written, _ = given[param]
        return f"{where} = {show(written)}: {rest.split(': ', 1)[1]}"
    return f"{path}: {message}"
