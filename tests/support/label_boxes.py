"""Labels as rerun draws them, read back from a recording: what the tests of the label placement
check (no two boxes overlap, each inside its view).

A label's box is sized from the viewer's text metrics measured on its screenshots
(:mod:`bananagrid.recording.labels`: 17.5 points high, 6.5 points a character and 8 of padding
wide, centred under its point 1.5 points below it), in metres by a map's scale (metres per
point)."""

from __future__ import annotations

import numpy as np
from rerun.chunk import RrdReader

from bananagrid.recording.labels import BOX_PADDING_POINTS, CHAR_POINTS, LABEL_GAP_POINTS, TEXT_HEIGHT_POINTS

def shown_labels(path, root: str) -> list[tuple[str, tuple[float, float], str]]:
    """Every label drawn under ``root`` (text, (x, y), entity): points with their labels shown, and
    a line's label (at the mean of its vertices, where rerun draws it) when shown."""
    out = []
    for chunk in RrdReader(path).stream():
        entity = chunk.entity_path
        if not entity.startswith(root):
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        for kind in ("Points2D", "LineStrips2D", "Points3D", "LineStrips3D"):
            if f"{kind}:labels" not in names:
                continue
            shown = f"{kind}:show_labels" in names and batch.column(f"{kind}:show_labels")[0].as_py()
            shown = bool(shown[0]) if isinstance(shown, list) else bool(shown)
            texts = batch.column(f"{kind}:labels")[0].as_py()
            if not shown:
                continue
            if kind.startswith("Points"):
                spots = batch.column(f"{kind}:positions")[0].as_py()
            else:
                spots = [np.mean(np.array(strip), axis=0) for strip in batch.column(f"{kind}:strips")[0].as_py()]
            out += [(t, (float(p[0]), float(p[1])), entity) for t, p in zip(texts, spots)]
    return out


def hidden_only_on_hover(path, root: str, placed_entities: tuple[str, ...]) -> None:
    """Labels are shown only by the placed entities (labels, ticks, scale bar, contour labels)."""
    for chunk in RrdReader(path).stream():
        if not chunk.entity_path.startswith(root):
            continue
        batch = chunk.to_record_batch()
        for kind in ("Points2D", "LineStrips2D"):
            if f"{kind}:labels" in batch.schema.names and not chunk.entity_path.endswith(placed_entities):
                shown = batch.column(f"{kind}:show_labels")[0].as_py() if f"{kind}:show_labels" in batch.schema.names else None
                assert shown in ([False], False), f"{chunk.entity_path} shows labels rerun places itself"


def box(anchor, text: str, scale: float) -> tuple[float, float, float, float]:
    """Where rerun draws ``text`` for a point at ``anchor`` (north up): centred across, below."""
    half = 0.5 * (CHAR_POINTS * len(text) + BOX_PADDING_POINTS) * scale
    return (anchor[0] - half, anchor[0] + half,
            anchor[1] - (LABEL_GAP_POINTS + TEXT_HEIGHT_POINTS) * scale, anchor[1] + LABEL_GAP_POINTS * scale)


def assert_apart(labels, scale: float) -> None:
    """No two label boxes share more than an edge (1e-9 of a point of slack for rounding)."""
    boxes = [box(anchor, text, scale) for text, anchor, _ in labels]
    eps = 1e-9 * scale
    for i in range(len(boxes)):
        for j in range(i):
            a, b = boxes[i], boxes[j]
            overlap = a[0] < b[1] - eps and b[0] < a[1] - eps and a[2] < b[3] - eps and b[2] < a[3] - eps
            assert not overlap, f"{labels[i][0]!r} ({labels[i][2]}) over {labels[j][0]!r} ({labels[j][2]})"
