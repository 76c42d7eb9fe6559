"""bananagrid: probability maps from target-motion and sensing models."""

from .butterly import Butterly
from .grid import Grid
from .lattice import PolarLattice, PolarRaster
from .models import CAT, PolarBanana, Pose
from .radial import RadialDensity, RadialMoments, radial_density, radial_moments
from .raster import Raster, rasterise
from .validate import BananagridError

__all__ = [
    "Grid", "PolarLattice", "PolarRaster", "Raster", "CAT", "PolarBanana", "Butterly", "Pose", "rasterise",
    "radial_moments", "radial_density", "RadialMoments", "RadialDensity", "BananagridError",
]
__version__ = "0.1.0"
