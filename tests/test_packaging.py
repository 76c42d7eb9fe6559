"""The installed layout: kernels/ ships as bananagrid.kernels, never as a top-level module."""

import site
from pathlib import Path

import bananagrid


def test_kernels_are_a_subpackage():
    from bananagrid.kernels import cat, common, polar  # noqa: F401

    # installed: site-packages/bananagrid/kernels; editable: the checkout's kernels/ beside bananagrid/
    kernels_dir = Path(cat.__file__).parent
    assert kernels_dir.name == "kernels"
    assert kernels_dir.parent.name == "bananagrid" or (kernels_dir.parent / "bananagrid" / "__init__.py").is_file()


def test_no_top_level_kernels_in_site_packages():
    for directory in site.getsitepackages():
        assert not (Path(directory) / "kernels").exists(), directory
        assert not (Path(directory) / "kernels.py").exists(), directory


def test_public_names():
    for name in ("Grid", "Raster", "CAT", "PolarBanana", "Pose", "rasterise", "BananagridError"):
        assert hasattr(bananagrid, name), name
