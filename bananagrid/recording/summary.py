"""The run summary a reviewer reads first in the viewer: per layer and time the captured mass,
the peak and the probability-mass regions, the warnings of the run, and how to read the maps.

Logged as a static markdown ``TextDocument`` (default entity ``summary``), after every layer,
so that it can list them all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import rerun as rr

from ..contours import format_area
from .core import HOVER_NOTE, entity_path, strict

__all__ = ["log_summary", "summary_markdown"]


#: The cell probabilities' tab of a layer (``bananagrid.scenes.run.CELL_IMAGE``).
CELL_TAB = "cell_probability"


def summary_markdown(title: str, rows: Sequence[dict], warnings: Sequence[str]) -> str:
    """The summary as markdown.

    Parameters
    ----------
    title : str
        The scene's title.
    rows : sequence of dict
        One per layer and time with ``layer``, ``t`` (s), ``mass`` (raw captured mass),
        ``peak`` (m^-2), ``peak_x``, ``peak_y`` (m) and ``regions`` (list of
        :class:`~bananagrid.contours.MassRegion`); ``mass_from`` where the mass is not the
        density's midpoint sum (e.g. ``"the cell probabilities"``); ``evidence`` where the scene
        has evidence (:func:`bananagrid.recording.evidence.evidence_values`).
    warnings : sequence of str
        One-line warnings of the run (empty: says so).
    """
    out = [f"## {title}", ""]
    if warnings:
        out += ["**Warnings**", ""] + [f"- {w}" for w in warnings] + [""]
    else:
        out += ["No warnings: every layer's grid captured the target.", ""]
    levels = [r.probability for r in rows[0]["regions"]] if rows else []
    head = ["layer", "t [s]", "captured", "peak [m^-2]", "peak at (x, y) [m]"] + [f"{100 * p:g} % area" for p in levels]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [
            row["layer"], f"{row['t']:g}", f"{row['mass']:.6f}", f"{row['peak']:.4g}",
            f"({row['peak_x']:.6g}, {row['peak_y']:.6g})",
        ] + [f"{format_area(r.area)} (holds {r.enclosed:.4f})" if r.reached else "not reached" for r in row["regions"]]
        out.append("| " + " | ".join(cells) + " |")
    found = [row["evidence"] for row in rows if row.get("evidence")]
    if found:
        searches = found[0]["searches"]
        out += ["", "**After the evidence** (the tab `evidence`: each map's prior above its posterior, the POD map, "
                "POS over time): the probability that the searches so far would have found the target (POS), "
                "together and each alone (– before it began).", "",
                "| layer | t [s] | evidence | POS | " + " | ".join(f"{name} POS" for name in searches) + " |",
                "|" + "---|" * (4 + len(searches))]
        for item in found:
            alone = [f"{p:.4f}" if math.isfinite(p) else "–" for p in item["search_pos"]]
            out.append(f"| {item['layer']} | {item['t']:g} | {', '.join(item['evidence']) or 'none yet'} | "
                       f"{item['pos']:.4f} | " + " | ".join(alone) + " |")
    out += [
        "",
        "**Reading the maps.** The first tab of each layer is log10 of the density (m^-2), "
        "with the colour bar east of the grid and a scale bar below it; the contours enclose "
        "the smallest areas holding the stated probability (highest-density regions), each "
        "labelled once with its area. North is up, x east, y north, in metres. "
        f"Views say \"{HOVER_NOTE}\": rerun's 2D views count y downwards, so the hover position "
        "of a line reads (x, −y) in metres; over an image it reads the pixel (column from the "
        "west edge, row from the north edge).",
    ]
    if len({row["layer"] for row in rows}) > 1:
        out += ["", "**Colours.** Every map shares one colour range (the highest floor and the highest top of "
                "the maps', over every layer and time), so maps side by side compare colour for colour; "
                "the colour bar says \"all maps\"."]
    out += ["", "**Labels.** Each label sits on its own line (or beside its point, with a leader) where it "
            "covers no other; one with no free spot is left off the map, and hovering its line shows it."]
    sources = sorted({row["mass_from"] for row in rows if row.get("mass_from")})
    if sources:
        out += ["", f"**Captured mass** is the sum of {' and '.join(sources)} (the tab `{CELL_TAB}` of each layer: "
                "the probability that the target is in each cell), not the densities' midpoint sum."]
    return "\n".join(out) + "\n"


def log_summary(rec: rr.RecordingStream, title: str, rows: Sequence[dict], warnings: Sequence[str],
                entity: str = "summary") -> None:
    """Log :func:`summary_markdown` as a static markdown document under ``entity``."""
    with strict():
        rec.log(
            entity_path(entity),
            rr.TextDocument(summary_markdown(title, rows, warnings), media_type=rr.MediaType.MARKDOWN),
            static=True,
        )
