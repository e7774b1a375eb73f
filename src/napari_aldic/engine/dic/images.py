"""The image pair as the Local DIC kernels need it, prefiltered once
(:func:`prepare_images`), with the reference's work kept for the next pair
(``memo``) or started ahead on a background thread (``prefetch``)."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor, wait
from dataclasses import dataclass, field

import numpy as np

from .interpolation import (
    SplineImage,
    choose_order,
    jacobian_smoothing,
    prefilter,
    reference_gradients,
    steepest_descent_gradients,
)

__all__ = ["Images", "prepare_images", "RUNNING_WAIT"]

#: seconds :meth:`Images.memo` waits for a job the background thread has
#: started before computing it in place (at 1024² a job still running when
#: needed was computed twice in 2-3 runs of 6)
RUNNING_WAIT = 0.25


@dataclass
class Images:
    """The pair as the kernels need it: reference values and spline
    gradients, the deformed image's B-spline coefficients, and the
    gradients of Local IC-GN's steepest-descent images (``jgx, jgy``:
    :func:`~.interpolation.steepest_descent_gradients`; None: ``fgx, fgy``)."""

    f: np.ndarray
    g: np.ndarray
    fgx: np.ndarray
    fgy: np.ndarray
    g_spline: SplineImage
    jgx: np.ndarray | None = None
    jgy: np.ndarray | None = None
    j_sigma: float = 0.0
    #: what was computed from the reference image alone, kept for the next
    #: pair with the same reference (a sequence's frames); None: not kept
    ref_cache: dict | None = None
    #: the thread :meth:`prefetch` starts work on (None: none is started)
    background: Executor | None = None
    #: work started ahead, by ``memo`` key
    pending: dict = field(default_factory=dict)

    def memo(self, key, compute: Callable, keep: bool = True):
        """``compute()``, or its value for ``key`` kept from an earlier pair
        with this reference (the inputs of ``compute`` must be in ``key``
        unless they are the reference image itself), or started ahead by
        :meth:`prefetch`. ``keep=False``: work on this pair's deformed image,
        never kept for the next pair."""
        if keep and self.ref_cache is not None and key in self.ref_cache:
            return self.ref_cache[key]
        job = self.pending.pop(key, None)
        if job is not None and job.running():
            # started: usually near its end (the jobs take 0.02-0.1 s at
            # 1024²), and computing it here as well costs all of it twice
            # over; a while only, as a loaded machine starves the thread
            wait([job], timeout=RUNNING_WAIT)
        # not done yet (not started, or starved), or failed there (e.g. a job
        # built on another that memo claimed and cancelled first): computed
        # here rather than waited for
        usable = (job is not None and job.done() and not job.cancelled()
                  and job.exception() is None)
        value = job.result() if usable else compute()
        if job is not None:
            job.cancel()
        if keep and self.ref_cache is not None:
            self.ref_cache[key] = value
        return value

    def prefetch(self, key, compute: Callable, keep: bool = True) -> None:
        """Start ``compute()`` on :attr:`background` for a later :meth:`memo`
        of ``key`` (unless it is kept already; nothing without a background
        thread; ``keep`` as for :meth:`memo`): work on the images alone that
        overlaps the analysis, on a core its serial stages leave idle (the
        thread runs at a low priority; what it has not started when needed
        is computed there and then, what it has started is waited for up to
        :data:`RUNNING_WAIT`, so it never holds the analysis up for long)."""
        if self.background is None or key in self.pending:
            return
        if self.ref_cache is None or key not in self.ref_cache or not keep:
            self.pending[key] = self.background.submit(compute)


def prepare_images(f: np.ndarray, g: np.ndarray, interpolation: str,
                   jacobian_sigma: float | None = None, ref_cache: dict | None = None) -> Images:
    """Prefilter once: reference gradients and deformed-image coefficients
    (``interpolation="auto"`` picks the order from the speckle size);
    ``jacobian_sigma``: the smoothing of the steepest-descent images (px)
    when chosen beforehand on the whole reference (tiled runs), else chosen
    on ``f`` (:func:`~.interpolation.jacobian_smoothing`). ``ref_cache``: a
    dictionary kept while the reference image stays the same (``correlate``'s
    ``solver_cache``), where the reference's spline and gradients are kept."""
    im = Images(f, g, None, None, None, ref_cache=ref_cache)
    order = im.memo(("order", interpolation), lambda: choose_order(interpolation, f))
    # the two spline prefilters and the reference's exact gradients (serial
    # kernels, GIL released) run on a second thread while this one smooths
    # the reference for the steepest-descent images (1024², 2 cores: 0.11 s
    # in one thread, 0.06-0.08 s in two with scipy's filters, 0.04 s with the
    # kernels of kernels/prefilter.py)
    with ThreadPoolExecutor(1) as pool:
        g_spline = []

        def reference():
            exact = pool.submit(lambda: reference_gradients(prefilter(f, order)))
            g_spline.append(pool.submit(prefilter, g, order))
            sigma = jacobian_smoothing(f) if jacobian_sigma is None else float(jacobian_sigma)
            jgx, jgy = steepest_descent_gradients(f, order, sigma)
            return (*exact.result(), sigma, jgx, jgy)

        im.fgx, im.fgy, im.j_sigma, im.jgx, im.jgy = im.memo(
            ("images", interpolation, jacobian_sigma), reference)
        im.g_spline = (g_spline[0] if g_spline else pool.submit(prefilter, g, order)).result()
    return im
