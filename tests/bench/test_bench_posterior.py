"""``bananagrid bench``'s posterior rows (bananagrid.bench.posterior): what they time and
report; timings themselves are never asserted."""

import json

import pytest

import bananagrid as bg
from bananagrid.bench import posterior as rows
from bananagrid.bench import runner as bench


@pytest.fixture
def small_submarine(monkeypatch):
    """The submarine row on 30 x 30 cells of 8 km over the inner +-120 km, with a start of 8 km
    (1 sigma) each way: the real row (a start of 2 km x 0.5 km, 1150 x 1150 cells of 400 m over
    +-230 km) takes about 20 s a map here, as Butterly's cell rule costs (frame / start SD)^2."""
    real = rows.ROWS["butterly-posterior"]
    row = dict(real, params=dict(real["params"], sigma_x=8000.0, sigma_y=8000.0, rho=0.0),
               bounds=dict(x=(-120000.0, 120000.0), y=(-120000.0, 120000.0), step=8000.0))
    monkeypatch.setitem(rows.ROWS, "butterly-posterior", row)


@pytest.mark.parametrize("evidence", ["same", "earlier"])
def test_posterior_rows_time_the_posterior_against_its_prior(evidence, small_submarine, tmp_path, capsys):
    names = ["cat-posterior", "butterly-posterior"]
    out = tmp_path / "bench.json"
    argv = ["--kernels", ",".join(names), "--evidence", evidence, "--step", "200",
            "--repeat", "1", "--threads", "1", "--no-memory", "--json", str(out)]
    assert bench.main(argv) == 0
    records = json.loads(out.read_text())["posterior"]
    assert [(r["kernel"], r["threads"]) for r in records] == [(name, 1) for name in names]
    for r in records:
        prior, grid, searches = rows.posterior_case(r["kernel"], 200.0, evidence)
        assert r["cells"] == grid.nx * grid.ny and r["evidence"] == evidence
        assert r["ratio_to_prior"] == pytest.approx(r["seconds"] / r["prior_seconds"])
        assert r["ratio_to_density"] == pytest.approx(r["seconds"] / r["density_seconds"])
        assert r["target"] == {"cat-posterior": 2.0, "butterly-posterior": 3.0}[r["kernel"]]
        # the POS reported is the timed posterior's
        post = bg.posterior(prior, grid, searches)
        assert r["pos"] == pytest.approx(post.pos, rel=1e-12) and r["search_pos"] == pytest.approx(post.search_pos)
        # both boxes lie where the target is when searched: each search could have found it
        assert min(r["search_pos"]) > 0.01
        times = [s.time_span[0] for s in searches]
        assert r["search_times"] == times
        assert all(t < prior.t for t in times) if evidence == "earlier" else all(t == prior.t for t in times)
    out = capsys.readouterr().out
    assert "cat-posterior: CAT on 30 x 18 cells" in out and "target" in out


def test_each_box_is_where_the_target_is_when_searched():
    """The earlier searches' boxes hold a good part of the target's position law at their own
    times (Monte Carlo of the model at that time: its own ``sample``), so the rows time a
    posterior the searches change; the same-time boxes, stretched to the map's time, too."""
    import numpy as np

    for name, row in rows.ROWS.items():
        for evidence in rows.EVIDENCE:
            prior, _, searches = rows.posterior_case(name, 4.0, evidence)
            for search in searches:
                at = bg.MODEL_KINDS[row["kind"]].build({**row["params"], "t": search.time_span[0]})
                xy = at.sample(20_000, np.random.default_rng(5))
                (x0, y0), (x1, y1) = search.polygon.min(axis=0), search.polygon.max(axis=0)
                inside = np.mean((xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1))
                # a box over part of the target: between 5 % and 95 % of it (20,000 draws: +-0.4 %)
                assert 0.05 < inside < 0.95, (name, evidence, search.time_span, inside)


def test_a_row_whose_evidence_this_build_refuses_stops_before_timing(monkeypatch, capsys):
    """``check_rows`` raises what the row would, on a coarse grid, before any timing."""
    def never(*args, **kwargs):
        raise AssertionError("timed before checking the rows")

    monkeypatch.setattr(bench, "posterior_rows", never)
    bad = dict(rows.ROWS["cat-posterior"], searches=((11.0, (-400.0, 0.0, 1000.0, 1250.0), dict(pod=0.7)),))
    monkeypatch.setitem(rows.ROWS, "cat-posterior", bad)
    assert bench.main(["--kernels", "cat-posterior", "--no-memory"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bananagrid: error: --evidence earlier: evidence[0].t = 11.0: after"), err
