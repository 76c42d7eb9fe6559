"""The README cannot lie: every ```python block runs (in order, in one namespace), every command
it shows that finishes in seconds runs, the figures its examples quote are what they give, the
command synopsis matches the command line, and its API section lists ``bananagrid.__all__``.

A command the README shows but the suite does not run must be listed in ``NOT_RUN`` with the
reason (and so stay a deliberate choice): a new command in the README fails
``test_every_command_is_run_or_listed`` until it is classified.
"""

import contextlib
import io
import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import bananagrid as bg
from bananagrid import cli
from bananagrid.bench import runner as bench

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
BIN = Path(sys.executable).parent

#: Commands shown in the README that the suite does not run, and why.
NOT_RUN = {
    "python3 -m venv .venv": "creates the environment these tests run in",
    ".venv/bin/pip install .": "installs the package these tests run against",
    ".venv/bin/pip install -q '.[test]'": "installs the package these tests run against",
    ".venv/bin/pytest": "the suite itself",
    "pip install -e '.[test]'": "an editable install of the package these tests run against",
    "rerun out/figure1.rrd": "opens the viewer (a window); recordings are checked by inspect and rerun rrd verify",
    "pytest tests/models/test_heading.py": "part of the suite itself",
    "python tests/reproduce_tables.py": "about 4 minutes; tests/models/test_paper_tables.py checks the same tables",
    "bananagrid bench --kernels cat-cells,butterly-cells --repeat 3": "a minute of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --repeat 5 --json bench.json": "about 15 minutes of timing; tests/bench/test_bench.py runs bench on small grids",
    "bananagrid bench --repeat 5": "about 15 minutes of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --kernels presence-plane --repeat 5": "minutes of SciPy baseline (see tests/bench/test_bench.py)",
    "bananagrid bench --kernels polar-rough,polar-improved,polar-heading,bearing-exact --step 2 --repeat 15 --no-peers --no-memory":
        "a minute of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --kernels butterly-r1000 --repeat 5 --baseline-stride 100": "a minute of timing (see tests/bench/test_bench.py)",
    "bananagrid bench --kernels cat,cat-heading,cat-cells --repeat 3": "minutes of timing (see tests/bench/test_bench.py)",
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
}

SINGLE_WORD_COMMANDS = ("lint-imports",)
COMMAND_WORDS = ("bananagrid", ".venv/bin/", "python", "pip", "pytest", "lint-imports", "rerun", "time ")


def fenced_blocks(language: str) -> list[tuple[int, str]]:
    """(line number, text) of each ```language block."""
    blocks = []
    for match in re.finditer(rf"^```{language}\n(.*?)^```", README, flags=re.S | re.M):
        blocks.append((README[: match.start()].count("\n") + 2, match.group(1)))
    return blocks


def shown_commands() -> list[str]:
    """Every command in ```bash blocks (split at &&) and in inline code spans, in README order."""
    found = []
    # code blocks blanked to spaces of the same length, so that positions stay README positions
    prose = re.sub(r"^```.*?^```", lambda m: re.sub(r"[^\n]", " ", m.group(0)), README, flags=re.S | re.M)
    spans = [(m.start(), m.group(1)) for m in re.finditer(r"`([^`\n]+)`", prose)]
    for match in re.finditer(r"^```bash\n(.*?)^```", README, flags=re.S | re.M):
        spans += [(match.start(), line) for line in match.group(1).splitlines() if line.strip()]
    for _, text in sorted(spans, key=lambda item: item[0]):
        for part in text.split("&&"):
            part = part.strip()
            whole = " " in part or part.startswith(".venv/bin/") or part in SINGLE_WORD_COMMANDS
            if part.startswith(COMMAND_WORDS) and whole and part not in found:
                found.append(part)
    return found


def runnable() -> list[str]:
    return [c for c in shown_commands() if c not in NOT_RUN]


def test_every_command_is_run_or_listed():
    commands = shown_commands()
    assert len(commands) >= 8  # the parser finds them (the README shows more than this)
    assert set(NOT_RUN) <= set(commands), set(NOT_RUN) - set(commands)  # no stale entries
    # what runs: the Figure 1 scene, inspect, lint-imports and the from-the-root imports at least
    for needed in ("bananagrid run scenes/figure1.toml --out out", "bananagrid inspect out/figure1.rrd", "lint-imports"):
        assert any(needed in c for c in runnable()), needed


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A directory like the repository root: the scenes, and the package's sources for the
    commands run from a checkout."""
    work = tmp_path_factory.mktemp("readme")
    for name in ("scenes", "bananagrid", "kernels", "docs", "pyproject.toml"):
        (work / name).symlink_to(ROOT / name)
    return work


def as_run_here(command: str) -> list[str]:
    words = shlex.split(command)
    head = words[0].removeprefix(".venv/bin/")
    if head in ("python", "python3"):
        return [sys.executable, *words[1:]]
    return [str(BIN / head), *words[1:]]


def test_shown_commands_run(workdir):
    """In README order (``inspect`` reads what ``run`` wrote)."""
    for command in runnable():
        run = subprocess.run(as_run_here(command), cwd=workdir, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, f"{command}:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}"
    assert (workdir / "out" / "figure1.rrd").stat().st_size > 0


def test_python_blocks_run_and_give_the_figures_shown(workdir, monkeypatch):
    monkeypatch.chdir(workdir)
    namespace: dict = {"__name__": "readme"}
    blocks = fenced_blocks("python")
    assert len(blocks) >= 7
    for line, code in blocks:
        with contextlib.redirect_stdout(io.StringIO()):
            exec(compile(code, f"README.md:{line}", "exec"), namespace)
    # figures quoted in the blocks' comments (the README shows them rounded as below)
    assert f"{namespace['r'].mass:.10f}" == "0.9999999934"
    estimate = namespace["bg"].rasterise(namespace["exact"], namespace["grid"]).provenance["heading_error_estimate"]
    assert f"{estimate:.1e}" == "7.0e-07"
    assert f"{namespace['c'].goodness:.7f}" == "0.9999227"
    assert namespace["batch"].values.shape == (10_000, 64, 64)
    assert namespace["scores"].shape == (10_000, 2)
    assert namespace["cells"].prob.shape == (360, 91)
    assert math.isclose(namespace["cells"].prob.sum(), 1.0, rel_tol=1e-6)  # p(C | S) over the room
    assert (namespace["at_sea"].quantity, f"{namespace['at_sea'].mass:.9f}") == ("probability", "1.000000000")
    assert f"{namespace['bg'].rasterise(namespace['ship'], namespace['chart']).mass:.4f}" == "0.9846"
    assert namespace["blocks"] == (252, 256)
    single = namespace["bg"].rasterise_batch(namespace["tracks"])
    assert (namespace["gathered"].values == single.values).all() and namespace["gathered"].grids == tuple(single.grids)


def synopsis() -> list[str]:
    (block,) = [text for _, text in fenced_blocks("text") if text.startswith("bananagrid ")]
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


def test_the_api_section_lists_all():
    section = README.split("## API", 1)[1].split("\n## ", 1)[0]
    listed = set(re.findall(r"`([A-Za-z_][A-Za-z_0-9]*)`", section))
    assert set(bg.__all__) <= listed, set(bg.__all__) - listed


def test_the_inspect_report_shown_is_what_inspect_prints(workdir):
    """The Figure 1 report quoted under "Scenes and the command line" (its lines up to the
    ``...``) is what ``bananagrid inspect out/figure1.rrd`` prints first."""
    (shown,) = [text for _, text in fenced_blocks("text") if text.startswith("recording  out/figure1.rrd")]
    shown = shown.split("\n...")[0].splitlines()
    if not (workdir / "out" / "figure1.rrd").exists():  # run alone: test_shown_commands writes it
        subprocess.run(as_run_here("bananagrid run scenes/figure1.toml --out out --quiet"), cwd=workdir, check=True,
                       capture_output=True, timeout=600)
    run = subprocess.run(as_run_here("bananagrid inspect out/figure1.rrd"), cwd=workdir, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[: len(shown)] == shown
