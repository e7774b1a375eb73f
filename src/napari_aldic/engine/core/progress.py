"""Cooperative cancellation shared by ``correlate`` and ``track``."""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["Cancelled", "check_cancel"]

CancelFn = Callable[[], bool]


class Cancelled(Exception):
    """Raised when a cancel hook asks a running analysis to stop."""


def check_cancel(cancel: CancelFn | None) -> None:
    """Raise :class:`Cancelled` if ``cancel()`` returns True."""
    if cancel is not None and cancel():
        raise Cancelled("analysis cancelled")
