"""The package's architecture as tests: the import layers (import-linter's contracts in
pyproject.toml), no import cycle, no import inside a function, no private name imported across
modules, models named only where they live, the generated scene schema up to date, the
package usable from a plain checkout, the tests laid out as the package is, and
docs/architecture.md naming every module and the layers as they are."""

import ast
import importlib
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import bananagrid

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "bananagrid"
SOURCES = sorted(p for p in PACKAGE.rglob("*.py") if "kernels" not in p.relative_to(PACKAGE).parts)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def imported_modules(path: Path) -> set[str]:
    """The bananagrid modules ``path`` imports at module level (relative imports resolved)."""
    package = module_name(path).split(".") if path.name == "__init__.py" else module_name(path).split(".")[:-1]
    found = set()
    for node in parse(path).body:
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:  # "from . import x" may name a submodule
                found.add(f"{target}.{alias.name}")
            found.add(target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    known = {module_name(p) for p in SOURCES}
    return {m for m in found if m in known}


def venv_tool(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def test_import_layers_hold():
    """import-linter's contracts (pyproject.toml): the layers cli > bench > scenes > recording >
    analysis > models > engine > protocol/results > domains/kernels > atomic > validate; only the engine
    and the kernels import warp; the kernels import nothing of bananagrid."""
    run = subprocess.run([venv_tool("lint-imports")], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "4 kept, 0 broken" in run.stdout


def test_no_import_cycle():
    graph = {module_name(p): imported_modules(p) for p in SOURCES}
    state: dict[str, int] = {}

    def visit(node, path):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt == node or nxt.startswith(node + "."):  # a package importing its own modules
                continue
            if state.get(nxt) == 1:
                cycle = path[path.index(nxt):] + [nxt] if nxt in path else path + [nxt]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])


class _NestedImports(ast.NodeVisitor):
    def __init__(self):
        self.depth, self.found = 0, []

    def _scope(self, node):
        self.depth += 1
        self.generic_visit(node)
        self.depth -= 1

    visit_FunctionDef = visit_AsyncFunctionDef = visit_ClassDef = visit_Lambda = _scope

    def visit_Import(self, node):
        if self.depth:
            self.found.append(node.lineno)

    visit_ImportFrom = visit_Import


def test_no_import_inside_functions():
    """Every import is at module level, so the layers contract sees all of them (optional extras
    alone, matplotlib in bananagrid.plotting and the geo and peer libraries, are loaded with
    importlib on first use), and no module of the package is imported by its dotted name."""
    nested = []
    for path in SOURCES:
        visitor = _NestedImports()
        visitor.visit(parse(path))
        nested += [f"{path.relative_to(ROOT)}:{line}" for line in visitor.found]
    assert nested == []
    by_name = []
    for path in SOURCES:
        for node in ast.walk(parse(path)):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "import_module"
                    and node.args and isinstance(node.args[0], ast.Constant) and str(node.args[0].value).startswith(("bananagrid", "."))):
                by_name.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert by_name == []


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_private_name_crosses_a_module():
    """No module imports another's private name; a private module is imported only by modules
    of its own package."""
    crossings = []
    for path in SOURCES:
        for node in ast.walk(parse(path)):
            if not isinstance(node, ast.ImportFrom):
                continue
            where = f"{path.relative_to(ROOT)}:{node.lineno}"
            crossings += [f"{where} {alias.name}" for alias in node.names if _private(alias.name)]
            if node.module and any(_private(part) for part in node.module.split(".")):
                if node.level != 1 or "." in node.module:  # only "from ._sibling import x"
                    crossings.append(f"{where} {node.module}")
    assert crossings == []


def _files_naming(name: str) -> set[str]:
    """Files whose code (not docstrings or comments) names ``name``."""
    files = set()
    for path in SOURCES + sorted((ROOT / "kernels").glob("*.py")):
        for node in ast.walk(parse(path)):
            if ((isinstance(node, ast.Name) and node.id == name) or (isinstance(node, ast.Attribute) and node.attr == name)
                    or (isinstance(node, ast.alias) and name in (node.name, node.asname))):
                files.add(path.relative_to(ROOT).as_posix())
                break
    return files


#: Every registered model class by name, with the stem of its module.
MODEL_CLASSES = {kind.cls.__name__: kind.cls.__module__.rsplit(".", 1)[-1] for kind in bananagrid.MODEL_KINDS.values()}


def test_a_model_is_named_only_where_it_lives():
    """Adding a model is its model module, its kernel module and one registry line: nothing else
    in the package names the class (its recording extras module aside)."""
    assert _files_naming("Butterly") == {
        "bananagrid/models/butterly.py", "bananagrid/recording/butterly.py",
        "bananagrid/models/registry.py", "bananagrid/__init__.py",
    }
    # the engine, lattices, radial laws, batch and compare talk to models through the protocol
    for name in (*MODEL_CLASSES, "MotionModel"):
        for path in _files_naming(name):
            assert not path.startswith(("bananagrid/engine/", "bananagrid/domains/")), (name, path)
            assert path not in ("bananagrid/analysis/radial.py", "bananagrid/analysis/compare.py"), (name, path)


def test_no_isinstance_on_a_model_outside_its_module():
    models = {**MODEL_CLASSES, "MotionModel": "motion", "GaussianMixture": "presence", "UniformPresence": "presence"}
    found = []
    for path in SOURCES:
        for node in ast.walk(parse(path)):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance":
                classes = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
                for cls in classes:
                    if isinstance(cls, ast.Name) and cls.id in models and path.stem != models[cls.id]:
                        found.append(f"{path.relative_to(ROOT)}:{node.lineno} {cls.id}")
    assert found == []


def test_scene_schema_in_the_docs_is_generated_from_the_registry():
    run = subprocess.run([sys.executable, "-m", "bananagrid.scenes.docs", "--check", "docs/scenes.md"],
                         cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def _checkout_env() -> dict:
    """An environment in which only the checkout can provide bananagrid: the venv's packages stay
    importable (numpy, warp, ...), but its own installed bananagrid is hidden behind the root,
    which Python puts first on sys.path for ``-c`` and ``-m``."""
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    return env


def test_the_checkout_imports_and_rasterises_from_the_root():
    code = (
        "import bananagrid as bg, numpy as np;"
        "r = bg.rasterise(bg.CAT(v0=280.0, t=10.0, sigma_a=5/3, sigma_omega=np.pi/54),"
        " bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=100.0));"
        "print(bg.__file__); print(r.mass)"
    )
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_checkout_env(), capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    where, mass = run.stdout.split()
    assert Path(where).resolve() == (PACKAGE / "__init__.py").resolve()  # the source tree, not site-packages
    assert abs(float(mass) - 1.0) < 1e-3  # the Figure 1 banana at 100 m cells


def test_the_checkout_runs_a_scene_from_the_root(tmp_path):
    run = subprocess.run(
        [sys.executable, "-m", "bananagrid", "run", "scenes/figure1.toml", "--step", "50", "--out", str(tmp_path), "--quiet"],
        cwd=ROOT, env=_checkout_env(), capture_output=True, text=True,
    )
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "figure1.rrd").stat().st_size > 0


# The tests' own layout: tests/<package>/test_<module...>.py beside the package they test.
TESTS = ROOT / "tests"
SUPPORT = TESTS / "support"


def _test_files() -> list[Path]:
    return sorted(TESTS.rglob("test_*.py"))


def _test_directories() -> list[Path]:
    return sorted({path.parent for path in _test_files()})


def test_the_tests_mirror_the_package():
    """A test lives in tests/ (cross-cutting: README, packaging, architecture, CLI, top-level
    modules) or in tests/<name>/ for the package bananagrid/<name>/ (kernels/ for the kernels)."""
    packages = {path.parent.name for path in PACKAGE.glob("*/__init__.py")} | {"kernels"}
    for directory in _test_directories():
        if directory != TESTS:
            assert directory.parent == TESTS and directory.name in packages, directory.relative_to(ROOT)
    assert not list(SUPPORT.glob("test_*.py")), "tests/support/ holds what tests share, not tests"


def test_test_file_names_are_unique():
    """Tests import each other's tables by module name (every test directory is on pytest's
    path), so two test files of one name would shadow each other."""
    names = [path.name for path in _test_files()]
    assert sorted(names) == sorted(set(names)), sorted({name for name in names if names.count(name) > 1})


def test_pytest_path_is_support_and_every_test_directory():
    pythonpath = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["pythonpath"]
    expected = ["tests/support"] + [directory.relative_to(ROOT).as_posix() for directory in _test_directories()]
    assert pythonpath == expected


def test_shared_helpers_live_in_support():
    """A module that tests import (an oracle, a case table, the tests' own model) is in
    tests/support/; beside the tests only conftest.py and scripts run by hand (``__main__``).
    (A package the tests install, in a folder of its own without tests, is not looked at.)"""
    misplaced = []
    for path in sorted(path for directory in _test_directories() for path in directory.glob("*.py")):
        if path.name.startswith("test_") or path.name == "conftest.py":
            continue
        if "__main__" not in path.read_text():
            misplaced.append(path.relative_to(ROOT).as_posix())
    assert misplaced == []


#: Where a test file is named by its path (tests/...py): each such path must exist. (The
#: documentation's commands are quoted verbatim in test_docs.py's table, which follows the pages.)
NAMING_TEST_PATHS = ["pyproject.toml", "bananagrid", "kernels", "docs", "tests", "README.md"]
QUOTING_THE_README = TESTS / "test_docs.py"


def test_every_test_path_named_exists():
    missing = []
    for entry in NAMING_TEST_PATHS:
        paths = [ROOT / entry] if (ROOT / entry).is_file() else sorted((ROOT / entry).rglob("*.py"))
        paths += sorted((ROOT / entry).rglob("*.md")) if (ROOT / entry).is_dir() else []
        for path in (path for path in paths if path != QUOTING_THE_README):
            for named in re.findall(r"\btests/[\w/]+\.py\b", path.read_text()):
                if not (ROOT / named).is_file():
                    missing.append(f"{path.relative_to(ROOT)}: {named}")
    assert missing == []


# docs/architecture.md: the package as it is, kept true here.
ARCHITECTURE = ROOT / "docs" / "architecture.md"


def _package_modules() -> set[str]:
    """Every package and module of bananagrid, the kernels (installed as bananagrid.kernels) included."""
    kernels = {f"bananagrid.kernels.{path.stem}" for path in (ROOT / "kernels").glob("*.py") if path.stem != "__init__"}
    return {module_name(path) for path in SOURCES} | kernels | {"bananagrid.kernels"}


def _named_in_architecture() -> set[str]:
    return set(re.findall(r"`(bananagrid(?:\.\w+)*)`", ARCHITECTURE.read_text()))


def test_every_module_is_named_in_the_architecture_docs():
    assert sorted(_package_modules() - _named_in_architecture()) == []


def test_every_name_in_the_architecture_docs_exists():
    """A dotted name there is a module of the package, or a name defined in one."""
    modules = _package_modules()
    missing = []
    for name in sorted(_named_in_architecture() - modules):
        parts = name.split(".")
        owner = max((k for k in range(1, len(parts)) if ".".join(parts[:k]) in modules), default=None)
        if owner is None or not _has_attribute(".".join(parts[:owner]), parts[owner:]):
            missing.append(name)
    assert missing == []


def _has_attribute(module: str, path: list[str]) -> bool:
    value = importlib.import_module(module)
    for part in path:
        if not hasattr(value, part):
            return False
        value = getattr(value, part)
    return True


def test_the_layers_in_the_architecture_docs_are_the_contract():
    """The layers block of docs/architecture.md, top to bottom, is import-linter's layers contract."""
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    (layers,) = [c["layers"] for c in contracts if c["type"] == "layers"]
    section = ARCHITECTURE.read_text().split("\n## Layers\n", 1)[1].split("\n## ", 1)[0]
    (block,) = re.findall(r"^```text\n(.*?)^```", section, flags=re.S | re.M)
    assert block.splitlines() == layers


def test_every_test_directory_is_described_in_the_architecture_docs():
    section = ARCHITECTURE.read_text().split("\n## Tests\n", 1)[1].split("\n## ", 1)[0]
    described = set(re.findall(r"^\| `(tests/(?:\w+/)?)` \|", section, flags=re.M))
    directories = {directory.relative_to(ROOT).as_posix() + "/" for directory in [*_test_directories(), SUPPORT]}
    assert sorted(directories - described) == []
    assert sorted(name for name in described if not (ROOT / name).is_dir()) == []
