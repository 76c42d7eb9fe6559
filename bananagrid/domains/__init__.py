"""Where cells are: grids, polar and angular lattices, regions and poses."""

from .angular_lattice import AngularLattice
from .grid import MAX_CELLS, Grid
from .polar_lattice import PolarLattice
from .pose import Pose
from .region import Region

__all__ = ["Grid", "MAX_CELLS", "PolarLattice", "AngularLattice", "Region", "Pose"]
