"""``bananagrid bench`` runs and writes its records (timings themselves are never asserted)."""

import dataclasses
import json
import math

import numpy as np

import pytest

from bananagrid.bench import runner as bench


def test_bench_writes_records(tmp_path, capsys):
    out = tmp_path / "bench.json"
    argv = ["--kernels", "cat,polar-improved", "--step", "200", "--repeat", "1", "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    records = json.loads(out.read_text())["records"]
    # two kernels x two dtypes x (1 thread, all cores) rows, fewer when only one core is usable
    assert len(records) in (4, 8)
    for record in records:
        assert set(record) >= {"kernel", "dtype", "threads", "cells", "seconds", "baseline_seconds", "ratio"}
        assert record["cells"] == 30 * 18 and record["seconds"] > 0 and record["ratio"] > 0
        # the work check's figure for the row: the model's estimate over the row's threads
        assert record["estimate_seconds"] > 0
    out = capsys.readouterr().out
    assert "polar-improved" in out
    line = next(line for line in out.splitlines() if line.startswith("work estimate / measured (float64, 1 thread): "))
    assert [part.split()[0] for part in line.split(": ", 1)[1].split(", ")] == ["cat", "polar-improved"]


def test_bench_rejects_bad_arguments(capsys):
    assert bench.main(["--kernels", "banana"]) == 2
    assert (
        "--kernels = 'banana': choose from cat, cat-heading, polar-rough, polar-improved, polar-heading, bearing-exact, "
        "butterly-r1, butterly-r10, butterly-r100, butterly-r1000"
    ) in capsys.readouterr().err
    assert bench.main(["--repeat", "0"]) == 2
    assert "--repeat = 0: must be >= 1" in capsys.readouterr().err


def test_bench_refuses_a_device_it_cannot_use(capsys):
    """--device is checked before any timing: one line naming it and what is here (a GPU row is
    run by tests/test_cuda.py where a GPU is)."""
    from bananagrid.engine.warp_runtime import warp

    if not any(d.is_cuda for d in warp().get_devices()):
        assert bench.main(["--kernels", "polar-rough", "--device", "cuda"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == "bananagrid: error: --device: device = 'cuda': not available here (available: cpu)"
    assert bench.main(["--kernels", "polar-rough", "--device", "tpu"]) == 2
    assert "--device: device = 'tpu': not available here" in capsys.readouterr().err
    assert bench.main(["--cluster", "--device", "cuda"]) == 2
    assert "the cluster rows run on the CPU" in capsys.readouterr().err


def test_bench_reports_heading_cost(tmp_path, capsys):
    out = tmp_path / "bench.json"
    argv = ["--kernels", "cat,cat-heading", "--step", "200", "--repeat", "1", "--threads", "1", "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    cost = json.loads(out.read_text())["heading_cost"]
    assert {c["dtype"] for c in cost} == {"float64", "float32"} and all(c["ratio_to_cat"] > 0 for c in cost)
    assert "cat-heading (sigma_0 = pi/15) costs" in capsys.readouterr().out


def test_containment_timing_reports_both_methods():
    timing = bench.containment_timing(n=1000, repeat=1)
    assert timing["geometries"] == 1000 and timing["exact_seconds"] > 0 and timing["series_seconds"] > 0


def test_bench_butterly_rows(tmp_path, capsys, monkeypatch):
    """The Butterly rows on a small grid (the real one is 2048 x 2048): the framed grid, the
    record format, and the NumPy twin's time scaled from every 4th row."""
    monkeypatch.setattr(bench, "BUTTERLY_SIDE", 64)
    out = tmp_path / "bench.json"
    argv = ["--kernels", "butterly-r10", "--repeat", "1", "--threads", "1", "--baseline-stride", "4",
            "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    records = json.loads(out.read_text())["records"]
    assert [(r["kernel"], r["dtype"], r["threads"]) for r in records] == [
        ("butterly-r10", "float64", 1), ("butterly-r10", "float32", 1)
    ]
    for record in records:
        assert record["cells"] == 64 * 64 and record["seconds"] > 0 and record["baseline_seconds"] > 0
        assert record["mcells_per_s"] == pytest.approx(record["cells"] / record["seconds"] / 1e6)
    grid = bench._grid_for("butterly-r10", 4.0)
    model = bench.KERNELS["butterly-r10"]()
    # framed about the ring +- 6 sigma_max; the largest range is 10 sigma_min
    assert model.ranges.max() == pytest.approx(10 * model.sigma_min)
    assert grid.x[-1] - grid.x[0] == pytest.approx(2 * (model.ranges.max() + 6 * math.sqrt(model.axes[1])) * 63 / 64)
    assert "butterly-r10" in capsys.readouterr().out


def test_bench_times_jobs_that_are_not_one_grid(tmp_path):
    """The presence lattice rows: both dtypes, its cells, and a SciPy baseline (a sample of
    cells, scaled) in the same record format."""
    out = tmp_path / "bench.json"
    argv = ["--kernels", "presence-plane", "--repeat", "1", "--threads", "1", "--baseline-stride", "100",
            "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    records = json.loads(out.read_text())["records"]
    assert sorted(r["dtype"] for r in records) == ["float32", "float64"]
    for record in records:
        assert record["kernel"] == "presence-plane" and record["cells"] == 32760
        assert record["baseline_seconds"] > 0 and record["ratio"] > 0


def test_heading_rows_pay_for_their_tables(monkeypatch):
    """Every timed call of the heading-noise CAT builds its table: the bench clears the cache
    that would otherwise serve the repeats."""
    import math

    import bananagrid as bg
    from bananagrid.models import _cat_heading as heading

    builds = []
    real = heading.build_heading_table
    monkeypatch.setattr(heading, "build_heading_table", lambda *a, **k: builds.append(1) or real(*a, **k))
    model = bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, sigma_heading=0.1)
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=200.0)
    bg.rasterise(model, grid)
    bg.rasterise(model, grid)
    assert len(builds) == 1  # a user's repeat is served from the cache
    bench._cold_rasterise(model, grid, float, 1)
    bench._cold_rasterise(model, grid, float, 1)
    assert len(builds) == 3


def test_bench_refuses_an_unwritable_json_path_before_timing(tmp_path, capsys, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("timed before checking --json")

    monkeypatch.setattr(bench, "run", never)
    assert bench.main(["--kernels", "polar-rough", "--json", str(tmp_path / "missing" / "b.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing: cannot write there" in err[0], err


def test_bench_times_cell_probabilities_against_their_densities(tmp_path, monkeypatch, capsys):
    """The cell-probability rows: both dtypes, a baseline on a sample of cells, and each row's
    cost against the densities on the same grid (timed in the same run; CAT's lines cost more
    than its centre densities, as the docs say)."""
    monkeypatch.setattr(bench._ButterlyCellJob, "SIDE", 64)
    out = tmp_path / "bench.json"
    argv = ["--kernels", "cat-cells,butterly-cells", "--repeat", "1", "--threads", "1", "--baseline-stride", "4",
            "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    records = json.loads(out.read_text())["records"]
    assert [(r["kernel"], r["dtype"]) for r in records] == [
        ("cat-cells", "float64"), ("cat-cells", "float32"), ("butterly-cells", "float64"), ("butterly-cells", "float32")
    ]
    for record in records:
        assert record["baseline_seconds"] > 0 and record["density_seconds"] > 0
        assert record["cost_vs_density"] == pytest.approx(record["seconds"] / record["density_seconds"])
    assert records[0]["cells"] == 1500 * 900 and records[2]["cells"] == 64 * 64
    assert records[0]["cost_vs_density"] > 1.0
    assert "cell probabilities cost, against the densities on the same grid: cat-cells float64" in capsys.readouterr().out


def test_bench_cluster_rows(tmp_path, capsys):
    """The cluster rows at a small size: an 8192 x 8192 Butterly map into Zarr, a 4096 x 4096 one
    its support fills, and 3,000 polar hypotheses sharded over 2 workers; the records say what was computed and skipped."""
    out = tmp_path / "cluster.json"
    assert bench.main(["--cluster", "--cluster-side", "8192", "--dense-side", "4096", "--hypotheses", "3000",
                       "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "zarr: 8,192 x 8,192 float32 Butterly" in text and "hypotheses: 3,000 polar bananas" in text
    result = json.loads(out.read_text())
    zarr = result["cluster_zarr"]
    assert zarr["blocks"] == 16 and zarr["cells_computed"] + zarr["cells_skipped"] == 8192**2
    assert 0 < zarr["blocks_skipped"] < zarr["blocks"]  # the 1.2 km ring reaches the central blocks only
    assert len(zarr["worker_peak_rss_mib"]) == 2 and max(zarr["worker_peak_rss_mib"]) < 4096
    dense = result["cluster_dense"]
    assert dense["blocks"] == 4 and dense["blocks_skipped"] == 0 and dense["cells_computed"] == 4096**2
    assert dense["in_memory_seconds"] > 0 and dense["computed_cells_per_second_per_core"] > 0
    assert "zarr-dense: 4,096 x 4,096 float32 cells inside the same ring" in text
    hyps = result["cluster_hypotheses"]
    assert hyps["hypotheses"] == 3000 and hyps["in_process"] == 3000 and hyps["sharded_seconds"] > 0
    assert result["records"] == []  # --cluster alone: no kernel rows
    assert bench.main(["--cluster", "--memory-limit", "lots"]) == 2
    assert "--memory-limit: memory_limit = \"lots\"" in capsys.readouterr().err


def test_bench_refuses_a_json_target_that_is_not_a_file_before_timing(tmp_path, capsys):
    """A directory or a link at --json is refused before any timing, one line naming it."""
    (tmp_path / "dir.json").mkdir()
    (tmp_path / "link.json").symlink_to(tmp_path / "elsewhere.json")
    for name, what in (("dir.json", "it is a directory"), ("link.json", "it is a symbolic link")):
        assert bench.main(["--kernels", "polar-rough", "--json", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and what in err and name in err, err


def test_bench_times_small_calls(tmp_path, capsys, monkeypatch):
    """``--small`` alone runs only the small-call rows: rasterise and pdf of each of its models on
    one thread and on --threads, and the batch's framing against its launch, into the JSON."""
    monkeypatch.setattr(bench, "SMALL_SECONDS", 1e-3)  # one or a few calls a timing: records, not figures
    monkeypatch.setattr(bench, "SMALL_HYPOTHESES", 20)
    out = tmp_path / "bench.json"
    assert bench.main(["--small", "--threads", "2", "--repeat", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["records"] == []  # no kernel rows without --kernels
    calls = result["small_calls"]["calls"]
    assert {(r["call"], r["model"], r["threads"]) for r in calls} == {
        (call, name, n) for call in ("rasterise 100 x 100", "pdf 1,000 points") for name in bench.SMALL_ROWS
        for n in (1, 2)}
    assert all(r["cpu_us"] > 0 and r["wall_us"] > 0 and r["calls"] >= 1 for r in calls)
    batches = result["small_calls"]["batches"]
    assert [b["shape"] for b in batches] == [list(s) for s in bench.SMALL_BATCH_SHAPES]
    for b in batches:
        assert b["hypotheses"] == 20 and b["frame_over_launch_wall"] == b["frame_wall_us"] / b["launch_wall_us"]
        # the microseconds are the seconds times 1e6, each rounded: the ratio within a few ulps
        assert b["frame_over_launch_cpu"] == pytest.approx(b["frame_cpu_us"] / b["launch_cpu_us"], rel=1e-14)
    text = capsys.readouterr().out
    assert "small calls, float64, per call" in text and "framing costs" in text
    assert bench.main(["--small", "--device", "cuda"]) == 2
    assert "the small-call rows run on the CPU" in capsys.readouterr().err


def test_bench_times_a_plan_over_periods(tmp_path, monkeypatch):
    """The plan-periods row on the submarine's square at 92 km cells (5 x 5), its start 20 times
    wider (the Butterly cell rule's sub-cells scale with the start's SD) and to a loose tolerance:
    the row's own takes minutes. One float64 record, its baseline the periods' own plans."""
    monkeypatch.setattr(bench._PeriodPlanJob, "STEP", 92000.0)
    monkeypatch.setattr(bench._PeriodPlanJob, "TOL", 1e-3)
    build = bench._PeriodPlanJob.__init__

    def wider(job):
        build(job)
        job.model = dataclasses.replace(job.model, cov=400.0 * np.asarray(job.model.cov))

    monkeypatch.setattr(bench._PeriodPlanJob, "__init__", wider)
    out = tmp_path / "bench.json"
    argv = ["--kernels", "plan-periods", "--repeat", "1", "--threads", "1", "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    (record,) = json.loads(out.read_text())["records"]
    assert record["kernel"] == "plan-periods" and record["dtype"] == "float64" and record["cells"] == 25
    assert record["seconds"] > 0 and record["baseline_seconds"] > 0
