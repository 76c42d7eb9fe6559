"""Parameter checks shared by every public constructor.

Every message names the argument, the value it got and what is allowed, so that a scene
error can be traced to its key (the scene layer prefixes the key path).
"""

from __future__ import annotations

import json
import math
from numbers import Real

import numpy as np

__all__ = ["finite", "positive", "non_negative", "positive_int", "pair", "point", "real_array", "show", "step_ratio",
           "BananagridError", "BananagridWarning"]


class BananagridError(ValueError):
    """A user-facing error: bad parameter, bad scene, bad file. The CLI prints it as one line."""


class BananagridWarning(UserWarning):
    """A likely mistake that still gives a result: a grid that misses the target, an angle that
    looks like degrees given in radians, a contour level the map never reaches. The CLI prints
    it as one line; ``warnings.simplefilter("error", BananagridWarning)`` makes it an error."""


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise BananagridError(f"{name} = {value!r}: expected a real number")
    return float(value)


def real_array(name: str, value, expected: str = "numbers") -> np.ndarray:
    """``value`` as a new float64 array, or raise unless every entry is a real number: NumPy
    alone would turn ``"1"`` and ``True`` into 1.0 (shape and finiteness are the caller's)."""
    try:
        array = np.array(value)
    except (TypeError, ValueError):  # ragged nesting
        array = None
    # kinds b: booleans, U/S: strings, O: anything else; and a bool among floats becomes a float
    if array is None or array.dtype.kind not in "iuf" or _holds_non_number(value):
        raise BananagridError(f"{name} = {value!r}: expected {expected}")
    return array.astype(float)


def _holds_non_number(value) -> bool:
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return True
    return isinstance(value, (list, tuple)) and any(_holds_non_number(v) for v in value)


def finite(name: str, value) -> float:
    """Return ``value`` as float, or raise if it is not a finite real number."""
    v = _real(name, value)
    if not math.isfinite(v):
        raise BananagridError(f"{name} = {v!r}: must be finite")
    return v


def positive(name: str, value) -> float:
    """Return ``value`` as float, or raise unless it is finite and > 0."""
    v = finite(name, value)
    if v <= 0.0:
        raise BananagridError(f"{name} = {v!r}: must be > 0")
    return v


def non_negative(name: str, value) -> float:
    """Return ``value`` as float, or raise unless it is finite and >= 0."""
    v = finite(name, value)
    if v < 0.0:
        raise BananagridError(f"{name} = {v!r}: must be >= 0")
    return v


def positive_int(name: str, value) -> int:
    """Return ``value`` as int, or raise unless it is an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, (int,)) and not (
        isinstance(value, float) and value.is_integer()
    ):
        raise BananagridError(f"{name} = {value!r}: expected an integer")
    v = int(value)
    if v < 1:
        raise BananagridError(f"{name} = {v}: must be >= 1")
    return v


def pair(name: str, value, expected: str = "a pair (low, high)") -> tuple[float, float]:
    """Return ``value`` as a pair of finite floats, or raise naming ``name[0]`` / ``name[1]``
    (``expected`` says what the pair is, for the message when ``value`` is not a pair)."""
    try:
        first, second = value
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {value!r}: expected {expected}") from None
    return finite(f"{name}[0]", first), finite(f"{name}[1]", second)


def point(name: str, value) -> tuple[float, float]:
    """Return ``value`` as a pair of finite floats (x, y), or raise naming the bad one."""
    return pair(name, value, "a pair (x, y)")


def step_ratio(name: str, step: float, span: float, limit: int, unit: str = "") -> float:
    """``span / step``: the number of cells a step cuts a span into, or raise when it overflows
    (a subnormal step: 1 / 5e-324 is inf) or exceeds ``limit`` (before any count is rounded or
    any array allocated)."""
    ratio = span / step
    if not ratio <= limit:
        count = f"{ratio:.3g}" if math.isfinite(ratio) else "more than 1.8e308"
        raise BananagridError(
            f"{name} = {step!r}: cuts the span {span!r}{unit} into {count} cells, more than the {limit:,} a "
            "domain may have; use a larger step"
        )
    return ratio


def show(value) -> str:
    """A value as a scene file (TOML) would write it, for messages."""
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
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {show(v)}" for k, v in value.items()) + "}"
    return str(value)
