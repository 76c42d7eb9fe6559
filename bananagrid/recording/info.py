"""A layer's ``info`` values: provenance, mass, peak and grid flattened to dotted keys for
``AnyValues``."""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np

from ..results import Raster

__all__ = ["flatten", "raster_info"]


def raster_info(raster: Raster) -> dict[str, float | str]:
    """Flat ``{key: number or string}`` of the raster's provenance, mass, peak and grid.

    Nested keys are joined with ``.`` (``grid.origin.0``); numbers become float so that a
    key keeps one arrow type across times; booleans become ``"true"``/``"false"``.
    """
    info = {
        "provenance": raster.provenance,
        "quantity": raster.quantity,
        "mass": raster.mass,
        "normalised": raster.normalised,
        "peak": raster.peak,
        "grid": raster.grid.describe(),
    }
    return dict(flatten("", info))


def flatten(prefix: str, value) -> Iterator[tuple[str, float | str]]:
    """Yield ``(dotted key, leaf)`` pairs of nested mappings and sequences."""
    if isinstance(value, Mapping):
        for key, item in value.items():
            yield from flatten(f"{prefix}.{key}" if prefix else str(key), item)
    elif isinstance(value, (list, tuple, np.ndarray)):
        for k, item in enumerate(value):
            yield from flatten(f"{prefix}.{k}", item)
    elif value is not None:
        yield prefix, _leaf(value)


def _leaf(value) -> float | str:
    """A plain number or string for AnyValues."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    return str(value)
