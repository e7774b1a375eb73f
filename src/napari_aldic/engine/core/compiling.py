"""Seconds spent compiling Numba kernels, so that runs report them apart.

The first analysis in a fresh environment compiles the engine's kernels
(10-15 s on 2 cores, a minute or more before issue 25's compile work);
later ones load them from Numba's disk cache in well under a second.
Showing those seconds as analysis time
("frame 1: 72 s, 11 POI/s") misleads, so ``correlate`` records the compile
seconds of its call in ``meta["timing"]["compile"]`` (and
``meta["timing"]["analysis"]`` = total - compile), read from Numba's
``numba:compile`` events: they fire only for real compilation, not for a
kernel loaded from the cache.
"""

from __future__ import annotations

import threading
import time

__all__ = ["compile_seconds", "is_compiling"]

_lock = threading.Lock()
_state = {"depth": 0, "start": 0.0, "total": 0.0, "installed": False}


def _install() -> None:
    from numba.core import event

    class _Timer(event.Listener):
        # nested events (a kernel compiling its callees) count once: only the
        # outermost compilation is timed (Numba compiles under one global lock)
        def on_start(self, ev) -> None:
            with _lock:
                if _state["depth"] == 0:
                    _state["start"] = time.perf_counter()
                _state["depth"] += 1

        def on_end(self, ev) -> None:
            with _lock:
                _state["depth"] = max(0, _state["depth"] - 1)
                if _state["depth"] == 0:
                    _state["total"] += time.perf_counter() - _state["start"]

    event.register("numba:compile", _Timer())
    _state["installed"] = True


def compile_seconds() -> float:
    """Seconds this process has spent compiling Numba functions since the
    engine was first asked (a running compilation included)."""
    with _lock:
        if not _state["installed"]:
            _install()
        extra = time.perf_counter() - _state["start"] if _state["depth"] else 0.0
        return _state["total"] + extra


def is_compiling() -> bool:
    """True while Numba compiles a kernel in this process (e.g. for a GUI's
    "compiling kernels" note during a first run; poll it from another thread)."""
    with _lock:
        if not _state["installed"]:
            _install()
        return _state["depth"] > 0
