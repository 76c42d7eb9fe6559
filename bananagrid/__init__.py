"""bananagrid: probability maps from target-motion and sensing models.

The public face: every name below is documented on the API page (docs/api.md). Models follow one
protocol (:class:`DensityModel`); ``rasterise`` computes any of them on a grid or a polar
lattice with Warp kernels, ``cell_probabilities`` the presence laws on an array's angular cells.
"""

from .analysis.compare import Comparison, compare
from .analysis.radial import RadialDensity, RadialMoments, radial_density, radial_moments
from .domains.angular_lattice import AngularLattice
from .domains.grid import Grid
from .domains.polar_lattice import PolarLattice
from .domains.pose import Pose
from .domains.region import Region
from .engine.batch import pdf_batch, rasterise_batch
from .engine.batch_shards import pdf_batch_shards, rasterise_batch_shards
from .engine.cluster import dask_client
from .engine.rasterise import rasterise
from .evidence import (AreaSearch, BearingReport, Exclusion, PolarPosterior, PositionReport, Posterior, RasterSearch,
                       TrackSearch, posterior)
from .evidence.batches import BatchPosterior, posterior_batch, posterior_batch_shards
from .evidence.tiled import TiledPosterior, posterior_tiles
from .geo.frame import GeoFrame
from .geo.inputs import Bearings, Fix, Track, read_bearings, read_fix, read_track
from .models.base import Model
from .models.bearing import BearingFix, bearing_to
from .models.butterly import Butterly, NormalSpeed, TabulatedSpeed, UniformSpeed
from .models.cat import CAT
from .models.containment import containment, containment_radius
from .models.polar import PolarBanana
from .models.presence import GaussianMixture, UniformPresence, cell_probabilities, grid_probabilities
from .models.registry import MODEL_KINDS, ModelKind
from .planning.allocation import Allocation, allocate
from .planning.detection import DetectionLaw, detection_law
from .planning.figures import plot_allocation
from .planning.periods import PeriodPlan, plan_periods
from .planning.rectangles import SearchPlan, SearchRectangle, search_rectangles
from .planning.regions import RegionPlan, SearchRegion, search_regions
from .protocol import DensityModel
from .results import BatchRaster, CellMap, GridPresence, PolarRaster, Raster, ShardedBatch, TiledRaster
from .scenes.load import load_scene, parse_scene
from .scenes.run import run_scene
from .validate import BananagridError, BananagridWarning
from .version import __version__

__all__ = [
    # where cells are
    "Grid", "PolarLattice", "AngularLattice", "Region", "Pose", "GeoFrame",
    # models
    "CAT", "PolarBanana", "Butterly", "UniformSpeed", "NormalSpeed", "TabulatedSpeed", "BearingFix",
    "GaussianMixture", "UniformPresence",
    # computing them
    "rasterise", "cell_probabilities", "grid_probabilities", "rasterise_batch", "pdf_batch",
    # on a Dask cluster
    "rasterise_batch_shards", "pdf_batch_shards", "dask_client",
    # results
    "Raster", "TiledRaster", "PolarRaster", "CellMap", "GridPresence", "BatchRaster", "ShardedBatch",
    # analysis
    "radial_moments", "radial_density", "RadialMoments", "RadialDensity", "compare", "Comparison",
    "bearing_to", "containment", "containment_radius",
    # evidence on the map
    "AreaSearch", "TrackSearch", "RasterSearch", "PositionReport", "BearingReport", "Exclusion", "posterior",
    "Posterior", "PolarPosterior", "posterior_batch", "BatchPosterior",
    # ... on a Dask cluster
    "posterior_tiles", "TiledPosterior", "posterior_batch_shards",
    # where to look next
    "allocate", "Allocation", "DetectionLaw", "detection_law", "search_rectangles", "SearchPlan", "SearchRectangle",
    "search_regions", "RegionPlan", "SearchRegion", "plot_allocation", "plan_periods", "PeriodPlan",
    # scenes
    "load_scene", "parse_scene", "run_scene",
    # inputs from the field: tracks, last fixes and bearings from CSV, GPX, NMEA/AIS and GeoJSON
    "read_track", "read_fix", "read_bearings", "Track", "Fix", "Bearings",
    # your own models
    "DensityModel", "Model", "ModelKind", "MODEL_KINDS",
    "BananagridError", "BananagridWarning", "__version__",
]
