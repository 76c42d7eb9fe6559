"""bananagrid: probability maps from target-motion and sensing models."""

from .grid import Grid
from .raster import Raster
from .validate import BananagridError

__all__ = ["Grid", "Raster", "BananagridError"]
__version__ = "0.1.0"
