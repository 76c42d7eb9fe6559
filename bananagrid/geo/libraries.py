"""The optional libraries of the ``geo`` and ``cluster`` extras, loaded when first used.

``import bananagrid`` must work without them: a module that needs one calls :func:`require`
where it is used, and a missing library is a one-line error naming the extra.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ..validate import BananagridError

__all__ = ["require", "GEO_EXTRA", "CLUSTER_EXTRA", "CLUSTER_PURPOSE"]

#: How a user installs every library of the geographic frame and the file formats.
GEO_EXTRA = "pip install 'bananagrid[geo]'"
#: How a user installs Dask, distributed and Zarr (tiled rasterising, clusters, Zarr stores).
CLUSTER_EXTRA = "pip install 'bananagrid[cluster]'"
#: What the cluster extra's libraries are needed for, in the message when one is missing.
CLUSTER_PURPOSE = "tiled rasterising, clusters and Zarr stores"


def require(module_name: str, purpose: str = "geographic scenes and map files", extra: str = GEO_EXTRA) -> ModuleType:
    """The module ``module_name`` (e.g. ``"pyproj"``, ``"xarray"``, ``"dask.array"``), from the
    extra that ``extra`` installs.

    Raises
    ------
    BananagridError
        One line naming the missing library and the extra that installs it.
    """
    try:
        return importlib.import_module(module_name)
    except ImportError:
        top = module_name.split(".")[0]
        raise BananagridError(f"{purpose} need {top}: {extra} (or pip install {top})") from None
