"""Pictures without a viewer: Raster.plot, the notebook representations, bananagrid plot on
scenes, recordings and arrays, and the README's pictures."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bananagrid import BananagridError, Raster, cli  # noqa: E402
from bananagrid.contours import format_level, mass_regions  # noqa: E402
from bananagrid.domains.grid import Grid  # noqa: E402

from cases import small_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def gaussian_raster(step: float = 2.0) -> Raster:
    grid = Grid.from_bounds(x=(-100.0, 140.0), y=(-90.0, 90.0), step=step)
    x, y = np.meshgrid(grid.x, grid.y)
    sx, sy = 25.0, 12.0
    values = np.exp(-0.5 * (((x - 10.0) / sx) ** 2 + (y / sy) ** 2)) / (2.0 * math.pi * sx * sy)
    return Raster(values=values, grid=grid, mass=float(values.sum() * grid.cell_area), provenance={"model": "test", "t": 5.0})


def check_png(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """The PNG as an array; not blank: many distinct colours."""
    image = mpimg.imread(path)
    if size is not None:
        assert image.shape[1::-1] == size
    colours = np.unique((image[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 50, len(colours)
    return image


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
    texts = [t.get_text() for t in ax.texts]
    assert texts == [format_level(r) for r in regions]
    assert ax.get_xlabel() == "x east [km]" and ax.get_ylabel() == "y north [km]"
    assert ax.get_title() == "test, t = 5 s"
    assert ax.images[0].get_clim()[0] == pytest.approx(math.log10(regions[-1].density) - 2.0)
    ax.figure.savefig(tmp_path / "a.png", dpi=50)
    plt.close(ax.figure)
    check_png(tmp_path / "a.png", (350, 250))  # 7 x 5 in at 50 dpi


def test_notebook_representations_and_a_short_repr():
    raster = gaussian_raster()
    png = raster._repr_png_()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    page = raster._repr_html_()
    assert "<table>" in page and "captured mass" in page and "99 % region" in page and "data:image/png;base64," in page
    big = Raster(values=np.zeros((900, 1500)), grid=Grid.from_bounds(x=(0, 6000), y=(0, 3600), step=4.0), mass=0.0)
    assert len(repr(big)) < 300 and "1500 x 900 cells" in repr(big) and "0.0, 0.0" not in repr(big)
    plt.close("all")


def test_without_matplotlib_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import_module then raises ImportError
    with pytest.raises(BananagridError, match=r"pip install 'bananagrid\[plot\]'"):
        gaussian_raster().plot()
    assert "bananagrid[plot]" in gaussian_raster()._repr_html_()  # the table stays, saying why


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plot") / "pic.toml"
    path.write_text(small_scene("pic", '[layers.a]\nmodel = "cat"\n\n[layers.b]\nmodel = "polar"\n')
                    .replace("t = 5.0\n", "").replace('name = "pic"', 'name = "pic"\ntimes = [2.0, 4.0]'))
    return path


@pytest.mark.parametrize("source", ["toml", "rrd", "npz"])
def test_plot_command_reads_scenes_recordings_and_arrays(tmp_path, scene_file, source, capsys):
    if source == "toml":
        given = scene_file
    else:
        assert cli.main(["run", str(scene_file), "--out", str(tmp_path), "--npz", "--quiet"]) == 0
        given = tmp_path / f"pic.{source}"
    out = tmp_path / "pic.png"
    assert cli.main(["plot", str(given), "-o", str(out), "--dpi", "40"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    check_png(out, (int(5.5 * 2 * 40), int(4.2 * 40)))  # two panels side by side
    assert not list(tmp_path.glob(".*partial"))


def test_plot_picks_a_layer_and_a_time(tmp_path, scene_file):
    out = tmp_path / "a.png"
    assert cli.main(["plot", str(scene_file), "-o", str(out), "--layer", "a", "--t", "2", "--dpi", "40"]) == 0
    check_png(out, (int(5.5 * 40), int(4.2 * 40)))


@pytest.mark.parametrize("argv, message", [
    (["--layer", "c"], r'--layer "c": not a layer of .* at t = 4 s; choose one of a, b'),
    (["--t", "3"], r"--t = 3\.0: .* has times 2, 4 s"),
    (["--mass-levels", "0.5,1.5"], r"--mass-levels\[1\] = 1\.5: a probability-mass level must lie in \(0, 1\)"),
    (["--mass-levels", "half"], r"--mass-levels = 'half': expected numbers"),
    (["--dpi", "5"], r"--dpi = 5: must be an integer in \[20, 600\]"),
])
def test_bad_plot_arguments_are_one_line_errors(tmp_path, scene_file, capsys, argv, message):
    assert cli.main(["plot", str(scene_file), "-o", str(tmp_path / "x.png"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert re.search(message, err) and "\n" not in err
    assert not (tmp_path / "x.png").exists()


def test_plot_refuses_other_inputs_and_array_scenes(tmp_path, capsys):
    assert cli.main(["plot", str(tmp_path / "x.nc"), "-o", str(tmp_path / "x.png")]) == 2
    assert "cannot plot a .nc file; give one of .toml, .rrd, .npz" in capsys.readouterr().err
    assert cli.main(["plot", str(ROOT / "scenes" / "room_mixture.toml"), "-o", str(tmp_path / "x.png")]) == 2
    assert "an [array] scene maps angular cells, not a grid" in capsys.readouterr().err


def test_readme_pictures_exist_and_the_script_makes_them():
    readme = (ROOT / "README.md").read_text()
    shown = re.findall(r"!\[[^\]]*\]\((docs/pictures/[\w-]+\.png)\)", readme)
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import make_pictures
    finally:
        sys.path.pop(0)
    assert sorted(shown) == sorted(f"docs/pictures/{name}.png" for name in make_pictures.PICTURED)
    for picture in shown:
        check_png(ROOT / picture)
    # the script draws a scene like the committed picture (same size: same layout and dpi)
    committed = mpimg.imread(ROOT / "docs" / "pictures" / "folding.png").shape
    run = subprocess.run([sys.executable, str(ROOT / "docs" / "make_pictures.py"), "folding"], capture_output=True,
                         text=True, timeout=300, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    assert mpimg.imread(ROOT / "docs" / "pictures" / "folding.png").shape == committed
