"""The model keys of ``docs/scenes.md``, generated from the registry so that they cannot drift.

``python -m bananagrid.scenes.docs`` prints the generated sections; ``--check FILE`` exits 1 if
FILE's sections differ, ``--write FILE`` replaces them. The model keys lie between :data:`BEGIN`
and :data:`END`, the ``[plan]`` keys (:data:`~bananagrid.scenes.load.PLAN_TABLE`) between
:data:`PLAN_BEGIN` and :data:`PLAN_END`; everything else in the file is written by hand.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..atomic import atomic_write
from ..models.registry import MODEL_KINDS, Registry
from ..protocol import ALIASES, KEY_TYPES, LATLON, SceneKey
from .evidence import EVIDENCE_TABLE
from .load import PLAN_TABLE

__all__ = ["model_keys_markdown", "plan_keys_markdown", "evidence_keys_markdown", "replace_section", "BEGIN", "END",
           "PLAN_BEGIN", "PLAN_END", "EVIDENCE_BEGIN", "EVIDENCE_END", "main"]

BEGIN = "<!-- model keys: generated from the registry by `python -m bananagrid.scenes.docs --write docs/scenes.md` -->"
END = "<!-- end of the generated model keys -->"
PLAN_BEGIN = "<!-- plan keys: generated from bananagrid.scenes.load.PLAN_TABLE by `python -m bananagrid.scenes.docs --write docs/scenes.md` -->"
PLAN_END = "<!-- end of the generated plan keys -->"
EVIDENCE_BEGIN = ("<!-- evidence keys: generated from bananagrid.scenes.evidence.EVIDENCE_TABLE by "
                  "`python -m bananagrid.scenes.docs --write docs/scenes.md` -->")
EVIDENCE_END = "<!-- end of the generated evidence keys -->"

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


def plan_keys_markdown() -> str:
    """The table of the ``[plan]`` keys (:data:`~bananagrid.scenes.load.PLAN_TABLE`)."""
    lines = ["| key | type | unit | default | allowed |", "|---|---|---|---|---|"]
    lines += [f"| `{key}` | {kind} | {unit} | {default} | {allowed} |" for key, kind, unit, default, allowed in PLAN_TABLE]
    return "\n".join([PLAN_BEGIN, *lines, PLAN_END])


def evidence_keys_markdown() -> str:
    """The table of the ``[[evidence]]`` keys (:data:`~bananagrid.scenes.evidence.EVIDENCE_TABLE`)."""
    lines = ["| key | kinds | type | unit | default | allowed |", "|---|---|---|---|---|---|"]
    lines += [f"| `{key}` | {kinds} | {kind} | {unit} | {default} | {allowed} |"
              for key, kinds, kind, unit, default, allowed in EVIDENCE_TABLE]
    return "\n".join([EVIDENCE_BEGIN, *lines, EVIDENCE_END])


def replace_section(document: str, section: str, begin: str = BEGIN, end_mark: str = END) -> str:
    """``document`` with the text from ``begin`` to ``end_mark`` (default :data:`BEGIN` to
    :data:`END`) replaced by ``section``."""
    start, end = document.find(begin), document.find(end_mark)
    if start < 0 or end < start:
        raise ValueError(f"the document has no section between {begin!r} and {end_mark!r}")
    return document[:start] + section + document[end + len(end_mark):]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bananagrid.scenes.docs", description=__doc__.split("\n\n")[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--check", metavar="FILE", type=Path, help="exit 1 if FILE's generated section is stale")
    group.add_argument("--write", metavar="FILE", type=Path, help="replace FILE's generated section")
    args = parser.parse_args(argv)
    section, plan, evidence = model_keys_markdown(), plan_keys_markdown(), evidence_keys_markdown()
    if args.check is None and args.write is None:
        print(section + "\n\n" + plan + "\n\n" + evidence)
        return 0
    path = args.check or args.write
    document = path.read_text()
    updated = replace_section(replace_section(replace_section(document, section), plan, PLAN_BEGIN, PLAN_END),
                              evidence, EVIDENCE_BEGIN, EVIDENCE_END)
    if args.check is not None:
        if updated != document:
            print(f"{path}: the model or plan keys differ from their declarations; run {parser.prog} --write {path}", file=sys.stderr)
            return 1
        return 0
    with atomic_write(path) as tmp:
        tmp.write_text(updated)
    return 0


if __name__ == "__main__":
    sys.exit(main())
