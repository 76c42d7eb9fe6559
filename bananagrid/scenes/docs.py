"""The model keys of ``docs/scenes.md``, generated from the registry so that they cannot drift.

``python -m bananagrid.scenes.docs`` prints the generated section; ``--check FILE`` exits 1 if
FILE's section differs, ``--write FILE`` replaces it. The section lies between :data:`BEGIN` and
:data:`END`; everything else in the file is written by hand.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..atomic import atomic_write
from ..models.registry import MODEL_KINDS, Registry
from ..protocol import ALIASES, KEY_TYPES, LATLON, SceneKey

__all__ = ["model_keys_markdown", "replace_section", "BEGIN", "END", "main"]

BEGIN = "<!-- model keys: generated from the registry by `python -m bananagrid.scenes.docs --write docs/scenes.md` -->"
END = "<!-- end of the generated model keys -->"

#: Units of an alias: the SI unit with its radians (or m/s) replaced.
_ALIAS_UNITS = {"deg": ("rad", "deg"), "kn": ("m/s", "kn")}


def _rows(key: SceneKey) -> list[str]:
    kind = KEY_TYPES[key.type]
    default = key.default
    if key.alias is not None and default == "required":
        default = f"required (or `{key.name}_{key.alias}`)"
    allowed = key.allowed
    if key.type == "choice" and not allowed:
        allowed = ", ".join(f'`"{c}"`' for c in key.choices)
    rows = [f"| `{key.name}` | {kind} | {key.unit} | {default} | {allowed} |"]
    if key.alias is not None:
        si, alt = _ALIAS_UNITS[key.alias]
        unit = key.unit.replace(si, alt) if si in key.unit else alt
        rows.append(f"| `{key.name}_{key.alias}` | {kind} | {unit} | instead of `{key.name}` "
                    f"| as `{key.name}`, in {ALIASES[key.alias]} |")
    if key.position:
        shape = "`[lat, lon]`" if key.type == "pair" else "array of `[lat, lon]`"
        rows.append(f"| `{key.name}_{LATLON}` | {shape} | deg | instead of `{key.name}` "
                    f"| latitude in [-90, 90], longitude in [-180, 180]; needs `[geo]` |")
    return rows


def model_keys_markdown(kinds: Registry = MODEL_KINDS) -> str:
    """One section per model kind of grid layers: its summary and the table of its keys (the
    array's presence kinds are written in their ``[presence]`` table, documented by hand)."""
    parts = []
    for name, kind in kinds.on("grid").items():
        schema = kind.scene
        timed = ("it depends on the elapsed time: it takes `t`, or is computed at every `scene.times`"
                 if schema.timed else "it does not depend on time: it is logged at `t = 0` (or at every `scene.times`)")
        lines = [
            f"### `model = \"{name}\"`: `bananagrid.{kind.cls.__name__}`",
            "",
            f"{schema.summary[:1].upper()}{schema.summary[1:]}; {timed}.",
            "",
            "| key | type | unit | default | allowed |",
            "|---|---|---|---|---|",
        ]
        for key in schema.keys:
            lines += _rows(key)
        parts.append("\n".join(lines))
    return "\n\n".join([BEGIN, *parts, END])


def replace_section(document: str, section: str) -> str:
    """``document`` with the text from :data:`BEGIN` to :data:`END` replaced by ``section``."""
    start, end = document.find(BEGIN), document.find(END)
    if start < 0 or end < start:
        raise ValueError(f"the document has no section between {BEGIN!r} and {END!r}")
    return document[:start] + section + document[end + len(END):]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bananagrid.scenes.docs", description=__doc__.split("\n\n")[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--check", metavar="FILE", type=Path, help="exit 1 if FILE's generated section is stale")
    group.add_argument("--write", metavar="FILE", type=Path, help="replace FILE's generated section")
    args = parser.parse_args(argv)
    section = model_keys_markdown()
    if args.check is None and args.write is None:
        print(section)
        return 0
    path = args.check or args.write
    document = path.read_text()
    updated = replace_section(document, section)
    if args.check is not None:
        if updated != document:
            print(f"{path}: the model keys differ from the registry; run {parser.prog} --write {path}", file=sys.stderr)
            return 1
        return 0
    with atomic_write(path) as tmp:
        tmp.write_text(updated)
    return 0


if __name__ == "__main__":
    sys.exit(main())
