"""Scene keys: checking TOML values by type and converting them to SI units.

Every check raises :class:`SceneKeyError` with ``KEY.PATH = value: what is allowed``;
:func:`bananagrid.scenes.load.parse_scene` prefixes the file. Model parameters are checked by
type from the model's :class:`~bananagrid.protocol.SceneKey` list (:func:`parameters`), and by
value by the model itself when the scene is loaded.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

from ..protocol import LATLON, SceneKey
from ..validate import BananagridError, show, unknown_key

__all__ = [
    "SceneKeyError", "check_keys", "table", "name", "text", "number", "numbers", "pairs", "matrix", "pair",
    "prefixed", "parameters", "base_key", "merged_keys", "show", "NAME_PATTERN", "DTYPES", "KNOT", "UNIT_WORDS",
]

#: Names of scenes, layers and components: they become file and entity names.
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]+")
#: Kernel precisions a scene may ask for.
DTYPES = ("float64", "float32")
#: One knot in m/s (1852 m per hour): ``NAME_kn`` keys are converted with it.
KNOT = 1852.0 / 3600.0


class SceneKeyError(Exception):
    """A schema violation; :func:`bananagrid.scenes.load.parse_scene` prefixes the source."""


def check_keys(table: dict, allowed, path: str, note: str = "") -> None:
    """Refuse keys outside ``allowed``, naming the full key path and the nearest allowed key
    (:func:`~bananagrid.validate.unknown_key`)."""
    for key in table:
        if key not in allowed:
            where = f"{path}.{key}" if path else key
            raise SceneKeyError(unknown_key(where, key, allowed, note))


def table(doc: dict, key: str, required: bool = False) -> dict:
    """The sub-table ``doc[key]`` ({} when absent and optional)."""
    if key not in doc:
        if required:
            raise SceneKeyError(f"[{key}]: missing table")
        return {}
    value = doc[key]
    if not isinstance(value, dict):
        raise SceneKeyError(f"{key} = {show(value)}: expected a table [{key}]")
    return value


def name(value, path: str, required: bool = False, what: str = "name") -> str:
    """A name made of letters, digits, ``_`` and ``-`` (it becomes a file or entity name)."""
    if value is None and required:
        raise SceneKeyError(f"{path}: missing; expected a {what} of letters, digits, _ and -")
    if not isinstance(value, str) or not NAME_PATTERN.fullmatch(value):
        raise SceneKeyError(f"{path} = {show(value)}: expected a {what} of letters, digits, _ and -")
    return value


def text(doc: dict, key: str, path: str, default: str) -> str:
    """An optional free-text string."""
    value = doc.get(key, default)
    if not isinstance(value, str):
        raise SceneKeyError(f"{path}.{key} = {show(value)}: expected a string")
    return value


def number(value, path: str) -> float:
    """A TOML integer or float as float (booleans and strings are refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneKeyError(f"{path} = {show(value)}: expected a number")
    return float(value)


def numbers(value, path: str) -> list[float]:
    """A non-empty TOML list of numbers."""
    if not isinstance(value, list) or not value:
        raise SceneKeyError(f"{path} = {show(value)}: expected a list of numbers")
    return [number(v, f"{path}[{k}]") for k, v in enumerate(value)]


def pairs(value, path: str) -> list[tuple[float, float]]:
    """A non-empty TOML list of [x, y] pairs, metres."""
    if not isinstance(value, list) or not value:
        raise SceneKeyError(f"{path} = {show(value)}: expected a list of [x, y] pairs in m")
    out = []
    for k, item in enumerate(value):
        if not isinstance(item, list) or len(item) != 2:
            raise SceneKeyError(f"{path}[{k}] = {show(item)}: expected a pair [x, y] in m")
        out.append(tuple(number(v, f"{path}[{k}][{j}]") for j, v in enumerate(item)))
    return out


def matrix(value, path: str) -> list[list[float]]:
    """A 2 x 2 TOML array of numbers ``[[a, b], [c, d]]`` (m^2); symmetry and positive
    definiteness are the model's to check."""
    if not isinstance(value, list) or len(value) != 2 or not all(isinstance(row, list) and len(row) == 2 for row in value):
        raise SceneKeyError(f"{path} = {show(value)}: expected a 2 x 2 array [[sxx, sxy], [sxy, syy]] in m^2")
    return [[number(v, f"{path}[{i}][{j}]") for j, v in enumerate(row)] for i, row in enumerate(value)]


def pair(doc: dict, key: str, path: str, required: bool = False, unit: str = "m") -> tuple[float, float] | None:
    """``[a, b]`` of two finite numbers (metres) under ``doc[key]``."""
    where = f"{path}.{key}"
    if key not in doc:
        if required:
            raise SceneKeyError(f"{where}: missing; expected [low, high] in m")
        return None
    return _finite_pair(doc[key], where, unit)


def _finite_pair(value, where: str, unit: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise SceneKeyError(f"{where} = {show(value)}: expected a pair of numbers [a, b] in {unit}")
    a, b = (number(v, f"{where}[{k}]") for k, v in enumerate(value))
    for k, v in enumerate((a, b)):
        if not math.isfinite(v):
            raise SceneKeyError(f"{where}[{k}] = {show(value[k])}: must be finite")
    return (a, b)


def prefixed(message: str, path: str, keys) -> str:
    """Prefix ``path.`` to a ``key = ...`` message about one of ``keys``, else ``path: ``."""
    head = re.match(r"(\w+)(\[\d\])? = ", message)
    if head and head.group(1) in keys:
        return f"{path}.{message}"
    return f"{path}: {message}"


# --- model parameters -------------------------------------------------------------------------


def base_key(key: str) -> str:
    """The parameter a scene key sets: ``heading_deg`` -> ``heading``, ``speeds_kn`` -> ``speeds``,
    ``sensors_latlon`` -> ``sensors``."""
    for suffix in ("_deg", "_kn", f"_{LATLON}"):
        if key.endswith(suffix):
            return key.removesuffix(suffix)
    return key


#: A key's suffix: the units of the plain key and of the suffixed one, for messages.
UNIT_WORDS = {"_deg": ("rad", "degrees"), "_kn": ("m/s", "knots"), f"_{LATLON}": ("m", "[lat, lon] degrees")}


def _unit_suffix(key: str) -> str:
    return key[len(base_key(key)):]


def merged_keys(key_lists) -> dict[str, SceneKey]:
    """The parameters of several model kinds by name (for ``[defaults]``): a choice that differs
    between kinds allows every kind's values (sorted)."""
    out: dict[str, SceneKey] = {}
    for keys in key_lists:
        for key in keys:
            seen = out.get(key.name)
            if seen is not None and key.type == "choice" and seen.choices != key.choices:
                key = SceneKey(key.name, type="choice", choices=tuple(sorted({*seen.choices, *key.choices})))
            out[key.name] = key if seen is None or key.type == "choice" else seen
    return out


def _convert(spec: SceneKey, key: str, value, where: str, frame=None):
    """``value`` of scene key ``key`` (``spec.name`` or its alias) checked by type, in SI;
    ``NAME_latlon`` positions through the scene's geographic ``frame``."""
    if key.endswith(f"_{LATLON}"):
        return _latlon(spec, value, where, frame)
    scale = math.radians if key.endswith("_deg") else (lambda v: v * KNOT) if key.endswith("_kn") else None
    if spec.type == "pair":
        return _finite_pair(value, where, spec.unit or "m")
    if spec.type == "matrix":
        return matrix(value, where)
    if spec.type == "pairs":
        return pairs(value, where)
    if spec.type == "choice":
        if value not in spec.choices:
            raise SceneKeyError(f"{where} = {show(value)}: must be one of {', '.join(map(show, spec.choices))}")
        return value
    if spec.type == "numbers":
        values = numbers(value, where)
        return [scale(v) for v in values] if scale else values
    value = number(value, where)
    return scale(value) if scale else value


def _latlon(spec: SceneKey, value, where: str, frame):
    """A position (``"pair"``) or positions (``"pairs"``) given as ``[lat, lon]`` degrees, in
    local metres of the scene's geographic frame."""
    if frame is None:
        raise SceneKeyError(f"{where} = {show(value)}: positions in latitude and longitude need a [geo] table "
                            "(its origin_latlon)")
    points = [_finite_pair(value, where, "degrees [lat, lon]")] if spec.type == "pair" else pairs(value, where)
    local = []
    for k, (lat, lon) in enumerate(points):
        at = where if spec.type == "pair" else f"{where}[{k}]"
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise SceneKeyError(f"{at} = {show([lat, lon])}: expected [latitude in [-90, 90], longitude in [-180, 180]] degrees")
        try:
            x, y = frame.local(lat, lon)
        except BananagridError as exc:
            raise SceneKeyError(f"{at} = {show([lat, lon])}: {exc}") from None
        local.append((float(x), float(y)))
    return local[0] if spec.type == "pair" else local


def parameters(doc: dict, path: str, keys: Mapping[str, SceneKey], frame=None) -> dict:
    """``{param: (key path, written value, SI value)}`` of the parameter keys in ``doc``.

    The keys are known to be parameter keys of ``keys`` (parameter name -> SceneKey). Degrees
    under ``*_deg`` are converted to radians, knots under ``*_kn`` to m/s, and positions under
    ``*_latlon`` (``[lat, lon]`` degrees) to local metres of the geographic ``frame`` (a
    :class:`~bananagrid.geo.frame.GeoFrame`); giving two forms of one value is an error.
    """
    out = {}
    for key, value in doc.items():
        where = f"{path}.{key}"
        param = base_key(key)
        if param in out:
            first, second = sorted((key, next(k for k in doc if k != key and base_key(k) == param)), key=len)
            suffix = _unit_suffix(second)
            raise SceneKeyError(
                f"{path}: give {first} ({UNIT_WORDS[suffix][0]}) or {second} ({UNIT_WORDS[suffix][1]}), not both "
                f"({first} = {show(doc[first])}, {second} = {show(doc[second])})"
            )
        out[param] = (where, value, _convert(keys[param], key, value, where, frame))
    return out
