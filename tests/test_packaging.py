"""The installed layout: kernels/ ships as bananagrid.kernels, never as a top-level module."""

import site
import warnings
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


ROOT = Path(__file__).resolve().parents[1]


def test_every_bundled_scene_is_installed_as_an_example():
    from bananagrid.scenes.examples import example_names, example_path, example_title
    from bananagrid.scenes.load import load_scene

    scenes = sorted(p.stem for p in (ROOT / "scenes").glob("*.toml"))
    assert example_names() == scenes
    for name in scenes:
        path = example_path(name)
        # read from the package (site-packages, or the checkout's link bananagrid/examples)
        assert path.parent == Path(bananagrid.__file__).parent / "examples", path
        # the installed copy is the repository's file (one source, no hand-made copies)
        assert path.read_bytes() == (ROOT / "scenes" / f"{name}.toml").read_bytes()
        # it loads through the same API; its name is the file's (run --example NAME writes NAME.rrd)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # what a scene warns of (a poor crossing) is not asked here
            scene = load_scene(path)
        assert (scene.name, scene.title) == (name, example_title(name))


def test_examples_ship_in_the_wheel():
    from importlib import metadata

    files = {f.as_posix() for f in metadata.files("bananagrid") or ()}
    if any(name.endswith(".pth") or "__editable__" in name for name in files):
        # editable: the link bananagrid/examples -> ../scenes stands in for the installed folder
        assert (Path(bananagrid.__file__).parent / "examples").resolve() == (ROOT / "scenes").resolve()
        return
    shipped = sorted(Path(f).stem for f in files if f.startswith("bananagrid/examples/") and f.endswith(".toml"))
    assert shipped == sorted(p.stem for p in (ROOT / "scenes").glob("*.toml"))
    assert not any(f.startswith("scenes/") for f in files)  # no top-level "scenes" in site-packages


def test_installed_warp_and_rerun_are_within_the_declared_ranges():
    # The pins are ranges (warp within its minor version, rerun within the minor version whose
    # .rrd format inspect reads back); the versions this suite runs against must satisfy them.
    import tomllib
    from importlib import metadata

    from packaging.requirements import Requirement

    declared = {Requirement(r).name: Requirement(r) for r in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]}
    for name in ("warp-lang", "rerun-sdk"):
        spec = declared[name].specifier
        assert str(spec) and "==" not in str(spec), spec  # a tested range, not an exact pin
        assert spec.contains(metadata.version(name)), (name, metadata.version(name), spec)
