"""Progress events and cooperative cancellation shared by ``correlate`` and ``track``.

``correlate(..., progress=fn)`` and ``track(..., progress=fn)`` call ``fn(event)``
with a :class:`ProgressEvent`: what is being done (``stage``), for which frame,
how far the run is (``fraction``) and the time left (``eta_s``). Callers read
the fields; ``str(event)`` is the same human text the engine printed before.

Callbacks written for 0.1 (``fn(fraction, message)`` for ``correlate``,
``fn(frame, fraction, message)`` for ``track``) still work for one release:
they get ``str(event)`` as the message, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Cancelled", "check_cancel", "ProgressEvent", "event_callback"]

CancelFn = Callable[[], bool]

#: stages of one ``correlate`` call, in order
CORRELATE_STAGES = ("setup", "prefilter", "initial_guess", "icgn", "repair", "aldic", "done")
#: stages ``track`` reports per frame (``correlate``'s are passed on within a frame)
TRACK_STAGES = ("frame_start", "frame_done", "frame_loaded")


class Cancelled(Exception):
    """Raised when a cancel hook asks a running analysis to stop."""


def check_cancel(cancel: CancelFn | None) -> None:
    """Raise :class:`Cancelled` if ``cancel()`` returns True."""
    if cancel is not None and cancel():
        raise Cancelled("analysis cancelled")


@dataclass(frozen=True)
class ProgressEvent:
    """One progress report of ``correlate`` or ``track``.

    Attributes
    ----------
    stage : str
        What was just reached: a stage of ``correlate`` (``"setup"``,
        ``"prefilter"``, ``"initial_guess"``, ``"icgn"``, ``"repair"``,
        ``"aldic"``, ``"done"``) or of ``track`` (``"frame_start"``,
        ``"frame_done"``, ``"frame_loaded"``).
    fraction : float
        Share of the whole call done, 0 to 1.
    frame : int or None
        ``track``: the frame number in the stack (absolute, as in
        ``frames=``); ``None`` for a single ``correlate`` call.
    n_frames : int
        Deformed frames of the run (the reference not counted); 1 for a pair.
    eta_s : float or None
        Estimated seconds left (``None`` until it can be estimated).
    message : str
        Detail of the stage (``"1234 nodes"``, ``"12/40 valid"``, a file name).
    reference : int or None
        ``track``: the reference frame of ``frame``.
    """

    stage: str
    fraction: float
    frame: int | None = None
    n_frames: int = 1
    eta_s: float | None = None
    message: str = ""
    reference: int | None = None

    def __str__(self) -> str:
        if self.stage == "frame_start":
            return f"frame {self.frame} against frame {self.reference}"
        if self.stage == "frame_done":
            return f"frame {self.frame} done" + (f": {self.message}" if self.message else "")
        if self.stage == "frame_loaded":
            return f"frame {self.frame}: loaded from {self.message}"
        return self.message or self.stage


def _positional(fn) -> int:
    """How many positional arguments ``fn`` takes (1 when it takes ``*args``
    or its signature cannot be read: it is then given the event)."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return 1
    n = 0
    for p in sig.parameters.values():
        if p.kind is p.VAR_POSITIONAL:
            return max(n, 1)
        if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD):
            n += 1
    return n


def event_callback(fn, legacy: str, stacklevel: int = 3) -> Callable[[ProgressEvent], None]:
    """``fn`` as a callback of :class:`ProgressEvent` (a no-op for ``None``).

    ``legacy`` says how a 0.1 callback of several positional arguments is
    called: ``"correlate"`` as ``fn(fraction, str(event))``, ``"track"`` as
    ``fn(frame, fraction, str(event))`` with only ``track``'s own stages (as
    0.1 reported them).
    """
    if fn is None:
        return lambda event: None
    if _positional(fn) <= 1:
        return fn
    warnings.warn(f"a {legacy} progress callback of several arguments is deprecated: it "
                  "will be called with one ProgressEvent (str(event) is the message)",
                  DeprecationWarning, stacklevel=stacklevel)
    if legacy == "track":
        def old_track(event: ProgressEvent) -> None:
            if event.stage in TRACK_STAGES:
                fn(event.frame, event.fraction, str(event))
        return old_track
    return lambda event: fn(event.fraction, str(event))
