"""The bundled example scenes, reachable from an installed package.

The repository's ``scenes/`` folder is installed as ``bananagrid/examples`` (package data, mapped
by ``package-dir`` in ``pyproject.toml``; in a source checkout the link
``bananagrid/examples -> ../scenes`` gives the same path), so ``bananagrid run --example figure1``
works wherever the package does, with one copy of each file.
"""

from __future__ import annotations

import os
import tomllib
from importlib import resources
from pathlib import Path

from ..validate import BananagridError, show

__all__ = ["example_names", "example_path", "example_title", "scene_source"]


def _folder() -> Path:
    """Where the examples are: a real directory for both wheels and source checkouts."""
    return Path(str(resources.files("bananagrid") / "examples"))


def example_names() -> list[str]:
    """Names of the bundled scenes, sorted.

    Returns
    -------
    list of str
        The file stems (``"figure1"`` for ``figure1.toml``); each is also the scene's
        ``scene.name``, so ``run --example NAME`` writes ``NAME.rrd``.
    """
    folder = _folder()
    return sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []


def example_path(name: str, *, key: str = "--example") -> Path:
    """The file of the bundled scene ``name``.

    Parameters
    ----------
    name : str
        A name from :func:`example_names`, e.g. ``"figure1"``.
    key : str, optional
        The option that gave ``name``, for the error message (``--example``, ``--show``).

    Returns
    -------
    pathlib.Path
        The installed scene file (in a source checkout, ``scenes/NAME.toml`` through the link).

    Raises
    ------
    BananagridError
        For a name that is not a bundled scene, listing those that are.
    """
    names = example_names()
    if not isinstance(name, str) or name not in names:
        raise BananagridError(f"{key} {show(name)}: not a bundled scene; choose one of {', '.join(names)}")
    return _folder() / f"{name}.toml"


def example_title(name: str) -> str:
    """The ``scene.title`` of a bundled scene, read without building its models.

    Parameters
    ----------
    name : str
        A name from :func:`example_names`.

    Returns
    -------
    str
        The title, or the name for a scene without one (as ``load_scene`` does).
    """
    scene = tomllib.loads(example_path(name).read_text()).get("scene", {})
    return str(scene.get("title", name))


def scene_source(path: str | os.PathLike | None, example: str | None, *, what: str = "SCENE.toml") -> Path:
    """The scene a command was given: a file, or a bundled scene by ``--example NAME``.

    For commands that take one scene (``compare``, ``plot``): exactly one of ``path`` and
    ``example`` must be given.

    Parameters
    ----------
    path : str or os.PathLike or None
        The positional argument (a scene file, or whatever else the command reads).
    example : str or None
        The value of ``--example``.
    what : str, optional
        How the command's usage names the positional argument, for the error messages.

    Returns
    -------
    pathlib.Path
        ``path``, or the bundled scene's file.

    Raises
    ------
    BananagridError
        When both or neither are given, or for an unknown example name.
    """
    if path is not None and example is not None:
        raise BananagridError(f"{what} {path} and --example {show(example)}: give one of them, not both")
    if example is not None:
        return example_path(example)
    if path is None:
        raise BananagridError(f"give {what} or --example NAME (`bananagrid examples` lists the names)")
    return Path(path)
