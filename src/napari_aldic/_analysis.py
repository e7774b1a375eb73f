"""What the plugin's Run button does, without napari: track a stack, then strain.

The dock widget collects a :class:`Job` on the main thread and runs it with
:func:`run_in_thread` in a napari worker; tests and scripts can call
:func:`run_analysis` directly. Everything here is a thin layer over the engine
(:func:`~napari_aldic.engine.track`, with a painted refine region as its
``refine=``, and :func:`~napari_aldic.engine.compute_strain`); no napari or Qt
is imported.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .engine import (
    DICParams,
    DICResult,
    ProgressEvent,
    Refinement,
    StrainParams,
    TrackError,
    compute_strain,
    correlate_sem,
    resolve_refinement,
    track,
)
from .i18n import tr

__all__ = ["Analysis", "StrainSettings", "Job", "run_analysis", "run_in_thread", "zero_field",
           "brush_refinement", "describe_fields"]

ProgressFn = Callable[[ProgressEvent], None]


#: how strain is computed from each frame's displacement field (the engine's defaults)
StrainSettings = StrainParams
_STRAIN = StrainParams()


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
    error : str
        Why the run stopped early at a frame that could not be analysed (the
        frames finished before it are kept); empty when it did not.
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
    error: str = ""

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


def zero_field(res: DICResult) -> DICResult:
    """``res`` with zero displacement (the reference frame of a sequence)."""
    z = np.zeros_like(res.u)
    return replace(res, u=z, v=z.copy(), dudx=z.copy(), dudy=z.copy(), dvdx=z.copy(),
                   dvdy=z.copy(), zncc=np.ones_like(res.zncc), meta={**res.meta, "frame": 0})


def brush_refinement(preset: str | None, brush: np.ndarray) -> Refinement:
    """The refinement of a painted region: ``preset``'s criteria (two levels of
    refinement when there is no preset) plus the region ``brush``."""
    base = resolve_refinement(preset)
    return replace(Refinement(levels=2) if base is None else base,
                   brush=np.asarray(brush, bool))


def _relative_frames(n: int, start: int, stop: int, stride: int) -> list[int]:
    """Frames ``0, stride, ... <= stop - start`` of the sliced stack (checked)."""
    if not (0 <= start < stop < n):
        raise ValueError(tr("frame range {start}..{stop} is not valid for a stack of {n} "
                            "frames (the first frame must come before the last)").format(
                                start=start, stop=stop, n=n))
    if stride < 1:
        raise ValueError(tr("frame stride {stride} must be >= 1").format(stride=stride))
    rel = list(range(0, stop - start + 1, stride))
    if len(rel) < 2:
        raise ValueError(tr("frames {start}..{stop} with stride {stride} hold a single "
                            "frame").format(start=start, stop=stop, stride=stride))
    return rel


def _tracked(sub, roi, params, reference, rel, start, brush, report, cancel):
    """``track`` of the sliced stack: ``(results, cancelled, error)`` (a bad frame
    ends the run with the frames finished before it)."""
    def rel_report(ev: ProgressEvent) -> None:
        # the engine counts frames in the sliced stack; report stack indices
        ref = None if ev.reference is None else ev.reference + start
        report(replace(ev, frame=None if ev.frame is None else ev.frame + start,
                       reference=ref))

    refine = None
    if brush is not None and np.any(brush):
        if reference != "accumulative":
            raise ValueError(tr("a brush refinement region needs accumulative tracking"))
        refine = brush_refinement(params.refine, brush)  # replaces the preset
    error = ""
    try:
        seq = track(sub, roi=roi, params=params, reference=reference, frames=rel,
                    refine=refine, progress=rel_report, cancel=cancel)
    except TrackError as exc:  # a bad frame: show the frames finished before it
        if not any(r is not None for r in exc.partial.frames[1:]):
            raise
        seq, error = exc.partial, str(exc)
        report(ProgressEvent("stopped", 1.0, frame=start + exc.frame, n_frames=len(rel) - 1,
                             message="stopped at a bad frame, finished frames kept (done "
                                     f"before it): {error}"))
    return list(seq.frames), bool(seq.meta.get("cancelled", False)), error


def run_analysis(stack, roi, params: DICParams, *, reference: str = "accumulative",
                 start: int = 0, stop: int | None = None, stride: int = 1,
                 brush: np.ndarray | None = None,
                 strain: StrainSettings | None = _STRAIN,
                 progress: ProgressFn | None = None, cancel: Callable[[], bool] | None = None,
                 source: str = "", sem: dict | None = None) -> Analysis:
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
    progress : callable(ProgressEvent)
        ``event.frame`` is the index in ``stack`` (not in the tracked slice);
        ``event.fraction`` of the tracking done; stages of ``track`` plus
        ``"stopped"`` (a bad frame ended the run) and ``"strain"``.
    cancel : callable() -> bool
        Polled between frames; finished frames are kept.
    sem : dict, optional
        ``correlate_sem`` options (issue 27): the pair of the range (one
        deformed frame) is measured with those SEM corrections.
    """
    t0 = time.perf_counter()
    n = int(stack.shape[0])
    stop = n - 1 if stop is None else int(stop)
    rel = _relative_frames(n, start, stop, stride)
    frames = [start + k for k in rel]
    sub = stack[start:stop + 1]
    report = progress or (lambda ev: None)

    if sem is not None:  # issue 27: one SEM pair with its corrections
        if len(rel) != 2 or (brush is not None and np.any(brush)):
            raise ValueError(tr("SEM corrections apply to a pair: choose a frame range with "
                                "one deformed frame and no brush refinement region"))
        pair = correlate_sem(np.asarray(sub[0]), np.asarray(sub[rel[1]]), roi, params, **sem)
        results, cancelled, error = [zero_field(pair), pair], False, ""
    else:
        results, cancelled, error = _tracked(sub, roi, params, reference, rel, start, brush,
                                             report, cancel)
    for k, r in zip(frames, results):
        if r is not None:
            r.meta["frame"] = k  # index in the full stack
    strains: list = [None] * len(results)
    if strain is not None:
        # the fraction of the frames tracked (below 1 after a cancel)
        done = sum(r is not None for r in results[1:]) / max(1, len(results) - 1)
        report(ProgressEvent("strain", done, frame=frames[-1], n_frames=len(rel) - 1,
                             message="computing strain"))
        for i, r in enumerate(results):
            if r is not None:
                strains[i] = compute_strain(r, window=strain.window, method=strain.method,
                                            measure=strain.measure)
    return Analysis(results=results, strains=strains, frames=frames, n_frames=n,
                    params=params, reference=reference,
                    strain=strain if strain is not None else StrainSettings(),
                    cancelled=cancelled, seconds=time.perf_counter() - t0, source=source,
                    error=error)



def describe_fields(fields: dict) -> str:
    """``name=value, ...`` of parameter fields (for the log)."""
    return ", ".join(f"{k}={v!r}" for k, v in fields.items())


@dataclass
class Job:
    """Everything one run needs, collected from the widget on the main thread."""

    stack: Any
    roi: np.ndarray | None
    params: DICParams
    reference: str = "accumulative"
    start: int = 0
    stop: int | None = None
    stride: int = 1
    brush: np.ndarray | None = None
    strain: StrainSettings = field(default_factory=StrainSettings)
    source: str = ""
    summary: str = ""
    #: ``correlate_sem`` options (issue 27), or None for a plain run
    sem: dict | None = None
    #: the dock's units: the log's result summary says lengths in them (issue 24, trap 16)
    units: Any = None

    @property
    def n_deformed(self) -> int:
        """Frames to correlate (the reference frame not counted)."""
        stop = int(self.stack.shape[0]) - 1 if self.stop is None else int(self.stop)
        return len(range(self.start, stop + 1, self.stride)) - 1

    def describe(self, roi_notes: list[str], extra: dict | None = None) -> str:
        """The job in words (for the log): image, frames, ROI (``roi_notes``: how
        it was made), parameters, strain and the ``extra`` parameters kept from a
        settings file."""
        n, rows, cols = self.stack.shape
        p = self.params
        n_roi = rows * cols if self.roi is None else int(self.roi.sum())
        stop = n - 1 if self.stop is None else int(self.stop)
        s = self.strain
        roi = (tr("ROI {n} px [{notes}]").format(n=n_roi, notes="; ".join(roi_notes)) if roi_notes
               else tr("ROI {n} px (whole image)").format(n=n_roi))
        init = (tr("init {init} ({n} seeds)").format(init=p.init, n=len(p.seeds)) if p.seeds
                else tr("init {init}").format(init=p.init))
        refine = p.refine or "none"
        refine = (tr("refinement {refine} + brush region ({n} px)").format(
            refine=refine, n=int(self.brush.sum())) if self.brush is not None
            else tr("refinement {refine}").format(refine=refine))
        method = [tr("method {method}").format(method=p.method),
                  tr("subset {subset} px").format(subset=p.subset),
                  tr("step {step} px").format(step=p.step),
                  tr("search {search} px").format(search=p.search), init, refine]
        if p.method == "aldic":
            method.append(tr("smoothing {smooth}").format(smooth=p.smooth))
        clauses = [tr("image '{source}' ({n} frames, {cols} x {rows} px, {dtype})").format(
                       source=self.source, n=n, cols=cols, rows=rows, dtype=self.stack.dtype),
                   tr("frames {start}..{stop} every {stride}, {reference}").format(
                       start=self.start, stop=stop, stride=self.stride,
                       reference=self.reference),
                   roi, ", ".join(method),
                   tr("strain {method}, window {window}, {measure}").format(
                       method=s.method, window=s.window, measure=s.measure)]
        if extra:
            clauses.append(tr("from the parameter file: {fields}").format(
                fields=describe_fields(extra)))
        return "; ".join(clauses)

    def run(self, progress: ProgressFn | None = None,
            cancel: Callable[[], bool] | None = None) -> Analysis:
        """:func:`run_analysis` of this job."""
        return run_analysis(self.stack, self.roi, self.params, reference=self.reference,
                            start=self.start, stop=self.stop, stride=self.stride,
                            brush=self.brush, strain=self.strain, progress=progress,
                            cancel=cancel, source=self.source, sem=self.sem)


def run_in_thread(job: Job, cancel: threading.Event,
                  after: Callable[[Analysis], Any] | None = None,
                  before: Callable[[], Any] | None = None
                  ) -> Generator[ProgressEvent, None, tuple[Analysis, Any]]:
    """Run ``job`` in a helper thread; yield its progress reports
    (:class:`~napari_aldic.engine.ProgressEvent`) and return ``(analysis, after(analysis))``
    (``None`` for the second without ``after``).

    The engine reports through a callback; the callback queues the reports
    and this generator yields them, so a napari generator worker delivers
    each one to the main thread. ``before`` runs first in the helper thread
    (e.g. to wait until the correlation engine is prepared), ``after`` runs in
    the worker too (e.g. to make the result layers away from the event loop).
    An exception is raised here.
    """
    reports: queue.Queue = queue.Queue()
    box: dict = {}

    def target():
        try:
            if before is not None:
                before()
            box["result"] = job.run(reports.put, cancel.is_set)
        except BaseException as exc:  # re-raised in the generator
            box["error"] = exc
        finally:
            reports.put(None)

    thread = threading.Thread(target=target, name="napari-aldic-analysis", daemon=True)
    thread.start()
    while (item := reports.get()) is not None:
        yield item
    thread.join()
    if "error" in box:
        raise box["error"]
    analysis = box["result"]
    return analysis, (after(analysis) if after is not None else None)
