"""Scene files: keys and their checks, loading (a grid or an array's angular lattice as the
domain), and running them (one runner for both)."""

from .load import Layer, Scene, load_scene, parse_scene
from .run import run_scene

__all__ = ["Scene", "Layer", "load_scene", "parse_scene", "run_scene"]
