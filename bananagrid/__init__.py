"""bananagrid: probability maps from target-motion and sensing models."""

from .grid import Grid
from .models import CAT, PolarBanana, Pose
from .raster import Raster, rasterise
from .validate import BananagridError

__all__ = ["Grid", "Raster", "CAT", "PolarBanana", "Pose", "rasterise", "BananagridError"]
__version__ = "0.1.0"
