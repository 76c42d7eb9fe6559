"""bananagrid: probability maps from target-motion and sensing models."""

from .angular import AngularLattice, CellMap, cell_probabilities
from .butterly import Butterly
from .grid import Grid
from .lattice import PolarLattice, PolarRaster
from .models import CAT, PolarBanana, Pose
from .presence import GaussianMixture, Region, UniformPresence
from .radial import RadialDensity, RadialMoments, radial_density, radial_moments
from .raster import Raster, rasterise
from .validate import BananagridError

__all__ = [
    "Grid", "PolarLattice", "PolarRaster", "Raster", "CAT", "PolarBanana", "Butterly", "Pose", "rasterise",
    "radial_moments", "radial_density", "RadialMoments", "RadialDensity", "BananagridError",
    "GaussianMixture", "UniformPresence", "Region", "AngularLattice", "CellMap", "cell_probabilities",
]
__version__ = "0.1.0"
