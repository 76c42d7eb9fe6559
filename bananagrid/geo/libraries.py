"""The optional libraries of the ``geo`` extra, loaded when first used.

``import bananagrid`` must work without them: a module that needs one calls :func:`require`
where it is used, and a missing library is a one-line error naming the extra.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ..validate import BananagridError

__all__ = ["require", "GEO_EXTRA"]

#: How a user installs every library of the geographic frame and the file formats.
GEO_EXTRA = "pip install 'bananagrid[geo]'"


def require(module_name: str, purpose: str = "geographic scenes and map files") -> ModuleType:
    """The module ``module_name`` (e.g. ``"pyproj"``, ``"xarray"``, ``"rasterio.transform"``).

    Raises
    ------
    BananagridError
        One line naming the missing library and the extra that installs it.
    """
    try:
        return importlib.import_module(module_name)
    except ImportError:
        top = module_name.split(".")[0]
        raise BananagridError(f"{purpose} need {top}: {GEO_EXTRA} (or pip install {top})") from None
