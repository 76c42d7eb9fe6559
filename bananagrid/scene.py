"""Scene files: parse a TOML scene, validate every key once, and build grids and models.

A scene names a grid, one or more model layers and how to record them; see ``docs/scenes.md``
for the schema. :func:`load_scene` and :func:`parse_scene` raise :class:`BananagridError` with
one line that names the file, the key path (``layers.exact.sigma_a``), the value given and what
is allowed; nothing downstream has to check a scene again.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType

from .bearing import MAP_VARIANTS, BearingFix
from .butterly import Butterly, NormalSpeed, TabulatedSpeed, UniformSpeed
from .grid import Grid
from .models import CAT, VARIANTS, PolarBanana, Pose
from .record import DEFAULT_LEVELS
from .validate import BananagridError, positive

__all__ = ["Layer", "Scene", "RadialOutput", "load_scene", "parse_scene", "MODEL_KINDS", "PARAMETER_KEYS"]

#: Model classes by the ``model`` value of a layer.
MODEL_KINDS = MappingProxyType({"cat": CAT, "polar": PolarBanana, "bearing_fix": BearingFix, "butterly": Butterly})

#: Kinds with a pose whose conditional radial curves can be recorded (``[radial]``).
MOTION_KINDS = ("cat", "polar")
#: Kinds whose density depends on the elapsed time ``t`` (``scene.times`` applies).
TIMED_KINDS = ("cat", "polar", "butterly")

#: One knot in m/s (1852 m per hour): ``NAME_kn`` keys are converted with it.
KNOT = 1852.0 / 3600.0
#: Butterly's speed laws (``speed_law``) and the keys each takes besides the common ones.
SPEED_LAWS = MappingProxyType({
    "discrete": ("speeds", "weights"),
    "uniform": ("speed_min", "speed_max"),
    "normal": ("speed_mean", "speed_sd"),
    "table": ("speeds", "speed_density"),
})

#: Scene keys of every model kind (the ``t`` key is refused when ``scene.times`` is given).
PARAMETER_KEYS = MappingProxyType({
    "cat": (
        "v0", "t", "sigma_a", "sigma_omega", "sigma_omega_deg", "k_sigma",
        "sigma_heading", "sigma_heading_deg", "origin", "heading", "heading_deg",
    ),
    "polar": (
        "v0", "t", "sigma_a", "sigma_omega", "sigma_omega_deg", "variant",
        "sigma_heading", "sigma_heading_deg", "heading_order", "origin", "heading", "heading_deg",
    ),
    "bearing_fix": ("sensors", "bearings", "bearings_deg", "sigmas", "sigmas_deg", "variant"),
    "butterly": (
        "mean", "cov", "sigma_x", "sigma_y", "rho", "t", "speed_law", "speeds", "speeds_kn", "weights",
        "speed_min", "speed_min_kn", "speed_max", "speed_max_kn", "speed_mean", "speed_mean_kn",
        "speed_sd", "speed_sd_kn", "speed_density", "course_kappa", "course_mean", "course_mean_deg",
    ),
})

#: Angles that a scene may give in radians or, under ``NAME_deg``, in degrees (lists too).
ANGLE_KEYS = ("sigma_omega", "sigma_heading", "heading", "bearings", "sigmas", "course_mean")
#: Speeds that a scene may give in m/s or, under ``NAME_kn``, in knots (lists too).
SPEED_KEYS = ("speeds", "speed_min", "speed_max", "speed_mean", "speed_sd")

#: Parameters every layer of a kind needs (from its table or ``[defaults]``); motion kinds
#: also need ``t`` unless the scene gives ``scene.times``.
REQUIRED = MappingProxyType({
    "cat": ("v0", "sigma_a", "sigma_omega"),
    "polar": ("v0", "sigma_a", "sigma_omega"),
    "bearing_fix": ("sensors", "bearings", "sigmas"),
    # and the start covariance (cov, or sigma_x and sigma_y) and the speed law's keys
    "butterly": ("mean",),
})

#: The ``variant`` values each kind accepts.
KIND_VARIANTS = MappingProxyType({"polar": VARIANTS, "bearing_fix": MAP_VARIANTS})

NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]+")
TOP_KEYS = ("scene", "grid", "output", "defaults", "layers", "radial")
RADIAL_KEYS = ("layers", "density_bearings_deg", "moments_max_deg", "moments_step_deg")
SCENE_KEYS = ("name", "title", "description", "times")
GRID_KEYS = ("x", "y", "step", "dx", "dy")
OUTPUT_KEYS = ("contour_levels", "normalise", "dtype", "colormap", "bearing_validation")
DTYPES = ("float64", "float32")


@dataclass(frozen=True)
class Layer:
    """One model layer of a scene, validated.

    Attributes
    ----------
    name : str
        Layer name (the table name under ``[layers]``); its entity is ``layers/NAME``.
    kind : str
        A key of :data:`MODEL_KINDS`: ``"cat"``, ``"polar"``, ``"bearing_fix"`` or ``"butterly"``.
    params : Mapping
        Model parameters in SI units (m, s, m/s) and radians, ``[defaults]`` merged in, under
        their scene names without ``_deg`` / ``_kn``: for motion layers ``v0``, ``sigma_a``,
        ``sigma_omega``, ``t`` (absent when the scene has ``times``) and, where given,
        ``k_sigma``, ``variant``, ``origin`` (a pair) and ``heading``; for Butterly layers those
        of :func:`butterly_arguments`.
    """

    name: str
    kind: str
    params: Mapping = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    def model(self, t: float | None = None) -> CAT | PolarBanana | BearingFix | Butterly:
        """The layer's model at elapsed time ``t`` (s); by default the layer's own ``t``.
        A bearing fix does not change with time and ignores ``t``.

        Raises
        ------
        BananagridError
            If no ``t`` is known, or a parameter is out of its domain.
        """
        kwargs = dict(self.params)
        if self.kind not in TIMED_KINDS:
            return MODEL_KINDS[self.kind](**kwargs)
        if t is not None:
            kwargs["t"] = t
        if "t" not in kwargs:
            raise BananagridError(f"layer {self.name}: no elapsed time t; pass model(t=...)")
        if self.kind == "butterly":
            return Butterly(**butterly_arguments(kwargs))
        pose = Pose(origin=kwargs.pop("origin", (0.0, 0.0)), heading=kwargs.pop("heading", 0.0))
        return MODEL_KINDS[self.kind](**kwargs, pose=pose)


def butterly_arguments(params: Mapping) -> dict:
    """Keyword arguments of :class:`~bananagrid.Butterly` from a Butterly layer's parameters.

    ``params`` holds, in SI units: ``mean``; ``cov`` or ``sigma_x``, ``sigma_y`` (m) and
    optionally ``rho`` (correlation, default 0); ``t``; ``speed_law`` (default
    ``"discrete"``) with ``speeds`` and ``weights``, ``speed_min`` and ``speed_max``
    (uniform), ``speed_mean`` and ``speed_sd`` (normal, truncated at 0) or ``speeds`` and
    ``speed_density`` (table); optionally ``course_kappa`` and ``course_mean``.

    Raises
    ------
    BananagridError
        ``NAME = value: rule`` for a value out of its domain (sigma_x, sigma_y, rho here; the
        rest from the model and its speed laws).
    """
    if "cov" in params:
        cov = params["cov"]
    else:
        sx, sy = params["sigma_x"], params["sigma_y"]
        rho = params.get("rho", 0.0)
        for name, value in (("sigma_x", sx), ("sigma_y", sy)):
            if not (math.isfinite(value) and value > 0.0):
                raise BananagridError(f"{name} = {value!r}: must be finite and > 0 (m, 1 sigma)")
        if not (math.isfinite(rho) and -1.0 < rho < 1.0):
            raise BananagridError(f"rho = {rho!r}: must be in (-1, 1) (the start's correlation)")
        cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
    law = params.get("speed_law", "discrete")
    weights = None
    if law == "discrete":
        speeds, weights = params["speeds"], params.get("weights")
    elif law == "uniform":
        speeds = UniformSpeed(params["speed_min"], params["speed_max"])
    elif law == "normal":
        speeds = NormalSpeed(params["speed_mean"], params["speed_sd"])
    else:
        speeds = TabulatedSpeed(params["speeds"], params["speed_density"])
    return dict(
        mean=params["mean"], cov=cov, speeds=speeds, weights=weights, t=params["t"],
        course_kappa=params.get("course_kappa", 0.0), course_mean=params.get("course_mean", 0.0),
    )


@dataclass(frozen=True)
class RadialOutput:
    """``[radial]``: the conditional radial curves of Figures 2-5 and 8 of the polar-banana
    paper, for some motion layers (see :mod:`bananagrid.record_radial`).

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
class Scene:
    """A validated scene: a grid, model layers and recording options.

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
    grid : Grid
        The grid every layer is rasterised on.
    bounds : ((float, float), (float, float))
        The ``x`` and ``y`` bounds as written, m; :meth:`with_step` rebuilds the grid from them.
    layers : tuple of Layer
        In file order.
    times : tuple of float or None
        Elapsed times, s, strictly increasing; every layer is computed at each. None when the
        layers give their own ``t``.
    levels : tuple of float
        Contour levels, density per m^2.
    normalise : bool
        Whether rasters are normalised over the grid before they are recorded.
    dtype : str
        Kernel precision, ``"float64"`` or ``"float32"``.
    colormap : str
        rerun colormap of the density images (lower case).
    bearing_validation : bool
        Whether the recording gets the Walsh linearisation validation table (Monte Carlo of
        the true geometry over crossing angles and bearing errors; a few seconds).
    radial : RadialOutput or None
        The conditional radial curves to record, if the scene asks for them (``[radial]``).
    """

    name: str
    title: str
    description: str
    text: str
    source: str
    grid: Grid
    bounds: tuple
    layers: tuple
    times: tuple | None
    levels: tuple
    normalise: bool
    dtype: str
    colormap: str
    bearing_validation: bool = False
    radial: RadialOutput | None = None

    def with_step(self, step: float) -> "Scene":
        """A copy whose grid covers the same bounds with square cells of ``step`` metres."""
        step = positive("step", step)
        x, y = self.bounds
        try:
            grid = Grid.from_bounds(x=x, y=y, step=step)
        except BananagridError as exc:
            raise BananagridError(f"{self.source}: grid at step {step:g} m: {exc}") from None
        return replace(self, grid=grid)

    def jobs(self) -> list[tuple[Layer, float]]:
        """Every (layer, elapsed time) to compute, time-major when the scene has times. A
        bearing fix, timeless, is logged at t = 0 unless the scene has times."""
        if self.times is None:
            return [(layer, layer.params.get("t", 0.0)) for layer in self.layers]
        return [(layer, t) for t in self.times for layer in self.layers]


# --- entry points -----------------------------------------------------------------------------


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate the scene file at ``path``.

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
    return parse_scene(text, source=str(path))


def parse_scene(text: str, source: str = "<string>") -> Scene:
    """Parse and validate scene TOML ``text``; ``source`` names it in error messages."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BananagridError(f"{source}: invalid TOML: {exc}") from None
    try:
        if "array" in doc:  # a presence scene: bananagrid.scene_presence
            from .scene_presence import build_presence_scene

            return build_presence_scene(doc, text, source)
        return _build(doc, text, source)
    except _KeyError as exc:
        raise BananagridError(f"{source}: {exc}") from None


# --- building the scene -----------------------------------------------------------------------


class _KeyError(Exception):
    """A schema violation; :func:`parse_scene` prefixes the source."""


def _build(doc: dict, text: str, source: str) -> Scene:
    """Validate the parsed document table by table and assemble the Scene."""
    _check_keys(doc, TOP_KEYS, "")
    head = _table(doc, "scene", required=True)
    _check_keys(head, SCENE_KEYS, "scene")
    name = _name(head.get("name"), "scene.name", required=True)
    title = _text(head, "title", "scene", default=name)
    description = _text(head, "description", "scene", default="")
    times = _times(head["times"]) if "times" in head else None
    bounds, grid = _grid(_table(doc, "grid", required=True))
    levels, normalise, dtype, colormap, bearing_validation = _output(_table(doc, "output"))
    defaults = _table(doc, "defaults")
    every_key = tuple(dict.fromkeys(k for keys in PARAMETER_KEYS.values() for k in keys))
    _check_keys(defaults, every_key, "defaults")
    if times is not None and "t" in defaults:
        raise _KeyError(
            f"defaults.t = {_show(defaults['t'])}: not allowed when scene.times is given "
            "(every layer is computed at every time)"
        )
    shared = _parameters(defaults, "defaults")
    layers = _layers(_table(doc, "layers", required=True), shared, times)
    radial = _radial(doc["radial"], layers) if "radial" in doc else None
    return Scene(
        name=name, title=title, description=description, text=text, source=source,
        grid=grid, bounds=bounds, layers=layers, times=times, levels=levels,
        normalise=normalise, dtype=dtype, colormap=colormap, bearing_validation=bearing_validation,
        radial=radial,
    )


def _radial(value, layers) -> RadialOutput:
    """``[radial]``: which motion layers get radial curves, at which bearings (degrees)."""
    table = _table({"radial": value}, "radial")
    _check_keys(table, RADIAL_KEYS, "radial")
    motion = [layer.name for layer in layers if layer.kind in MOTION_KINDS]  # not Butterly: no pose
    names = table.get("layers", motion)
    if not isinstance(names, list) or not names:
        raise _KeyError(f"radial.layers = {_show(names)}: expected a non-empty list of cat or polar layer names")
    for k, name in enumerate(names):
        if name not in motion:
            raise _KeyError(
                f"radial.layers[{k}] = {_show(name)}: not a cat or polar layer of this scene "
                f"(those are: {', '.join(map(_show, motion)) or 'none'})"
            )
    bearings = ()
    if "density_bearings_deg" in table:
        bearings = tuple(_numbers(table["density_bearings_deg"], "radial.density_bearings_deg"))
        for k, b in enumerate(bearings):
            if not (math.isfinite(b) and -180.0 < b <= 180.0):
                raise _KeyError(
                    f"radial.density_bearings_deg[{k}] = {_show(table['density_bearings_deg'][k])}: "
                    "must be in (-180, 180] degrees"
                )
    top = _number(table.get("moments_max_deg", 0.0), "radial.moments_max_deg")
    if not (0.0 <= top <= 180.0):
        raise _KeyError(f"radial.moments_max_deg = {_show(table['moments_max_deg'])}: must be in [0, 180] degrees")
    step = _number(table.get("moments_step_deg", 2.0), "radial.moments_step_deg")
    if not (math.isfinite(step) and 0.0 < step <= 90.0):
        raise _KeyError(f"radial.moments_step_deg = {_show(table['moments_step_deg'])}: must be in (0, 90] degrees")
    if not bearings and top == 0.0:
        raise _KeyError("radial: give density_bearings_deg or moments_max_deg (> 0), or drop [radial]")
    return RadialOutput(
        layers=tuple(names), density_bearings=tuple(math.radians(b) for b in bearings),
        moments_max=math.radians(top), moments_step=math.radians(step),
    )


def _times(value) -> tuple[float, ...]:
    """``scene.times``: a non-empty list of finite elapsed times > 0, strictly increasing."""
    path = "scene.times"
    if not isinstance(value, list) or not value:
        raise _KeyError(f"{path} = {_show(value)}: expected a non-empty list of elapsed times in s")
    times = tuple(_number(v, f"{path}[{k}]") for k, v in enumerate(value))
    for k, t in enumerate(times):
        if not (math.isfinite(t) and t > 0.0):
            raise _KeyError(f"{path}[{k}] = {_show(value[k])}: must be finite and > 0 (s)")
        if k and not t > times[k - 1]:
            raise _KeyError(
                f"{path} = {_show(value)}: must be strictly increasing "
                f"({_show(value[k - 1])} then {_show(value[k])})"
            )
    return times


def _grid(table: dict) -> tuple[tuple, Grid]:
    """``[grid]``: bounds ``x``, ``y`` and ``step`` (or ``dx`` and ``dy``), all metres."""
    _check_keys(table, GRID_KEYS, "grid")
    x = _pair(table, "x", "grid", required=True)
    y = _pair(table, "y", "grid", required=True)
    steps = {k: _number(table[k], f"grid.{k}") for k in ("step", "dx", "dy") if k in table}
    if "step" in steps and len(steps) > 1:
        raise _KeyError("grid: give either step or both dx and dy, not both")
    if "step" not in steps and len(steps) != 2:
        raise _KeyError("grid: step (m) is required (or both dx and dy)")
    try:
        return (x, y), Grid.from_bounds(x=x, y=y, **steps)
    except BananagridError as exc:
        raise _KeyError(_prefixed(str(exc), "grid", GRID_KEYS)) from None


def _output(table: dict) -> tuple[tuple, bool, str, str, bool]:
    """``[output]``: contour levels, normalisation, dtype, colormap and whether to add the
    bearing-fix validation table, with defaults."""
    _check_keys(table, OUTPUT_KEYS, "output")
    levels = DEFAULT_LEVELS
    if "contour_levels" in table:
        value = table["contour_levels"]
        if not isinstance(value, list) or not value:
            raise _KeyError(
                f"output.contour_levels = {_show(value)}: expected a non-empty list of densities (m^-2)"
            )
        levels = tuple(_number(v, f"output.contour_levels[{k}]") for k, v in enumerate(value))
        for k, level in enumerate(levels):
            if not (math.isfinite(level) and level > 0.0):
                raise _KeyError(
                    f"output.contour_levels[{k}] = {_show(value[k])}: must be finite and > 0 (m^-2)"
                )
    normalise = table.get("normalise", True)
    if not isinstance(normalise, bool):
        raise _KeyError(f"output.normalise = {_show(normalise)}: expected true or false")
    dtype = table.get("dtype", "float64")
    if dtype not in DTYPES:
        raise _KeyError(f"output.dtype = {_show(dtype)}: must be one of {', '.join(map(_show, DTYPES))}")
    colormap = table.get("colormap", "viridis")
    allowed = _colormaps()
    if not isinstance(colormap, str) or colormap.lower() not in allowed:
        raise _KeyError(f"output.colormap = {_show(colormap)}: must be one of {', '.join(allowed)}")
    validation = table.get("bearing_validation", False)
    if not isinstance(validation, bool):
        raise _KeyError(f"output.bearing_validation = {_show(validation)}: expected true or false")
    return tuple(float(v) for v in levels), normalise, dtype, colormap.lower(), validation


def _colormaps() -> tuple[str, ...]:
    """The colormap names rerun knows, in lower case."""
    import rerun as rr

    return tuple(c.name.lower() for c in rr.components.Colormap)


def _layers(table: dict, shared: dict, times) -> tuple[Layer, ...]:
    """``[layers.NAME]`` tables in file order, each merged over ``[defaults]`` and checked.

    ``shared`` holds the ``[defaults]`` parameters as returned by :func:`_parameters`.
    """
    if not table:
        raise _KeyError("layers: at least one [layers.NAME] table is required")
    layers = []
    for name, body in table.items():
        path = f"layers.{name}"
        if not NAME_PATTERN.fullmatch(name):
            raise _KeyError(f"layers.{_show(name)}: a layer name must be letters, digits, _ and -")
        if not isinstance(body, dict):
            raise _KeyError(f"{path} = {_show(body)}: expected a table [layers.{name}]")
        layers.append(_layer(name, body, shared, times))
    return tuple(layers)


def _layer(name: str, body: dict, shared: dict, times) -> Layer:
    """Validate one layer: its keys, its values, and its model at every elapsed time."""
    path = f"layers.{name}"
    kind = body.get("model")
    if kind not in MODEL_KINDS:
        shown = "missing" if kind is None else f"= {_show(kind)}"
        raise _KeyError(f"{path}.model {shown}: must be one of {', '.join(map(_show, MODEL_KINDS))}")
    allowed = PARAMETER_KEYS[kind]
    _check_keys(body, ("model", *allowed), path, note=f" (model {_show(kind)})")
    if times is not None and "t" in body and kind in TIMED_KINDS:
        raise _KeyError(
            f"{path}.t = {_show(body['t'])}: not allowed when scene.times is given "
            "(every layer is computed at every time)"
        )
    # Where each parameter comes from: {param: (key path, value as written, value in SI)}.
    # Defaults of the other model kind (k_sigma, variant) do not apply to this layer.
    params = {_base_key(key) for key in allowed}
    given = {p: v for p, v in shared.items() if p in params}
    given.update(_parameters({k: v for k, v in body.items() if k != "model"}, path, kind))
    needed = REQUIRED[kind] if times is not None or kind not in TIMED_KINDS else (*REQUIRED[kind], "t")
    missing = [p for p in needed if p not in given]
    if kind == "butterly":
        missing += _butterly_missing(given, path)
    if missing:
        keys = ", ".join(
            f"{p} (or {p}_deg)" if p in ANGLE_KEYS else f"{p} (or {p}_kn)" if p in SPEED_KEYS else p for p in missing
        )
        raise _KeyError(f"{path}: missing {keys}: give each in [{path}] or [defaults]")
    layer = Layer(name=name, kind=kind, params={p: si for p, (_, _, si) in given.items()})
    for t in times or (None,):
        try:
            layer.model(t)
        except BananagridError as exc:
            raise _KeyError(_model_error(str(exc), path, given)) from None
    return layer


def _base_key(key: str) -> str:
    """The parameter a scene key sets: ``heading_deg`` -> ``heading``, ``speeds_kn`` -> ``speeds``."""
    if key.endswith("_deg"):
        return key.removesuffix("_deg")
    if key.endswith("_kn"):
        return key.removesuffix("_kn")
    return key


def _butterly_missing(given: dict, path: str) -> list[str]:
    """The start covariance and speed-law keys a Butterly layer lacks (as 'missing' items);
    keys that contradict each other or the speed law are errors."""
    missing = []
    sigmas = [k for k in ("sigma_x", "sigma_y", "rho") if k in given]
    if "cov" in given and sigmas:
        raise _KeyError(
            f"{path}: give cov or sigma_x, sigma_y (and rho), not both "
            f"(cov from {given['cov'][0]}, {sigmas[0]} from {given[sigmas[0]][0]})"
        )
    if "cov" not in given:
        if sigmas:
            missing += [k for k in ("sigma_x", "sigma_y") if k not in given]
        else:
            missing.append("cov (or sigma_x and sigma_y)")
    law = given.get("speed_law", (None, None, "discrete"))[2]
    needed = SPEED_LAWS[law]
    missing += [k for k in needed if k not in given and not (law == "discrete" and k == "weights")]
    for key in (k for ks in SPEED_LAWS.values() for k in ks):
        if key in given and key not in needed:
            where, written, _ = given[key]
            laws = [name for name, keys in SPEED_LAWS.items() if key in keys]
            raise _KeyError(
                f"{where} = {_show(written)}: only with speed_law = "
                + " or ".join(map(_show, laws)) + f" (this layer's is {_show(law)})"
            )
    return missing


def _parameters(table: dict, path: str, kind: str | None = None) -> dict:
    """``{param: (key path, written value, SI value)}`` of the parameter keys in ``table``.

    The keys are known to be parameter keys. Degrees under ``*_deg`` are converted to
    radians and knots under ``*_kn`` to m/s; giving both forms of one value is an error.
    ``kind`` decides which ``variant`` values are allowed (``None``, for ``[defaults]``: any
    kind's).
    """
    out = {}
    for key, value in table.items():
        where = f"{path}.{key}"
        param = _base_key(key)
        if param in out:
            other = next(k for k in table if k != key and _base_key(k) == param)
            unit, alt = ("rad", "degrees") if key.endswith("_deg") or other.endswith("_deg") else ("m/s", "knots")
            suffix = "_deg" if unit == "rad" else "_kn"
            raise _KeyError(
                f"{path}: give {param} ({unit}) or {param}{suffix} ({alt}), not both "
                f"({param} = {_show(table[param])}, {param}{suffix} = {_show(table[param + suffix])})"
            )
        if param in ("origin", "mean"):
            out[param] = (where, value, _pair(table, key, path, unit="m"))
        elif param == "cov":
            out[param] = (where, value, _matrix(value, where))
        elif param == "speed_law":
            if value not in SPEED_LAWS:
                raise _KeyError(f"{where} = {_show(value)}: must be one of {', '.join(map(_show, SPEED_LAWS))}")
            out[param] = (where, value, value)
        elif param in ("speeds", "weights", "speed_density"):
            numbers = _numbers(value, where)
            out[param] = (where, value, [v * KNOT for v in numbers] if key.endswith("_kn") else numbers)
        elif param == "variant":
            allowed = KIND_VARIANTS.get(kind) if kind else sorted({v for vs in KIND_VARIANTS.values() for v in vs})
            if allowed is None or value not in allowed:
                raise _KeyError(f"{where} = {_show(value)}: must be one of {', '.join(map(_show, allowed or ()))}")
            out[param] = (where, value, value)
        elif param == "sensors":
            out[param] = (where, value, _pairs(value, where))
        elif param in ("bearings", "sigmas"):
            numbers = _numbers(value, where)
            out[param] = (where, value, [math.radians(v) for v in numbers] if key.endswith("_deg") else numbers)
        else:
            number = _number(value, where)
            if key.endswith("_deg"):
                number = math.radians(number)
            elif key.endswith("_kn"):
                number = number * KNOT
            out[param] = (where, value, number)
    return out


#: Butterly speed-law messages name the law's fields; the scene keys that set them.
_SPEED_LAW_FIELDS = {
    "speeds.v_min": "speed_min", "speeds.v_max": "speed_max", "speeds.mean": "speed_mean",
    "speeds.sd": "speed_sd", "speeds.speeds": "speeds", "speeds.density": "speed_density",
}


def _model_error(message: str, path: str, given: dict) -> str:
    """A model's ``name = value: rule`` (or ``name[k] = value: rule``) message restated with
    the scene key and its value as written."""
    param, sep, rest = message.partition(" = ")
    param = _SPEED_LAW_FIELDS.get(param, param)
    index = re.fullmatch(r"(\w+)\[(\d+)\]", param)
    if sep and index and index.group(1) in given and ": " in rest:
        where, written, _ = given[index.group(1)]
        k = int(index.group(2))
        shown = _show(written[k]) if isinstance(written, list) and k < len(written) else rest.split(": ", 1)[0]
        return f"{where}[{k}] = {shown}: {rest.split(': ', 1)[1]}"
    if sep and param in given and ": " in rest:
        where, written, _ = given[param]
        return f"{where} = {_show(written)}: {rest.split(': ', 1)[1]}"
    return f"{path}: {message}"


# --- small checks -----------------------------------------------------------------------------


def _check_keys(table: dict, allowed, path: str, note: str = "") -> None:
    """Refuse keys outside ``allowed``, naming the full key path."""
    for key in table:
        if key not in allowed:
            where = f"{path}.{key}" if path else key
            raise _KeyError(f"{where}: unknown key{note}; allowed: {', '.join(allowed)}")


def _table(doc: dict, key: str, required: bool = False) -> dict:
    """The sub-table ``doc[key]`` ({} when absent and optional)."""
    if key not in doc:
        if required:
            raise _KeyError(f"[{key}]: missing table")
        return {}
    value = doc[key]
    if not isinstance(value, dict):
        raise _KeyError(f"{key} = {_show(value)}: expected a table [{key}]")
    return value


def _name(value, path: str, required: bool = False, what: str = "name") -> str:
    """A name made of letters, digits, ``_`` and ``-`` (it becomes a file or entity name)."""
    if value is None and required:
        raise _KeyError(f"{path}: missing; expected a {what} of letters, digits, _ and -")
    if not isinstance(value, str) or not NAME_PATTERN.fullmatch(value):
        raise _KeyError(f"{path} = {_show(value)}: expected a {what} of letters, digits, _ and -")
    return value


def _text(table: dict, key: str, path: str, default: str) -> str:
    """An optional free-text string."""
    value = table.get(key, default)
    if not isinstance(value, str):
        raise _KeyError(f"{path}.{key} = {_show(value)}: expected a string")
    return value


def _number(value, path: str) -> float:
    """A TOML integer or float as float (booleans and strings are refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _KeyError(f"{path} = {_show(value)}: expected a number")
    return float(value)


def _numbers(value, path: str) -> list[float]:
    """A non-empty TOML list of numbers."""
    if not isinstance(value, list) or not value:
        raise _KeyError(f"{path} = {_show(value)}: expected a list of numbers")
    return [_number(v, f"{path}[{k}]") for k, v in enumerate(value)]


def _pairs(value, path: str) -> list[tuple[float, float]]:
    """A non-empty TOML list of [x, y] pairs, metres."""
    if not isinstance(value, list) or not value:
        raise _KeyError(f"{path} = {_show(value)}: expected a list of [x, y] pairs in m")
    out = []
    for k, item in enumerate(value):
        if not isinstance(item, list) or len(item) != 2:
            raise _KeyError(f"{path}[{k}] = {_show(item)}: expected a pair [x, y] in m")
        out.append(tuple(_number(v, f"{path}[{k}][{j}]") for j, v in enumerate(item)))
    return out


def _matrix(value, path: str) -> list[list[float]]:
    """A 2 x 2 TOML array of numbers ``[[a, b], [c, d]]`` (m^2); symmetry and positive
    definiteness are the model's to check."""
    if not isinstance(value, list) or len(value) != 2 or not all(isinstance(row, list) and len(row) == 2 for row in value):
        raise _KeyError(f"{path} = {_show(value)}: expected a 2 x 2 array [[sxx, sxy], [sxy, syy]] in m^2")
    return [[_number(v, f"{path}[{i}][{j}]") for j, v in enumerate(row)] for i, row in enumerate(value)]


def _pair(table: dict, key: str, path: str, required: bool = False, unit: str = "m") -> tuple[float, float]:
    """``[a, b]`` of two finite numbers (metres)."""
    where = f"{path}.{key}"
    if key not in table:
        if required:
            raise _KeyError(f"{where}: missing; expected [low, high] in m")
        return None
    value = table[key]
    if not isinstance(value, list) or len(value) != 2:
        raise _KeyError(f"{where} = {_show(value)}: expected a pair of numbers [a, b] in {unit}")
    a, b = (_number(v, f"{where}[{k}]") for k, v in enumerate(value))
    for k, v in enumerate((a, b)):
        if not math.isfinite(v):
            raise _KeyError(f"{where}[{k}] = {_show(value[k])}: must be finite")
    return (a, b)


def _prefixed(message: str, path: str, keys) -> str:
    """Prefix ``path.`` to a ``key = ...`` message about one of ``keys``, else ``path: ``."""
    head = re.match(r"(\w+)(\[\d\])? = ", message)
    if head and head.group(1) in keys:
        return f"{path}.{message}"
    return f"{path}: {message}"


def _show(value) -> str:
    """A value as TOML would write it, for messages."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_show(v)}" for k, v in value.items()) + "}"
    return str(value)
