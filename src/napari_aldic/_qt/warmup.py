"""Prepare the correlation engine before the first run (no Qt here but the worker).

The engine's Numba kernels are compiled the first time they run (about a
minute on a new install; later they load from Numba's on-disk cache in well
under a second). When the dock widget opens, :func:`start_in_background` runs
a tiny analysis in a worker thread that touches every kernel a run uses, and
the status line says "preparing the correlation engine (first run only)"
meanwhile. A run started before it ends waits for it (:func:`wait`): two
threads must not launch the parallel kernels at once with Numba's default
threading layer.
"""

from __future__ import annotations

import gc
import os
import threading
from collections.abc import Callable

import numpy as np

__all__ = ["warm_up", "is_warm", "wait", "start_in_background"]

_lock = threading.Lock()
_warm = threading.Event()


def warm_up() -> None:
    """Run every kernel of a typical analysis once on a tiny synthetic pair:
    local and AL-DIC with a quadtree around a hole, seed propagation, both
    strain methods. Once per process; later calls return at once."""
    if _warm.is_set():
        return
    with _lock:
        if _warm.is_set():
            return
        # compiling allocates heavily: every full garbage collection would scan the
        # whole napari process (~0.3 s, all threads stopped) again and again; objects
        # of before are left out of collections meanwhile (collected again after)
        gc.freeze()
        try:
            _run_tiny_analyses()
        finally:
            gc.unfreeze()
        _warm.set()


def _run_tiny_analyses() -> None:
    """Every kernel of a typical analysis, once, on a tiny synthetic pair."""
    from ..engine import compute_strain, correlate, precompile_kernels, synthetic

    # a first run: the kernels listed ahead compile in parallel processes (the
    # tiny analyses below then load them from Numba's cache and compile the rest)
    precompile_kernels(("local", "aldic", "strain", "synthetic"))
    size = 96
    field = synthetic.Affine.strain_rotation(exx=0.002, eyy=-0.001,
                                             center=(size / 2, size / 2), t=(0.4, -0.3))
    ref, dfm = synthetic.speckle_pair((size, size), field, seed=5)
    roi = np.ones((size, size), bool)
    roi[40:56, 40:56] = False  # a hole: subset splitting and quadtree refinement
    runs = ({"method": "local"}, {"method": "aldic", "refine": "light"},
            {"method": "local", "init": "seeds", "seeds": [(20.0, 20.0)]})
    for options in runs:
        res = correlate(ref, dfm, roi=roi, subset=17, step=8, **options)
        for method in ("plane_fit", "fem"):
            compute_strain(res, window=3, method=method)


def is_warm() -> bool:
    """Whether the engine has been prepared in this process."""
    return _warm.is_set()


def wait() -> None:
    """Block until a warm-up that is running has finished (at once otherwise)."""
    with _lock:
        pass


_errors: list[str] = []
_thread: threading.Thread | None = None


def _warm_up_safely() -> None:
    """:func:`warm_up`, its error kept as text (a failure here must not stop runs)."""
    try:
        warm_up()
    except Exception as exc:  # e.g. a broken Numba cache: the run will say more
        _errors.append(str(exc) or exc.__class__.__name__)


def start_in_background(set_preparing: Callable[[bool], None],
                        on_done: Callable[[str | None], None], parent=None) -> None:
    """Warm the engine in a thread unless it is warm already (or the environment
    variable ``NAPARI_ALDIC_WARMUP`` is ``0``): ``set_preparing(True)`` now, and
    ``on_done(error or None)`` on the main thread when it ends.

    A plain daemon thread (one per process) does the work and a timer of
    ``parent`` (a QObject: it stops with it) looks for its end, so closing the
    widget or napari meanwhile is safe.
    """
    global _thread
    if is_warm() or os.environ.get("NAPARI_ALDIC_WARMUP", "1") == "0":
        return
    from qtpy.QtCore import QTimer

    if _thread is None or not _thread.is_alive():
        _thread = threading.Thread(target=_warm_up_safely, name="napari-aldic-warm-up",
                                   daemon=True)
        _thread.start()
    set_preparing(True)
    timer = QTimer(parent)
    timer.setInterval(200)

    def poll() -> None:
        if _thread is None or not _thread.is_alive():
            timer.stop()
            on_done(_errors[-1] if _errors else None)

    timer.timeout.connect(poll)
    timer.start()
