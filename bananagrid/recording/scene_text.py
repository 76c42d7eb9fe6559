"""The scene file as a static markdown text document."""

from __future__ import annotations

import rerun as rr

from .entities import entity_path, strict

__all__ = ["log_scene_text"]


def log_scene_text(rec: rr.RecordingStream, text: str, entity: str = "scene") -> None:
    """Log the scene file as a static markdown ``TextDocument`` (a fenced TOML block).

    rerun renders ``text/plain`` and ``text/markdown`` only, so the TOML goes in a fence.
    """
    with strict():
        rec.log(
            entity_path(entity),
            rr.TextDocument(_fenced(text, "toml"), media_type=rr.MediaType.MARKDOWN),
            static=True,
        )


def _fenced(text: str, language: str) -> str:
    """``text`` in a markdown code fence longer than any backtick run inside it."""
    fence = "`" * max(3, _longest_run(text, "`") + 1)
    return f"{fence}{language}\n{text.rstrip()}\n{fence}\n"


def _longest_run(text: str, char: str) -> int:
    """Length of the longest run of ``char`` in ``text``."""
    best = run = 0
    for c in text:
        run = run + 1 if c == char else 0
        best = max(best, run)
    return best
