"""What the plugin's Run button does, without napari: track a stack, then strain.

The dock widget calls :func:`run_analysis` in a worker thread; tests and scripts
can call it directly. Everything here is a thin layer over the engine
(:func:`~napari_aldic.engine.track`, :func:`~napari_aldic.engine.correlate`,
:func:`~napari_aldic.engine.compute_strain`); no napari or Qt is imported.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from .engine import DICParams, DICResult, Refinement, compute_strain, track
from .engine.dic.quadtree import resolve_refinement

__all__ = ["Analysis", "StrainSettings", "run_analysis"]

ProgressFn = Callable[[int, float, str], None]


@dataclass(frozen=True)
class StrainSettings:
    """How strain is computed from each frame's displacement field."""

    window: int = 5
    method: str = "plane_fit"
    measure: str = "green_lagrange"


@dataclass
class Analysis:
    """The outcome of one run, as the plugin shows it.

    Attributes
    ----------
    results : list of DICResult or None
        One per analysed frame (``None``: not computed, e.g. cancelled);
        ``results[0]`` is the reference frame (zero field).
    strains : list of StrainResult or None
        Strain of each result (``None`` where there is no result).
    frames : list of int
        Index of each analysed frame in the image stack (time axis).
    n_frames : int or None
        Length of the image's time axis; ``None`` for a single pair shown
        without a time axis (e.g. a result file opened on its own).
    """

    results: list
    strains: list
    frames: list
    n_frames: int | None
    params: DICParams
    reference: str = "accumulative"
    strain: StrainSettings = field(default_factory=StrainSettings)
    cancelled: bool = False
    seconds: float = 0.0
    source: str = ""

    @property
    def n_done(self) -> int:
        """Frames with a result (the reference frame included)."""
        return sum(r is not None for r in self.results)

    def lattice(self) -> DICResult | None:
        """A computed result whose node lattice the image layers use."""
        for r in self.results:
            if r is not None:
                return r
        return None


def _zero_field(res: DICResult) -> DICResult:
    """``res`` with zero displacement (the reference frame of a sequence)."""
    z = np.zeros_like(res.u)
    return replace(res, u=z, v=z.copy(), dudx=z.copy(), dudy=z.copy(), dvdx=z.copy(),
                   dvdy=z.copy(), zncc=np.ones_like(res.zncc), meta={**res.meta, "frame": 0})


def _track_refined(stack, roi, params: DICParams, frames: list[int], refine: Refinement,
                   progress: ProgressFn, cancel) -> tuple[list, bool]:
    """Accumulative tracking with a full :class:`Refinement` (e.g. a brush region).

    ``track`` takes refinement only as a preset name in ``DICParams``, so a
    painted region goes through ``correlate(refine=...)`` frame by frame here,
    each frame against frame 0, started from the previous frame's field.
    """
    from .engine import correlate, open_stack

    src = open_stack(stack)
    plain = params.replace(refine=None)
    ref = src[0]
    results: list = [None] * len(frames)
    results[0] = _zero_field(correlate(ref, ref, roi=roi, params=plain, refine=refine))
    prev = None
    for i in range(1, len(frames)):
        if cancel is not None and cancel():
            return results, True
        k = frames[i]
        progress(k, (i - 1) / (len(frames) - 1), f"frame {k} against frame 0")
        res = correlate(ref, src[k], roi=roi, params=plain, refine=refine, guess=prev)
        res.meta["frame"] = k
        res.meta["reference_frame"] = 0
        results[i] = prev = res
        progress(k, i / (len(frames) - 1), f"frame {k} done: {res.n_valid}/{len(res)} valid")
    return results, False


def run_analysis(stack, roi, params: DICParams, *, reference: str = "accumulative",
                 start: int = 0, stop: int | None = None, stride: int = 1,
                 brush: np.ndarray | None = None,
                 strain: StrainSettings | None = StrainSettings(),
                 progress: ProgressFn | None = None, cancel: Callable[[], bool] | None = None,
                 source: str = "") -> Analysis:
    """Track frames ``start, start + stride, ... <= stop`` of ``stack`` against
    frame ``start`` and compute strain.

    Parameters
    ----------
    stack : (T, H, W) array (NumPy or dask; read lazily frame by frame)
    roi : (H, W) bool or None
    params : DICParams
    reference : {"accumulative", "incremental"}
    start, stop, stride : int
        Frame range (``stop`` inclusive; ``None`` = last frame).
    brush : (H, W) bool, optional
        Region painted for mesh refinement; combined with ``params.refine``
        (its preset, or two levels of refinement when no preset is chosen).
    strain : StrainSettings or None
        ``None`` skips strain.
    progress : callable(frame, fraction, message)
        ``frame`` is the index in ``stack``; ``fraction`` of the tracking done.
    cancel : callable() -> bool
        Polled between frames; finished frames are kept.
    """
    t0 = time.perf_counter()
    n = int(stack.shape[0])
    stop = n - 1 if stop is None else int(stop)
    if not (0 <= start < stop < n):
        raise ValueError(f"frame range {start}..{stop} is not valid for a stack of {n} frames "
                         "(the first frame must come before the last)")
    if stride < 1:
        raise ValueError(f"frame stride {stride} must be >= 1")
    rel = list(range(0, stop - start + 1, stride))
    if len(rel) < 2:
        raise ValueError(f"frames {start}..{stop} with stride {stride} hold a single frame")
    frames = [start + k for k in rel]
    sub = stack[start:stop + 1]
    report = progress or (lambda k, frac, msg: None)

    def rel_report(k: int, frac: float, msg: str) -> None:
        # the engine counts frames in the sliced stack; report stack indices
        msg = re.sub(r"frame (\d+)", lambda m: f"frame {int(m.group(1)) + start}", msg)
        report(start + k, frac, msg)

    if brush is not None and np.any(brush):
        if reference != "accumulative":
            raise ValueError("a brush refinement region needs accumulative tracking")
        base = resolve_refinement(params.refine)
        refine = (Refinement(levels=2) if base is None else base)
        refine = replace(refine, brush=np.asarray(brush, bool))
        results, cancelled = _track_refined(sub, roi, params, rel, refine, rel_report, cancel)
    else:
        seq = track(sub, roi=roi, params=params, reference=reference, frames=rel,
                    progress=rel_report, cancel=cancel)
        results, cancelled = list(seq.frames), bool(seq.meta.get("cancelled", False))
    for k, r in zip(frames, results):
        if r is not None:
            r.meta["frame"] = k  # index in the full stack
    strains: list = [None] * len(results)
    if strain is not None:
        report(frames[-1], 1.0, "computing strain")
        for i, r in enumerate(results):
            if r is not None:
                strains[i] = compute_strain(r, window=strain.window, method=strain.method,
                                            measure=strain.measure)
    return Analysis(results=results, strains=strains, frames=frames, n_frames=n,
                    params=params, reference=reference,
                    strain=strain if strain is not None else StrainSettings(),
                    cancelled=cancelled, seconds=time.perf_counter() - t0, source=source)

