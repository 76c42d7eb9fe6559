"""Entity paths and strict logging: the two rules every ``log_*`` function follows."""

from __future__ import annotations

from rerun.error_utils import catch_and_log_exceptions

from ..validate import BananagridError

__all__ = ["entity_path", "strict"]


def entity_path(entity: str) -> str:
    """``entity`` without leading or trailing slashes; raise if that leaves nothing."""
    if not isinstance(entity, str) or not entity.strip("/"):
        raise BananagridError(f"entity = {entity!r}: expected a non-empty entity path")
    return entity.strip("/")


def strict() -> catch_and_log_exceptions:
    """Make rerun raise on bad data inside this block instead of warning and dropping it.

    A recording that silently lacks a layer is worse than an error: :func:`write_recording`
    then removes the partial file. The setting is thread-local and restored on exit.
    """
    return catch_and_log_exceptions("bananagrid.recording", strict=True)
