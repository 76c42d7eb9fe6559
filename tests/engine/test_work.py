"""Work before it starts: models estimate their computing, enormous work is refused in one line
before any launch, and the CAT scan stays in the domain where its proof holds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid import BananagridError, cli
from bananagrid.engine import warp_runtime
from bananagrid.engine.grid_kernel import GridExtent
from bananagrid.engine.points import PointsExtent
from bananagrid.engine.work import DEFAULT_MAX_SECONDS, check_work, format_duration, work_limit
from bananagrid.models.cat import MAX_NODES, NODE_SPACING, SECONDS_PER_FLAGGED_NODE, scan_node_count, scan_nodes
from bananagrid.scenes.examples import example_names, example_path
from bananagrid.scenes.load import load_scene
from bananagrid.scenes.run import check_run_work

#: A CAT whose turn-rate SD is 25,000 rad over t: 4,000,001 scan nodes. On WILD_GRID its map
#: took 9.2-9.9 h of one core (rows at y = 0 and 500 m, each 17-18 s of process CPU time; Intel
#: Xeon AVX-512), so that even two threads need over 4 h: enormous work on any CPU.
WILD_CAT = dict(v0=8.0, t=100.0, sigma_a=0.05, sigma_omega=250.0)
WILD_GRID = dict(x=(-1000.0, 1000.0), y=(-1000.0, 1000.0), step=1.0)  # 2000 x 2000 cells


def no_launch(monkeypatch):
    """Make any kernel launch fail the test: the refusal must come first."""
    monkeypatch.setattr(warp_runtime.WarpContext, "launch",
                        lambda *a, **k: pytest.fail("a kernel was launched"))


def test_rasterise_refuses_enormous_work_before_any_launch(monkeypatch):
    model = bg.CAT(**WILD_CAT)
    grid = bg.Grid.from_bounds(WILD_GRID["x"], WILD_GRID["y"], WILD_GRID["step"])
    estimate = model.work_estimate(grid.nx * grid.ny, GridExtent(grid))
    # above the 9.9 h measured (WILD_CAT), and so above the limit on 2 threads
    assert estimate > 9.9 * 3600 > 2 * DEFAULT_MAX_SECONDS
    no_launch(monkeypatch)
    with pytest.raises(BananagridError) as error:
        bg.rasterise(model, grid, threads=2)
    message = str(error.value)
    assert message.startswith("CAT: rasterise on a grid of 2000 x 2000 = 4,000,000 cells would take about ")
    assert "more than the 1 h allowed" in message and "max_seconds=S to allow more" in message
    assert "\n" not in message


def test_max_seconds_raises_and_lowers_the_limit(monkeypatch):
    model = bg.CAT(v0=8.0, t=60.0, sigma_a=0.02, sigma_omega=math.radians(0.5))
    grid = bg.Grid.from_bounds((-400.0, 800.0), (-400.0, 800.0), 12.0)
    assert bg.rasterise(model, grid, max_seconds=math.inf).mass > 0.9
    with pytest.raises(BananagridError, match="more than the 1e-06 s allowed"):
        bg.rasterise(model, grid, max_seconds=1e-6)
    lattice = bg.PolarLattice(ranges=(0.0, 600.0), range_step=20.0, bearings=(-math.pi, math.pi),
                              bearing_step=math.pi / 90, pose=model.pose)
    with pytest.raises(BananagridError, match=r"CAT: a polar lattice of .* quadrature nodes\) would take"):
        bg.rasterise(model, lattice, max_seconds=1e-6)


def test_run_refuses_a_scene_above_the_limit_before_computing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "run_scene", lambda *a, **k: pytest.fail("run_scene was called"))
    out = tmp_path / "out"
    code = cli.main(["run", "scenes/figure1.toml", "--out", str(out), "--max-seconds", "0.01", "--threads", "2"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("bananagrid: error: scenes/figure1.toml: 3 layer maps of 1,350,000 cells would take about ")
    assert err[0].endswith("on 2 CPU threads (estimate), more than the 0.01 s allowed: use coarser cells, a smaller "
                           "grid or gentler parameters, or --max-seconds S to allow more")
    assert not out.exists()


def test_a_refused_scene_leaves_nothing_and_computes_nothing(tmp_path, capsys, monkeypatch):
    scene = tmp_path / "wild.toml"
    scene.write_text(
        '[scene]\nname = "wild"\n[grid]\nx = [-1000, 1000]\ny = [-1000, 1000]\nstep = 1\n'
        "[layers.cat]\nmodel = \"cat\"\nv0 = 8\nt = 100\nsigma_a = 0.05\nsigma_omega = 250\n"
    )
    no_launch(monkeypatch)
    out = tmp_path / "out"
    out.mkdir()
    assert cli.main(["run", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"bananagrid: error: {scene}: 1 layer map of 4,000,000 cells would take about ")
    assert "--max-seconds S" in err[-1]
    assert list(out.iterdir()) == []


@pytest.mark.filterwarnings("ignore:bearings cross at")  # a bundled scene shows a poor crossing on purpose
def test_no_bundled_scene_is_refused_and_every_estimate_is_positive():
    for name in example_names():
        scene = load_scene(example_path(name))
        if not scene.gridded:
            assert check_run_work(scene) is None
            continue
        seconds = check_run_work(scene, threads=1)
        assert 0.0 < seconds < DEFAULT_MAX_SECONDS / 10, name  # far below the limit on one core


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    k=st.floats(1.0, 38.0),
    turn=st.floats(1e-12, 1e6),  # sigma_omega t, rad
    t=st.floats(1e-3, 1e9),
)
def test_the_scan_nodes_are_never_wider_than_the_spacing_the_proof_needs(k, turn, t):
    """The kernel's bounds settle every node interval only when nodes are at most NODE_SPACING
    apart in omega t (kernels/cat.py); a scan that would need more than MAX_NODES is refused."""
    sigma_omega = turn / t
    n = scan_node_count(k, sigma_omega, t)
    if n > MAX_NODES:
        with pytest.raises(BananagridError, match="sigma_omega = .* nodes, above 4,194,304"):
            bg.CAT(v0=1.0, t=t, sigma_a=1.0, sigma_omega=sigma_omega, k_sigma=k)
        return
    model = bg.CAT(v0=1.0, t=t, sigma_a=1.0, sigma_omega=sigma_omega, k_sigma=k)
    nodes = scan_nodes(model)
    assert len(nodes) == n
    # np.diff of nodes k sigma_omega wide, n of them: each difference carries about n ulps of the
    # spacing (n <= 2^22: below 1e-9 relative); the kernel's bounds use the actual widths
    assert np.max(np.diff(nodes)) * t <= NODE_SPACING * (1.0 + 1e-9)


def test_the_scan_domain_is_refused_with_the_numbers():
    with pytest.raises(BananagridError) as error:
        bg.CAT(v0=8.0, t=9.2e18, sigma_a=0.05, sigma_omega=0.01)
    message = str(error.value)
    assert message.startswith("sigma_omega = 0.01 rad/s: over t = 9.2e+18 s the turn-rate SD is sigma_omega t = "
                              "9.2e+16 rad")
    assert "(k_sigma sigma_omega t <= 209,715 rad)" in message


def test_the_estimate_follows_the_work_sizes():
    narrow = bg.CAT(v0=8.0, t=100.0, sigma_a=0.05, sigma_omega=0.001)
    wide = bg.CAT(v0=8.0, t=100.0, sigma_a=0.05, sigma_omega=1.0)
    extent = GridExtent(bg.Grid.from_bounds((-1000.0, 1000.0), (-1000.0, 1000.0), 10.0))
    # 64 nodes against 16,001: the scan term dominates
    assert wide.work_estimate(1000, extent) > 50 * narrow.work_estimate(1000, extent)
    assert narrow.work_estimate(2000, extent) == pytest.approx(2 * narrow.work_estimate(1000, extent))
    one = bg.Butterly(mean=(0, 0), cov=[[100.0, 0], [0, 100.0]], speeds=[1.0], t=100.0)
    many = bg.Butterly(mean=(0, 0), cov=[[100.0, 0], [0, 100.0]], speeds=list(np.linspace(1, 2, 50)),
                        weights=[0.02] * 50, t=100.0)
    assert many.work_estimate(1000, extent) > 5 * one.work_estimate(1000, extent)


class SameRadii:
    """An extent (not a grid's) with another extent's radii."""

    def __init__(self, extent):
        self.radii = extent.radii


def square_grid(centre, half: float, n: int) -> bg.Grid:
    """n x n cells over centre +- half."""
    return bg.Grid(origin=(centre[0] - half, centre[1] - half), dx=2 * half / n, dy=2 * half / n, nx=n, ny=n)


@seed(20261127)
@settings(max_examples=300, deadline=None)
@given(
    turn=st.floats(1e-3, 2.5e4),  # sigma_omega t, rad: 64 to 4,000,001 scan nodes
    more=st.floats(1.0, 30.0),
    sigma_a=st.floats(1e-3, 50.0),
    t=st.floats(1.0, 1e4),
    half=st.floats(1e-2, 1e5),
    n=st.integers(1, 3000),
    away=st.floats(0.0, 1e6),
)
def test_the_grid_estimate_grows_with_the_scan_the_cells_and_nearness(turn, more, sigma_a, t, half, n, away):
    """The CAT's grid estimate (the row sweep) grows with the scan's nodes, is proportional to the
    cells of whole rows, grows with the grid's rows, and is largest about the pose (where every
    node interval is searched); with 64 columns or more it is below the same cells' estimate as
    points (the per-point scan the sweep replaces)."""
    narrow = bg.CAT(v0=10.0, t=t, sigma_a=sigma_a, sigma_omega=turn / t)
    wide = bg.CAT(v0=10.0, t=t, sigma_a=sigma_a, sigma_omega=min(turn * more, 2.5e4) / t)
    near = square_grid((0.0, 0.0), half, n)
    far = square_grid((away, 0.0), half, n)
    cells = n * n
    for model in (narrow, wide):
        at_pose = model.work_estimate(cells, GridExtent(near))
        assert 0.0 < at_pose < math.inf
        # proportional to the cells (a share of the rows: tiles of it), to rounding (1e-12: a few ulps)
        assert model.work_estimate(n, GridExtent(near)) == pytest.approx(at_pose / n, rel=1e-12)
        assert model.work_estimate(cells, GridExtent(far)) <= at_pose * (1 + 1e-12)  # 1e-12: a few ulps
        taller = bg.Grid(origin=near.origin, dx=near.dx, dy=near.dy, nx=n, ny=2 * n)
        assert model.work_estimate(2 * cells, GridExtent(taller)) >= at_pose
        # launches narrower than the row (blocks of columns) sweep each row once per block:
        # never cheaper, and the sweep's term grows as the width shrinks
        blocks = [model.work_estimate(cells, GridExtent(near, row_cells=w)) for w in (n, max(1, n // 4), 1)]
        assert blocks[0] == at_pose and blocks[0] <= blocks[1] <= blocks[2]
        if n >= 4:
            assert blocks[2] > at_pose  # n sweeps of each row where there was one
        if n >= 64:  # the same cells as points: an extent with the grid's radii that is no GridExtent
            points = model.work_estimate(cells, SameRadii(GridExtent(near)))
            assert at_pose <= points
    for grid in (near, far):  # 1e-12: the estimates' float rounding (a few terms, a few ulps each)
        extent = GridExtent(grid)
        assert wide.work_estimate(cells, extent) >= narrow.work_estimate(cells, extent) * (1 - 1e-12)
    # at points (the per-point scan): the same growth with the nodes, and nearness to the pose
    xy = np.array([[away, 0.0], [away + half, half]])
    at, beyond = PointsExtent(xy[:, 0], xy[:, 1]), PointsExtent(xy[:, 0] + 2 * half, xy[:, 1])
    assert wide.work_estimate(cells, at) >= narrow.work_estimate(cells, at) > 0.0
    assert narrow.work_estimate(cells, beyond) <= narrow.work_estimate(cells, at)
    assert narrow.work_estimate(2 * cells, at) == pytest.approx(2 * narrow.work_estimate(cells, at), rel=1e-12)


def test_a_big_scan_costs_most_about_the_pose():
    """Near the pose the scan flags most node intervals (measured: 7.4 ms a cell within 1 m of it
    at 160,001 nodes, 0.74 ms on average within 100 m); far from it the grid is estimated lower."""
    big = bg.CAT(v0=10.0, t=100.0, sigma_a=0.05, sigma_omega=10.0)  # 160,001 nodes
    about = big.work_estimate(2500, GridExtent(square_grid((0.0, 0.0), 1.0, 50)))
    wider = big.work_estimate(2500, GridExtent(square_grid((0.0, 0.0), 100.0, 50)))
    remote = big.work_estimate(2500, GridExtent(square_grid((1e5, 0.0), 1.0, 50)))
    assert about > wider > remote
    # within 1 m every interval is searched: at least the 160,001 nodes a cell, each at the least rate
    assert about >= 2500 * 160001 * SECONDS_PER_FLAGGED_NODE


def test_format_duration_and_the_limit_option():
    assert [format_duration(s) for s in (0.5, 42.0, 90.0, 5400.0, 86400.0 * 3, 1e17)] == [
        "0.5 s", "42 s", "1.5 min", "1.5 h", "3 days", "3.2e+09 years"]
    assert work_limit("inf") == math.inf and work_limit(2) == 2.0
    for bad in ("abc", 0, -1, "nan", True):
        with pytest.raises(BananagridError, match="--max-seconds"):
            work_limit(bad)
    assert check_work(10.0, 2, "x", limit=5.0) == 5.0
    with pytest.raises(BananagridError, match="x would take about 10 s on 1 CPU thread "):
        check_work(10.0, 1, "x", limit=5.0)
    with pytest.raises(BananagridError):
        check_work(math.nan, 1, "x")


def test_closed_form_models_estimate_per_cell_and_per_station():
    """The polar and bearing estimates are per cell, the same wherever the cells lie (a closed-form
    density costs the same everywhere), heading noise costs more, and each station adds its term
    (the bearing density sums one per bearing)."""
    grid = square_grid((0.0, 0.0), 1000.0, 100)
    far = square_grid((1e6, 0.0), 1000.0, 100)
    polar = bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    turned = bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, sigma_heading=0.2)
    assert polar.work_estimate(10_000, GridExtent(grid)) == polar.work_estimate(10_000, GridExtent(far)) > 0.0
    assert turned.work_estimate(10_000, GridExtent(grid)) > polar.work_estimate(10_000, GridExtent(grid))
    costs = []
    for n in (2, 3, 6):
        angles = np.linspace(0.0, 2.0, n)
        sensors = np.column_stack([1e4 * np.sin(angles), 1e4 * np.cos(angles)])
        fix = bg.BearingFix(sensors=sensors, bearings=angles + math.pi, sigmas=np.full(n, 0.03))
        costs.append(fix.work_estimate(10_000, GridExtent(grid)))
    # 2, 3 and 6 stations: equal steps of one station's term (1e-12: float rounding)
    assert costs[1] - costs[0] == pytest.approx((costs[2] - costs[1]) / 3, rel=1e-12) and costs[1] > costs[0]
