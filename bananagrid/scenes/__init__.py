"""Scene files: keys and their checks, loading (grid and presence scenes), and running them."""

from .load import Layer, Scene, load_scene, parse_scene
from .presence import PresenceScene
from .run import run_scene

__all__ = ["Scene", "Layer", "PresenceScene", "load_scene", "parse_scene", "run_scene"]
