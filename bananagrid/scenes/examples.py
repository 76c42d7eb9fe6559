"""The bundled example scenes, reachable from an installed package.

The repository's ``scenes/`` folder is installed as ``bananagrid/examples`` (package data; in a
source checkout the link ``bananagrid/examples -> ../scenes`` gives the same path), so
``bananagrid run --example figure1`` works wherever the package does, with one copy of each file.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

from ..validate import BananagridError, show

__all__ = ["example_names", "example_path", "example_title"]


def _folder() -> Path:
    """Where the examples are: a real directory for both wheels and source checkouts."""
    return Path(str(resources.files("bananagrid") / "examples"))


def example_names() -> list[str]:
    """Names of the bundled scenes (file stems), sorted."""
    folder = _folder()
    return sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []


def example_path(name: str) -> Path:
    """The file of the bundled scene ``name`` (e.g. ``"figure1"``).

    Raises
    ------
    BananagridError
        For a name that is not a bundled scene, listing those that are.
    """
    names = example_names()
    if not isinstance(name, str) or name not in names:
        raise BananagridError(f"--example {show(name)}: not a bundled scene; choose one of {', '.join(names)}")
    return _folder() / f"{name}.toml"


def example_title(name: str) -> str:
    """The ``scene.title`` of a bundled scene, read without building its models."""
    scene = tomllib.loads(example_path(name).read_text()).get("scene", {})
    return str(scene.get("title", name))
