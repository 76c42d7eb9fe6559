"""The installed layout: kernels/ ships as bananagrid.kernels, never as a top-level module."""

import importlib.util
from pathlib import Path

import bananagrid


def test_kernels_are_a_subpackage():
    from bananagrid.kernels import cat, common, polar  # noqa: F401

    assert Path(cat.__file__).parent.name == "kernels"
    assert importlib.util.find_spec("kernels") is None


def test_public_names():
    for name in ("Grid", "Raster", "CAT", "PolarBanana", "Pose", "rasterise", "BananagridError"):
        assert hasattr(bananagrid, name), name
