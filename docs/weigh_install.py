"""What each requirement of bananagrid brings to an environment: ``python docs/weigh_install.py
[SITE_PACKAGES] [--extra test]`` (default: this interpreter's site-packages, the base
requirements).

For each top-level requirement of the base install (or of an extra, the base included) it
prints the size of the distributions it pulls in (from their RECORD files) and the part no
other top-level requirement needs (its exclusive share: what leaving it out would save), and
the total of them all. Sizes in MiB (2^20 bytes) of the installed files.
"""

from __future__ import annotations

import argparse
import importlib.metadata as metadata
import os
import re
import sysconfig
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _name(requirement: str) -> str:
    return re.sub(r"[-_.]+", "-", re.match(r"[A-Za-z0-9_.-]+", requirement).group(0)).lower()


def installed(site: str) -> dict[str, tuple[int, list[str]]]:
    """Every distribution in ``site``: its size in bytes and what it requires (no extras)."""
    found = {}
    for dist in metadata.distributions(path=[site]):
        size = 0
        for f in dist.files or []:
            try:
                size += os.path.getsize(os.path.join(site, f))
            except OSError:
                pass
        needs = [_name(r) for r in dist.requires or [] if "extra ==" not in r]
        found[_name(dist.metadata["Name"])] = (size, needs)
    return found


def closure(root: str, dists: dict) -> set[str]:
    seen, stack = set(), [root]
    while stack:
        name = stack.pop()
        if name not in seen and name in dists:
            seen.add(name)
            stack.extend(dists[name][1])
    return seen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("site", nargs="?", default=sysconfig.get_paths()["purelib"])
    parser.add_argument("--extra", default=None, help="an extra of pyproject.toml (its requirements and the base's)")
    args = parser.parse_args()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    roots = [_name(r) for r in project["dependencies"]]
    if args.extra:
        roots += [_name(r) for r in project["optional-dependencies"][args.extra]]
    roots = list(dict.fromkeys(roots))
    dists = installed(args.site)
    missing = [r for r in roots if r not in dists]
    if missing:
        raise SystemExit(f"not installed in {args.site}: {', '.join(missing)}")
    reach = {r: closure(r, dists) for r in roots}
    mib = 2.0**20

    def size(names):
        return sum(dists[n][0] for n in names) / mib

    print(f"{'requirement':<22} {'exclusive MiB':>13} {'with its deps':>13}  largest exclusive parts")
    for r in sorted(roots, key=lambda r: -size(reach[r] - set().union(*(reach[o] for o in roots if o != r)))):
        own = reach[r] - set().union(*(reach[o] for o in roots if o != r))
        parts = ", ".join(sorted(own, key=lambda n: -dists[n][0])[:4])
        print(f"{r:<22} {size(own):>13.0f} {size(reach[r]):>13.0f}  {parts}")
    print(f"{'all of them':<22} {size(set().union(*reach.values())):>13.0f}")


if __name__ == "__main__":
    main()
