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


def test_typed_marker_ships():
    """py.typed marks the package as typed (PEP 561): in the installed files, or in the source
    tree of an editable install."""
    from importlib import metadata

    files = {f.as_posix() for f in metadata.files("bananagrid") or ()}
    installed = "bananagrid/py.typed" in files
    assert installed or (Path(bananagrid.__file__).parent / "py.typed").is_file()
    if any(name.endswith(".pth") or "__editable__" in name for name in files):
        return  # editable: the source tree's marker, checked above
    assert installed, sorted(files)[:10]


def test_all_is_curated():
    assert len(bananagrid.__all__) == len(set(bananagrid.__all__))
    for name in bananagrid.__all__:
        assert hasattr(bananagrid, name), name
    assert {"BearingFix", "grid_probabilities", "DensityModel", "MODEL_KINDS"} <= set(bananagrid.__all__)
