"""Pictures without a viewer: Raster.plot (contours, labels, colour scale, frame, the geometry
a provenance names), the notebook representations and short reprs, bananagrid plot on scenes,
recordings and arrays, its one-line errors, and the gallery's pictures."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import socket
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import bananagrid as bg  # noqa: E402
from bananagrid import BananagridError, Raster, cli  # noqa: E402
from bananagrid.contours import format_level, mass_regions  # noqa: E402
from bananagrid.domains.grid import Grid  # noqa: E402
from bananagrid.geo.chart import chart  # noqa: E402
from bananagrid.plotting import (  # noqa: E402
    FLOOR_DECADES,
    MASS_COLOURS,
    colour_range,
    figure_layout,
    map_frame,
    map_geometry,
    plot_raster,
    shared_colour_range,
)
from bananagrid.scenes.examples import example_path  # noqa: E402
from bananagrid.scenes.load import load_scene  # noqa: E402
from bananagrid.scenes.pictures import (  # noqa: E402
    draw_picture,
    picture_layout,
    picture_overview,
    read_picture,
    read_timeline,
)
from PIL import Image  # noqa: E402

from cases import small_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def gaussian_raster(step: float = 2.0, provenance: dict | None = None, sx: float = 25.0, sy: float = 12.0) -> Raster:
    grid = Grid.from_bounds(x=(-100.0, 140.0), y=(-90.0, 90.0), step=step)
    x, y = np.meshgrid(grid.x, grid.y)
    values = np.exp(-0.5 * (((x - 10.0) / sx) ** 2 + (y / sy) ** 2)) / (2.0 * math.pi * sx * sy)
    return Raster(values=values, grid=grid, mass=float(values.sum() * grid.cell_area),
                  provenance={"model": "test", "t": 5.0} if provenance is None else provenance)


def check_png(path, size: tuple[int, int] | None = None) -> np.ndarray:
    """The PNG as an array, ``size`` (width, height) pixels (to the pixel matplotlib's rounding
    may take); not blank: many distinct colours."""
    image = mpimg.imread(path)
    if size is not None:
        assert np.abs(np.subtract(image.shape[1::-1], size)).max() <= 1, (image.shape, size)
    colours = np.unique((image[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 50, len(colours)
    assert float(np.std(image[..., :3])) > 0.05
    return image


def pixels(size_inches: tuple[float, float], dpi: int) -> tuple[int, int]:
    return round(size_inches[0] * dpi), round(size_inches[1] * dpi)


# --- Raster.plot ------------------------------------------------------------------------------


def test_plot_draws_the_regions_labelled_once_each(tmp_path):
    raster = gaussian_raster()
    ax = raster.plot()
    regions = mass_regions(raster)
    for region in regions:
        pieces = [line for line in ax.get_lines() if line.get_gid() == f"mass-contour-{region.probability:g}"]
        assert pieces  # the level's contour is in the figure's data
        # its vertices lie on the boundary density: interpolate the raster there
        xy = np.concatenate([np.column_stack(p.get_data()) for p in pieces]) * 1e3
        i = np.interp(xy[:, 1], raster.y, np.arange(raster.grid.ny))
        j = np.interp(xy[:, 0], raster.x, np.arange(raster.grid.nx))
        near = raster.values[np.round(i).astype(int), np.round(j).astype(int)]
        # within a cell of the line the density is within a cell's gradient of the level:
        # |grad f| h <= f * r h / sigma^2 <= f * 0.5 here (r <= 3.1 sigma, h = 2 m, sigma >= 12 m)
        assert np.allclose(near, region.density, rtol=0.6)
    labels = {t.get_gid(): t.get_text() for t in ax.texts}
    assert labels == {f"mass-label-{r.probability:g}": format_level(r) for r in regions}  # one per level
    assert re.fullmatch(r"50 % · \d\.\d+ km²|50 % · [\d,]+ m²", labels["mass-label-0.5"])
    assert ax.get_xlabel() == "x east [km]" and ax.get_ylabel() == "y north [km]"
    assert ax.get_title() == "test, t = 5 s"
    floor, top = ax.images[0].get_clim()
    assert floor == pytest.approx(math.log10(regions[-1].density) - FLOOR_DECADES)
    assert top == pytest.approx(math.log10(raster.peak))
    # km axes, north up, framed on the 99 % region, equal aspect
    x0, x1, y0, y1 = map_frame(raster)
    assert ax.get_xlim() == pytest.approx((x0 / 1e3, x1 / 1e3)) and ax.get_ylim() == pytest.approx((y0 / 1e3, y1 / 1e3))
    assert ax.get_aspect() == 1.0
    assert ax.images[0].origin == "lower"
    bar = ax.child_axes[0]
    assert bar.get_ylabel() == "log10 density [m⁻²]"
    ax.figure.savefig(tmp_path / "a.png", dpi=50)
    check_png(tmp_path / "a.png", pixels(tuple(ax.figure.get_size_inches()), 50))
    plt.close(ax.figure)


def test_plot_on_given_axes_with_levels_title_and_time():
    figure, ax = plt.subplots(figsize=(4, 3))
    raster = gaussian_raster()
    assert raster.plot(ax, mass_levels=[0.9, 0.5], t=7200.0, colorbar=False) is ax
    assert ax.get_title() == "test, t = 7200 s (2 h)"
    assert sorted(t.get_gid() for t in ax.texts) == ["mass-label-0.5", "mass-label-0.9"]
    assert not ax.child_axes
    raster.plot(ax, title="mine")
    assert ax.get_title() == "mine"
    plt.close(figure)


def test_levels_tied_on_a_coarse_grid_share_one_line_and_label():
    grid = Grid.from_bounds(x=(0.0, 50.0), y=(0.0, 50.0), step=10.0)
    values = np.full((5, 5), 1e-6)
    values[2, 2] = 0.5 / 100.0  # one cell holds half the mass, the rest share the remainder
    values[values < 1e-3] = (1.0 - 0.5) / (24 * 100.0)
    raster = Raster(values=values, grid=grid, mass=1.0)
    regions = mass_regions(raster)
    assert regions[1].density == regions[3].density  # 90, 95 and 99 % are the whole grid
    ax = raster.plot()
    labels = [t.get_text() for t in ax.texts]
    assert "90, 95, 99 % · 2,500 m²" in labels and not [t for t in labels if t.startswith(("95", "99"))]
    assert {line.get_gid() for line in ax.get_lines()} <= {"mass-contour-0.5", "mass-contour-0.9"}
    plt.close(ax.figure)


def test_the_geometry_a_provenance_names_is_drawn():
    """A bearing fix's sensors, bearings, wedges and fix, as the recording draws them; points
    beyond the frame named in the x label with the way to them."""
    provenance = {"model": "BearingFix", "variant": "exact",
                  "sensor0_x": -5000.0, "sensor0_y": 0.0, "bearing0": math.pi / 2, "sigma0": 0.01,
                  "sensor1_x": 10.0, "sensor1_y": 20.0, "bearing1": math.pi, "sigma1": 0.02,
                  "fix_x": 10.0, "fix_y": 0.0}
    ax = gaussian_raster(provenance=provenance).plot()
    gids = [line.get_gid() for line in ax.get_lines()]
    for k in (0, 1):
        assert gids.count(f"bearing-{k}") == 1 and gids.count(f"bearing-{k}-wedge") == 2
    assert "marker-fix" in gids and "marker-sensor 1" in gids and "marker-sensor 0" not in gids
    bearing = next(line for line in ax.get_lines() if line.get_gid() == "bearing-0")
    (xa, xb), (ya, yb) = bearing.get_data()
    assert (xa, ya) == (-5.0, 0.0) and xb > 0.0 and yb == pytest.approx(0.0, abs=1e-9)  # due east, km
    assert "← sensor 0 (-5, 0)" in ax.get_xlabel() and "±2σ" in ax.get_xlabel()
    assert ax.get_title() == "BearingFix (exact)"
    plt.close(ax.figure)


def test_a_models_provenance_names_its_geometry():
    """The keys map_geometry reads are those the models write."""
    fix = bg.BearingFix(sensors=[[0.0, 0.0], [20000.0, 0.0]], bearings=[0.26, -0.39], sigmas=[0.01, 0.02])
    shown = map_geometry(fix.parameters())
    assert [m[2] for m in shown.markers] == ["sensor 0", "sensor 1", "fix"]
    assert shown.markers[2][:2] == pytest.approx(tuple(fix.fix))
    assert np.ravel([b[1:] for b in shown.bearings]) == pytest.approx([0.26, 0.01, -0.39, 0.02])
    cat = bg.CAT(v0=10.0, t=5.0, sigma_a=1.0, sigma_omega=0.1, pose=bg.Pose(origin=(100.0, 50.0), heading=0.5))
    assert map_geometry(cat.parameters()) == type(shown)(markers=((100.0, 50.0, "start"),), heading=(100.0, 50.0, 0.5))
    butterly = bg.Butterly(mean=(1.0, 2.0), cov=[[1e4, 0.0], [0.0, 1e4]], t=60.0, speeds=[1.0], weights=[1.0])
    assert map_geometry(butterly.parameters()).markers == ((1.0, 2.0, "start mean"),)
    assert map_geometry({"model": "x"}) == type(shown)()


def test_markers_and_a_start_heading():
    ax = gaussian_raster(provenance={"model": "CAT", "t": 5.0, "origin_x": 10.0, "origin_y": 0.0, "heading": 0.0}).plot(
        markers=[(20.0, 5.0, "buoy"), (1e5, 0.0, "port")])
    gids = [line.get_gid() for line in ax.get_lines()]
    assert "marker-start" in gids and "marker-buoy" in gids
    assert "→ port (100, 0)" in ax.get_xlabel()
    arrows = [child for child in ax.texts if getattr(child, "arrow_patch", None) is not None]
    assert len(arrows) == 1 and arrows[0].xy[0] == pytest.approx(0.01) and arrows[0].xy[1] > 0.0  # north
    plt.close(ax.figure)


def test_a_tall_frame_is_widened_within_the_grid():
    raster = gaussian_raster(sx=2.0, sy=30.0)
    x0, x1, y0, y1 = map_frame(raster)
    assert (x1 - x0) == pytest.approx(0.6 * (y1 - y0)) and (x0 + x1) / 2 == pytest.approx(11.0, abs=2.0)
    rows, columns, size = figure_layout([map_frame(raster)] * 4)
    assert (rows, columns) == (2, 3) and size[0] <= 16.0  # narrow maps: three to a row


@pytest.mark.parametrize("kwargs, message", [
    ({"mass_levels": [0.5, 1.0]}, r"mass_levels\[1\] = 1\.0: a probability-mass level must lie in \(0, 1\)"),
    ({"markers": [(1.0, 2.0)]}, r"markers\[0\] = .*: expected \(x, y, label\)"),
    ({"markers": [(1.0, math.nan, "a")]}, r"markers\[0\] y"),
    ({"markers": [(1.0, 2.0, 3)]}, r"markers\[0\] label = 3: expected a string"),
    ({"title": 3}, r"title = 3: expected a string or None"),
    ({"t": math.inf}, r"^t = inf"),
    ({"ax": "axes"}, r"ax = str: expected matplotlib Axes or None"),
])
def test_bad_plot_arguments_are_one_line_errors(kwargs, message):
    with pytest.raises(BananagridError, match=message) as info:
        gaussian_raster().plot(**kwargs)
    assert "\n" not in str(info.value)
    plt.close("all")


def test_bad_rasters_are_refused():
    bad = gaussian_raster()
    with pytest.raises(BananagridError, match="finite 2-D array"):
        Raster(values=np.full((3, 3), np.nan), grid=Grid.from_bounds(x=(0, 3), y=(0, 3), step=1.0), mass=1.0).plot()
    with pytest.raises(BananagridError, match="negative"):
        Raster(values=-bad.values, grid=bad.grid, mass=1.0).plot()


# --- notebooks and reprs -----------------------------------------------------------------------


def test_notebook_representations_and_short_reprs():
    raster = gaussian_raster()
    png = raster._repr_png_()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    page = raster._repr_html_()
    assert page.startswith("<div><table>") and "captured mass" in page and "99 % region" in page
    assert "data:image/png;base64," in page
    big = Raster(values=np.zeros((900, 1500)), grid=Grid.from_bounds(x=(0, 6000), y=(0, 3600), step=4.0), mass=0.0)
    assert len(repr(big)) < 300 and "1500 x 900 cells" in repr(big) and "0.0, 0.0" not in repr(big)
    batch = bg.BatchRaster(values=np.zeros((5, 900, 1500)), grids=(big.grid,) * 5, mass=np.ones(5))
    assert len(repr(batch)) < 300 and "array(5, 900, 1500)" in repr(batch)
    plt.close("all")


def test_without_matplotlib_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import_module then raises ImportError
    with pytest.raises(BananagridError, match=r"pip install 'bananagrid\[plot\]'") as info:
        gaussian_raster().plot()
    assert "\n" not in str(info.value)
    assert gaussian_raster()._repr_png_() is None  # a notebook falls back to the HTML
    page = gaussian_raster()._repr_html_()
    assert "<table>" in page and "bananagrid[plot]" in page  # the table stays, saying why


# --- bananagrid plot ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plot") / "pic.toml"
    path.write_text(small_scene("pic", '[layers.a]\nmodel = "cat"\n\n[layers.b]\nmodel = "polar"\n')
                    .replace("t = 5.0\n", "").replace('name = "pic"', 'name = "pic"\ntimes = [2.0, 4.0]'))
    return path


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, scene_file) -> Path:
    """The scene's recording and arrays, as bananagrid run writes them."""
    out = tmp_path_factory.mktemp("run")
    assert cli.main(["run", str(scene_file), "--out", str(out), "--npz", "--quiet"]) == 0
    return out


@pytest.mark.parametrize("source", ["toml", "rrd", "npz"])
def test_plot_command_reads_scenes_recordings_and_arrays(tmp_path, scene_file, recorded, source, capsys):
    given = scene_file if source == "toml" else recorded / f"pic.{source}"
    out = tmp_path / "pic.png"
    assert cli.main(["plot", str(given), "-o", str(out), "--dpi", "40"]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out}"
    picture = read_picture(given)
    assert [(p.layer, p.t) for p in picture.panels] == [("a", 4.0), ("b", 4.0)]  # the last time
    _, columns, size = picture_layout([map_frame(p.raster) for p in picture.panels])
    assert columns == 2
    check_png(out, pixels(size, 40))
    assert not list(tmp_path.glob(".*partial"))
    # every source keeps the provenance that names the geometry (here the start and heading)
    assert map_geometry(picture.panels[0].raster.provenance).markers == ((0.0, 0.0, "start"),)
    # every source gives the same regions as the scene's own map held as the source holds it: the
    # recording in float32, which rounds mirrored cells an ulp apart to one value, and tied cells
    # are all inside a region (in float64 such a pair can split at a level's boundary)
    read = picture.panels[0].raster
    own = read_picture(scene_file).panels[0].raster
    if source == "rrd":
        own = dataclasses.replace(own, values=own.values.astype(np.float32).astype(np.float64))
    assert [format_level(r) for r in mass_regions(read)] == [format_level(r) for r in mass_regions(own)]


def test_plot_picks_layers_a_time_and_a_resolution(tmp_path, scene_file):
    out = tmp_path / "a.png"
    assert cli.main(["plot", str(scene_file), "-o", str(out), "--layer", "a", "--t", "2", "--dpi", "40"]) == 0
    picture = read_picture(scene_file, layers=["a"], t=2.0)
    _, _, size = picture_layout([map_frame(picture.panels[0].raster)])
    check_png(out, pixels(size, 40))
    assert cli.main(["plot", str(scene_file), "-o", str(out), "--layer", "a", "--t", "2", "--dpi", "80"]) == 0
    check_png(out, pixels(size, 80))
    assert [p.layer for p in read_picture(scene_file, layers=["b", "a"]).panels] == ["b", "a"]


def test_plot_example_draws_the_bundled_scene(tmp_path, capsys):
    out = tmp_path / "folding.png"
    assert cli.main(["plot", "--example", "folding", "--step", "200", "-o", str(out), "--dpi", "30"]) == 0
    picture = read_picture(example_path("folding"), step=200.0)
    _, _, size = picture_layout([map_frame(p.raster) for p in picture.panels])
    check_png(out, pixels(size, 30))
    capsys.readouterr()
    assert cli.main(["plot", "x.toml", "--example", "folding", "-o", str(out)]) == 2
    assert 'INPUT x.toml and --example "folding": give one of them, not both' in capsys.readouterr().err
    assert cli.main(["plot", "-o", str(out)]) == 2
    assert "give INPUT or --example NAME" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--layer", "c"], r'--layer "c": not a layer of .*pic\.toml at t = 4 s; choose one of a, b$'),
    (["--t", "3"], r"--t = 3\.0: .* has times 2, 4 s$"),
    (["--t", "nan"], r"--t = nan: expected a finite time in seconds$"),
    (["--mass-levels", "0.5,1.5"], r"--mass-levels\[1\] = 1\.5: a probability-mass level must lie in \(0, 1\)$"),
    (["--mass-levels", "half"], r"--mass-levels = 'half': expected numbers"),
    (["--dpi", "5"], r"--dpi = 5: must be an integer in \[20, 600\]$"),
    (["--step", "0"], r"--step = 0\.0: must be > 0|--step = 0\.0"),
    (["--threads", "0"], r"--threads = 0: must be >= 1$"),
])
def test_bad_plot_arguments_are_one_line_cli_errors(tmp_path, scene_file, capsys, argv, message):
    assert cli.main(["plot", str(scene_file), "-o", str(tmp_path / "x.png"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert re.search(message, err) and "\n" not in err, err
    assert not list(tmp_path.iterdir())


def test_plot_refuses_other_inputs_outputs_and_array_scenes(tmp_path, scene_file, capsys):
    def error(*argv: str) -> str:
        assert cli.main(["plot", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err
        return err

    assert "cannot plot a .tif file; give one of .toml, .rrd, .npz, .nc" in error(str(tmp_path / "x.tif"), "-o", str(tmp_path / "x.png"))
    assert "no such file" in error(str(tmp_path / "x.rrd"), "-o", str(tmp_path / "x.png"))
    assert "give a name ending in .png" in error(str(scene_file), "-o", str(tmp_path / "x.jpg"))
    assert "cannot write there" in error(str(scene_file), "-o", str(tmp_path / "missing" / "x.png"))
    assert "an [array] scene maps angular cells, not a grid" in error(
        str(ROOT / "scenes" / "room_mixture.toml"), "-o", str(tmp_path / "x.png"))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert "not an .npz written by bananagrid run --npz" in error(str(tmp_path / "junk.npz"), "-o", str(tmp_path / "x.png"))
    (tmp_path / "junk.nc").write_bytes(b"not a NetCDF file")
    assert "junk.nc: not a NetCDF file" in error(str(tmp_path / "junk.nc"), "-o", str(tmp_path / "x.png"))
    assert not list(tmp_path.glob("*.png"))


# --- the gallery's pictures --------------------------------------------------------------------


def test_gallery_pictures_are_made_from_every_grid_scene(tmp_path):
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import make_pictures
    finally:
        sys.path.pop(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the poor crossing's warning at load
        grid_scenes = {path.stem for path in (ROOT / "scenes").glob("*.toml")
                       if load_scene(path).gridded}
    assert set(make_pictures.PICTURED) == grid_scenes
    gallery = (ROOT / "docs" / "gallery.md").read_text()
    shown = [f"docs/{path}" for path in re.findall(r"!\[[^\]]+\]\((pictures/[\w-]+\.png)\)", gallery)]
    assert sorted(shown) == sorted(f"docs/pictures/{name}.png" for name in make_pictures.PICTURED)
    total = 0
    for picture in shown:
        check_png(ROOT / picture)
        total += (ROOT / picture).stat().st_size
    assert total < 500_000
    # the script draws a scene like the committed picture (same size: same layout and dpi)
    run = subprocess.run([sys.executable, str(ROOT / "docs" / "make_pictures.py"), "rice_isotropic", "--out",
                          str(tmp_path)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    made = check_png(tmp_path / "rice_isotropic.png")
    assert made.shape == mpimg.imread(ROOT / "docs" / "pictures" / "rice_isotropic.png").shape


# --- panels side by side: one colour range, one colour bar, a key to the contour colours ------


def test_panels_share_one_colour_range_one_bar_and_one_key(scene_file):
    """Side by side, every map is drawn in the union of the panels' own ranges (so a colour
    means one density in every panel), with one colour bar; the key names each level in the
    colour its contours are drawn in."""
    picture = read_picture(scene_file, t=2.0)
    levels = picture.mass_levels
    extents = [map_frame(p.raster, levels) for p in picture.panels]
    own = [colour_range(p.raster, levels) for p in picture.panels]
    assert own[0] != own[1]  # the layers differ: a shared range is a choice, not a coincidence
    figure = plt.figure(figsize=picture_layout(extents)[2], layout="constrained")
    axes = draw_picture(figure, picture, levels, clim=shared_colour_range(own), extents=extents)
    union = (min(r[0] for r in own), max(r[1] for r in own))
    assert [ax.images[0].get_clim() for ax in axes] == [pytest.approx(union)] * len(axes)
    bars = [ax for ax in figure.axes if ax.get_ylabel() == "log10 density [m⁻²]"]
    assert len(bars) == 1 and not any(ax.child_axes for ax in axes)
    (key,) = figure.legends
    assert [t.get_text() for t in key.get_texts()] == [f"{100 * p:g} % region" for p in levels]
    for handle, level in zip(key.legend_handles, levels):
        drawn = {line.get_color() for line in axes[0].get_lines() if line.get_gid() == f"mass-contour-{level:g}"}
        assert drawn in ({handle.get_color()}, set())  # an unreached level draws nothing
        assert handle.get_color() == MASS_COLOURS[list(levels).index(level) % len(MASS_COLOURS)]
    plt.close(figure)


def test_a_single_map_has_the_key_in_it():
    ax = gaussian_raster().plot()
    legend = ax.get_legend()
    assert [t.get_text() for t in legend.get_texts()] == ["50 % region", "90 % region", "95 % region", "99 % region"]
    plt.close(ax.figure)


# --- charts of geographic scenes --------------------------------------------------------------


@pytest.fixture(scope="module")
def coast_scene(tmp_path_factory) -> Path:
    """A geographic scene off Bergen whose map reaches the coast (Sotra, 5 to 20 km east)."""
    path = tmp_path_factory.mktemp("coast") / "coast.toml"
    path.write_text("""\
[scene]
name = "coast"
times = [600.0, 1200.0]

[geo]
origin_latlon = [60.35, 4.90]
time = "2026-11-24T23:50:00Z"

[grid]
x = [-15000.0, 15000.0]
y = [-15000.0, 15000.0]
step = 500.0

[layers.drift]
model = "butterly"
mean_latlon = [60.35, 4.90]
sigma_x = 500.0
sigma_y = 500.0
speed_law = "normal"
speed_mean = 5.0
speed_sd = 2.0
course_kappa = 1.0
course_mean_deg = 90.0
""")
    return path


@pytest.fixture(scope="module")
def coast_picture(coast_scene):
    return read_picture(coast_scene)


def test_a_geographic_map_is_a_chart_from_bundled_land_offline(coast_picture, monkeypatch):
    """Graticule lines with latitude and longitude labels where they cross the edges, the land
    filled from the bundled data with sockets refused, a scale bar, and the UTC time (the
    scene's time + t, past midnight here) in the title."""
    picture = coast_picture
    panel = picture.panels[0]
    assert panel.raster.frame is not None

    def refuse(*args, **kwargs):
        raise AssertionError("the chart tried to use the network")

    monkeypatch.setattr(socket, "socket", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    extents = [map_frame(panel.raster, picture.mass_levels)]
    figure = plt.figure(figsize=picture_layout(extents)[2], layout="constrained")
    (ax,) = draw_picture(figure, picture, picture.mass_levels, clim=colour_range(panel.raster), extents=extents)
    assert ax.get_title().splitlines() == ["drift (Butterly), t = 1200 s (20 min)", "2026-11-25 00:10:00 UTC"]
    land = [p for p in ax.patches if p.get_gid() == "land"]
    assert len(land) == 1 and len(land[0].get_path().vertices) > 100
    # inland Store Sotra (60.25 N, 5.05 E) is inside the drawn land, the origin at sea is not
    x, y = panel.raster.frame.local(60.25, 5.05)
    assert land[0].get_path().contains_point((float(x) / 1e3, float(y) / 1e3))
    assert not land[0].get_path().contains_point((0.0, 0.0))
    drawn = chart(panel.raster.frame, extents[0], land=False)
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == [t.label for t in drawn.ticks if t.edge == "bottom"] and all(s.endswith("E") for s in labels)
    assert ax.get_xticks() == pytest.approx([t.position / 1e3 for t in drawn.ticks if t.edge == "bottom"])
    assert [t.get_text() for t in ax.get_yticklabels()] == [t.label for t in drawn.ticks if t.edge == "left"]
    gids = {line.get_gid() for line in ax.get_lines()}
    assert {f"graticule-{line.kind}-{line.value:.10g}" for line in drawn.lines} <= gids
    assert any(getattr(a, "get_gid", lambda: None)() == "scale-bar" for a in ax.artists)
    assert "km" not in ax.get_xlabel()
    plt.close(figure)


@pytest.mark.parametrize("t, utc", [(0.0, "2026-11-24 23:50:00 UTC"), (600.0, "2026-11-25 00:00:00 UTC"),
                                    (90061.5, "2026-11-26 00:51:01 UTC")])
def test_titles_carry_the_utc_time(coast_picture, t, utc):
    """The frame's time plus t, to the whole second below (the scene's time is
    2026-11-24T23:50:00Z; 90061.5 s is a day, an hour, a minute and 1.5 s)."""
    ax = coast_picture.panels[0].raster.plot(t=t)
    assert ax.get_title().splitlines()[-1] == utc
    plt.close(ax.figure)


# --- animations -------------------------------------------------------------------------------


def test_animate_writes_one_gif_frame_per_time(tmp_path, coast_scene, capsys):
    out = tmp_path / "coast.gif"
    assert cli.main(["plot", str(coast_scene), "--animate", str(out), "--dpi", "30", "--fps", "4"]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip() == f"wrote {out} (2 frames)"
    assert captured.err.splitlines() == ["frame 1/2: t = 600 s", "frame 2/2: t = 1200 s"]
    frames = read_timeline(coast_scene)
    extents = [map_frame(p.raster) for p in frames[0].panels]
    with Image.open(out) as gif:
        assert gif.format == "GIF" and gif.n_frames == 2
        assert gif.info["duration"] == 250  # ms: 4 frames per second
        # every frame at the picture's size (frames are framed on the union over the timeline)
        union = [(min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                 for a, b in zip(extents, [map_frame(p.raster) for p in frames[1].panels])]
        assert abs(gif.size[0] - pixels(picture_layout(union)[2], 30)[0]) <= 1
        pictures = []
        for k in range(gif.n_frames):
            gif.seek(k)
            pictures.append(np.asarray(gif.convert("RGB"), dtype=float))
        assert np.abs(pictures[0] - pictures[1]).mean() > 1.0  # the frames differ: time moves
    assert not list(tmp_path.glob(".*partial"))


def test_timeline_frames_hold_every_layer_at_its_time(scene_file):
    frames = read_timeline(scene_file)
    assert [[(p.layer, p.t) for p in f.panels] for f in frames] == [[("a", 2.0), ("b", 2.0)], [("a", 4.0), ("b", 4.0)]]
    assert [[p.layer for p in f.panels] for f in read_timeline(scene_file, layers=["b"])] == [["b"], ["b"]]


@pytest.mark.parametrize("argv, message", [
    (["--animate", "{tmp}/x.avi"], r"--animate .*x\.avi: an animation is a GIF or an MP4; give a name ending in \.gif or \.mp4$"),
    (["--animate", "{tmp}/x.gif", "--fps", "0"], r"--fps = 0\.0: frames per second must lie in \(0, 50\]$"),
    (["--animate", "{tmp}/x.gif", "--fps", "-2"], r"--fps = -2\.0: frames per second must lie in \(0, 50\]$"),
    (["--animate", "{tmp}/x.gif", "--fps", "nan"], r"--fps = nan: frames per second"),
    (["--animate", "{tmp}/x.gif", "--fps", "100"], r"--fps = 100\.0: frames per second must lie in \(0, 50\]$"),
    (["--animate", "{tmp}/x.gif", "--t", "2"], r"--t = 2: an animation shows every time"),
    (["--animate", "{tmp}/missing/x.gif"], r"cannot write there"),
    ([], r"plot: nothing to write; give -o OUT\.png, --animate OUT\.gif, or both$"),
])
def test_bad_animation_arguments_are_one_line_cli_errors(tmp_path, scene_file, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert cli.main(["plot", str(scene_file), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert re.search(message, err) and "\n" not in err, err
    assert not list(tmp_path.iterdir())


def test_mp4_without_ffmpeg_is_refused_naming_it(tmp_path, scene_file, capsys, monkeypatch):
    monkeypatch.setitem(matplotlib.rcParams, "animation.ffmpeg_path", "ffmpeg-that-is-not-installed")
    assert cli.main(["plot", str(scene_file), "--animate", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err.strip()
    assert "writing MP4 needs ffmpeg, which is not on PATH" in err and "\n" not in err
    assert not list(tmp_path.iterdir())


def test_stations_beyond_a_chart_are_named_with_their_positions():
    """geo_bearing's stations, Marstein (60.1279 N, 5.0086 E) and Hellisoy (60.7517 N,
    4.7131 E), lie 38 and 49 km off its map: named at the edge in degrees and minutes."""
    picture = read_picture(example_path("geo_bearing"), step=500.0, layers=["exact"])
    panel = picture.panels[0]
    ax = panel.raster.plot()  # a raster with a frame is drawn as a chart
    label = " ".join(ax.get_xlabel().split())
    assert "↘ sensor 0 60°07.7′N 5°00.5′E" in label and "↗ sensor 1 60°45.1′N 4°42.8′E" in label
    plt.close(ax.figure)


def test_mp4_frames_go_to_ffmpeg_one_per_time(tmp_path, scene_file, capsys, monkeypatch):
    """Where ffmpeg is, each frame is piped to it as raw RGBA at the figure's size, for H.264 in
    yuv420p padded to even sides, into a temporary name renamed when ffmpeg is done. The ffmpeg
    here is a stand-in that keeps what it is sent: the real one is not in the test install."""
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text(f"#!{sys.executable}\n" + textwrap.dedent("""\
        import json, sys
        args = sys.argv[1:]
        data = sys.stdin.buffer.read()
        with open(args[-1], "wb") as out:
            out.write(data)
        with open(args[-1] + ".args.json", "w") as out:
            json.dump(args, out)
    """))
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake.parent}{os.pathsep}{os.environ['PATH']}")
    out = tmp_path / "pic.mp4"
    assert cli.main(["plot", str(scene_file), "--animate", str(out), "--dpi", "30"]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out} (2 frames)"
    (args_file,) = tmp_path.glob(".pic.mp4.*.partial.args.json")  # ffmpeg wrote the temporary name
    args = json.loads(args_file.read_text())
    width, height = (int(v) for v in args[args.index("-s") + 1].split("x"))
    assert out.stat().st_size == 2 * width * height * 4  # two frames of RGBA
    assert args[args.index("-pix_fmt", args.index("-i")) + 1] == "yuv420p"
    assert "pad=ceil(iw/2)*2:ceil(ih/2)*2" in args and args[args.index("-f", args.index("-i")) + 1] == "mp4"


@pytest.mark.parametrize("zoom", [1.0, 4.0, 30.0])
def test_contour_labels_never_overlap(zoom):
    """However small the regions in the frame (an animation frames its first times on the
    last's extent), the labels shown overlap neither each other nor a marker's name; in the
    map's own frame every level keeps its label."""
    raster = gaussian_raster(provenance={"model": "test", "t": 5.0, "origin_x": 10.0, "origin_y": 0.0})
    x0, x1, y0, y1 = map_frame(raster)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    extent = (cx - zoom * (cx - x0), cx + zoom * (x1 - cx), cy - zoom * (cy - y0), cy + zoom * (y1 - cy))
    figure, ax = plt.subplots(figsize=figure_layout([map_frame(raster)])[2], layout="constrained")  # as .plot()
    plot_raster(raster, ax, extent=extent)
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    shown = [t for t in ax.texts if t.get_visible() and t.get_text()]
    labels = [t for t in shown if (t.get_gid() or "").startswith("mass-label-")]
    if zoom == 1.0:
        assert len(labels) == 4
    boxes = [t.get_window_extent(renderer) for t in shown]
    for i in range(len(boxes)):
        for j in range(i):
            assert not boxes[i].overlaps(boxes[j]), (shown[i].get_text(), shown[j].get_text())
    if zoom == 30.0:
        assert len(labels) < 4  # a dot of a map: its labels would overlap; the key names the colours
    plt.close(figure)


def test_a_chart_that_leaves_out_its_stations_gets_an_overview(coast_picture):
    """geo_bearing's maps leave out both stations: a last panel shows the coast, the stations
    by name (on land: Marstein and Hellisoy are lighthouses on islets), their bearings, and
    each map's frame as a rectangle."""
    picture = read_picture(example_path("geo_bearing"), step=500.0)
    extents = [map_frame(p.raster) for p in picture.panels]
    overview = picture_overview(picture, extents)
    assert overview is not None
    extent, drawn, geometry = overview
    assert {label for _, _, label in geometry.markers} == {"sensor 0", "sensor 1", "fix"}
    for x, y, _ in geometry.markers:
        assert extent[0] < x < extent[1] and extent[2] < y < extent[3]
    figure = plt.figure(figsize=picture_layout(extents + [extent])[2], layout="constrained")
    draw_picture(figure, picture, picture.mass_levels, clim=colour_range(picture.panels[0].raster),
                 extents=extents, overview=overview)
    (ax,) = [a for a in figure.axes if a.get_gid() == "overview"]
    gids = [line.get_gid() for line in ax.get_lines()]
    assert {"marker-sensor 0", "marker-sensor 1", "marker-fix", "bearing-0", "bearing-1"} <= set(gids)
    frames = [p for p in ax.patches if (p.get_gid() or "").startswith("overview-frame-")]
    assert [(p.get_x() * 1e3, p.get_y() * 1e3) for p in frames] == [pytest.approx((e[0], e[2])) for e in extents]
    (land,) = [p for p in ax.patches if p.get_gid() == "land"]
    frame = picture.panels[0].raster.frame
    marstein = frame.local(60.1279, 5.0086)
    path = land.get_path()
    # the islet is below the bundled land's 220 m simplification; the coast is within 2 km of it
    near = np.hypot(path.vertices[:, 0] - marstein[0] / 1e3, path.vertices[:, 1] - marstein[1] / 1e3).min()
    assert near < 2.0
    plt.close(figure)
    # maps that hold every point they name (the coast scene's start mean) have none
    assert picture_overview(coast_picture, [map_frame(p.raster) for p in coast_picture.panels]) is None
