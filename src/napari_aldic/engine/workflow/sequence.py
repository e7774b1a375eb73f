"""Image sequences: lazy frame sources and ``track``.

Results of every frame refer to frame 0 (Lagrangian): ``seq[k].u`` at node
``(x, y)`` of frame 0 is the displacement of that material point between
frame 0 and frame k, whatever the reference strategy:

* ``reference="accumulative"``: frame k is correlated against frame 0;
* ``reference="incremental"``: frame k against frame k-1; the increments are
  composed back to frame 0, ``u_0k(X) = u_0,k-1(X) + du(X + u_0,k-1(X))``,
  with ``du`` interpolated (bilinearly on the node lattice of frame k-1) at
  the displaced positions;
* ``update_every=N`` (accumulative only): the reference image is replaced by
  frame N, 2N, ... and the same composition links each block back to frame 0.

The previous frame's field is the initial guess of the next one (within a
reference block). Frames are read only when needed. With ``out_dir`` each
frame's result is written as soon as it is computed (``frame_00003.npz``,
written under a temporary name and renamed), so an interrupted run keeps
every finished frame, and a rerun with the same ``out_dir`` and inputs
resumes where it stopped (:mod:`.runfolder`: the manifest, the checks and the
lock). A frame that cannot be analysed raises :class:`TrackError`, which
carries the frames finished before it.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.files import RunFolderError, array_digest, explain_os_error, explained
from ..core.images import validate_roi
from ..core.params import DICParams
from ..core.progress import Cancelled, ProgressEvent, event_callback
from ..core.results import DICResult, LazyFrames, SequenceResult, load_result
from ..core.roifile import write_roi_file
from ..dic.correlate import correlate, reference_result
from ..dic.roi_warp import carry_roi
from ..io.stack import frame_numbers, open_stack
from ..io.zarrstore import STORE_NAME, FieldStore
from .cluster import check_scheduler, run_parallel
from .compose import compose
from .runfolder import (
    IMAGE_DIGEST,
    MANIFEST,
    frame_file_meta,
    record_digests,
    refine_record,
    roi_record,
    run_folder,
    run_id,
    stack_record,
)

__all__ = ["track", "TrackError", "RunFolderError", "SequenceRun", "Chain"]

_ON_DISK = object()  # a finished frame kept only in the run folder


class TrackError(ValueError):
    """A frame of :func:`track` could not be read or analysed (an unreadable
    file, a frame of another size, ...). The frames finished before it (with
    a ``scheduler``: every frame finished) are not lost: ``partial`` is the
    :class:`SequenceResult` of the run so far (frames not computed are
    ``None``; ``partial.meta["failed_frame"]`` is ``frame``), and the
    original error is ``__cause__``."""

    def __init__(self, message: str, partial: SequenceResult, frame: int):
        super().__init__(message)
        self.partial = partial
        self.frame = frame


def track(stack, roi=None, subset: int | None = None, step: int | None = None,
          method: str | None = None, reference: str = "accumulative", *,
          update_every: int | None = None, rois=None, frames=None, out_dir=None,
          params: DICParams | None = None, scheduler=None, workers: int | None = None,
          refine=None, meta: dict | None = None,
          progress: Callable[[ProgressEvent], None] | None = None,
          on_frame: Callable[[int, DICResult], None] | None = None,
          cancel: Callable[[], bool] | None = None, **kwargs) -> SequenceResult:
    """Track a sequence of images; every result refers to frame 0.

    Parameters
    ----------
    stack : (T, H, W) array, dask array, TIFF stack path or image folder
    roi : (H, W) bool, optional
        ROI in frame 0 (holes and cracks False).
    subset, step, method, params, **kwargs : as for ``correlate`` (explicit ones win)
    reference : {"accumulative", "incremental"}
    update_every : int, optional
        With ``"accumulative"``: use frame N, 2N, ... as the new reference.
    rois : sequence of (H, W) bool or callable(k) -> mask, optional
        Per-frame ROI of the *reference* image used for frame k (e.g. a
        growing crack); the frame-0 ROI defaults to ``roi``.
    frames : sequence of int, optional
        Frames to analyse (starting with 0, increasing); default all.
    out_dir : path, optional
        A run folder: each frame is written as it finishes (``frame_#####.npz``,
        ``fields.zarr``) and a rerun resumes; locked while written, refused when
        of another analysis or its inputs changed (``workflow.runfolder``). Only
        frames later frames are composed with stay in memory.
    scheduler : None, "threads", "processes", a ``dask.distributed.Client`` or its address
        ``None``: frames one after the other, each started from the previous
        field. Otherwise frames run concurrently (threads, a local cluster of
        ``workers`` one-thread processes, or a dask cluster whose workers read
        their own frames: :mod:`~napari_aldic.engine.workflow.cluster`).
    workers : int, optional
        Concurrent frames for ``scheduler="threads"`` and worker processes
        for ``"processes"`` (default: CPU count).
    refine : preset name, Refinement or dict, optional
        Quadtree refinement for every frame (as in ``correlate``), e.g. a
        ``Refinement(brush=mask)`` painted region.
    meta : dict, optional
        JSON-compatible entries added to every frame's ``meta`` (e.g.
        ``{"units": units.to_dict()}``); part of a run folder's identity.
        Without ``"units"``: the stack file's own (``FrameSource.units``).
    progress : callable(ProgressEvent), optional
        Each frame's start, end (or load) and correlation stages, ``event.frame``
        its number in ``stack``; 0.1's ``(frame, fraction, message)`` is deprecated.
    on_frame : callable(frame, result), optional
        Called with each frame's final (frame-0 referenced) result as soon as
        it is computed, e.g. to save or display it.
    cancel : callable() -> bool, optional
        Polled before each frame and between the stages of a frame; True
        stops the run promptly (finished frames kept, the frame in progress
        dropped).

    Returns
    -------
    SequenceResult

    Raises
    ------
    TrackError
        A frame could not be read or analysed; ``error.partial`` holds the
        frames finished before it (with ``out_dir`` they are also on disk).
    RunFolderError
        ``out_dir`` is in use, holds another analysis, or its inputs changed.
    """
    _check_modes(reference, update_every)
    check_scheduler(scheduler, workers)
    src = open_stack(stack)
    params = DICParams.combine(params, kwargs, subset=subset, step=step, method=method)
    idx = frame_numbers(frames, len(src))
    run = SequenceRun(src, idx, reference, update_every, roi, rois, params, refine,
                      _with_file_units(src, meta), event_callback(progress, "track"),
                      on_frame)
    if out_dir is None:
        return run.execute(stack, scheduler, workers, cancel)
    with run_folder(out_dir, info := run.identity()) as out:
        run.out, run.run_id = out, run_id(info)
        return run.execute(stack, scheduler, workers, cancel)


def _with_file_units(src, meta: dict | None) -> dict:
    """``meta`` with the pixel size / frame interval the stack's file records
    (and where they came from) when it gives no ``"units"`` itself."""
    meta = dict(meta or {})
    if "units" not in meta and getattr(src, "units", None) is not None:
        meta.update(units=src.units.to_dict(), units_source=src.units_source)
    return meta


def _check_modes(reference: str, update_every: int | None) -> None:
    if reference not in ("accumulative", "incremental"):
        raise ValueError(f"reference={reference!r} must be 'accumulative' or 'incremental'")
    if update_every is not None and (update_every < 1 or reference != "accumulative"):
        raise ValueError("update_every must be >= 1 and needs reference='accumulative'")


@dataclass
class SequenceRun:
    """One ``track`` run: its frames, the results so far (index ``i`` of
    ``idx``), and how a frame's increment becomes its frame-0 result. A run
    whose frames arrive while it runs (``watch``) grows with :meth:`extend`
    and correlates them one by one with :meth:`step`."""

    src: object  # the frame source (open_stack)
    idx: list  # analysed frame numbers, idx[0] == 0
    reference: str
    update_every: int | None
    roi: object
    rois: object
    params: DICParams
    refine: object
    extra: dict  # entries added to every frame's meta
    report: Callable[[ProgressEvent], None]
    on_frame: Callable[[int, DICResult], None] | None
    out: Path | None = None
    run_id: str | None = None
    results: list = field(init=False)
    store: FieldStore | None = None

    def __post_init__(self):
        self.results = [None] * len(self.idx)
        self._users: Counter = Counter()  # index -> frames still to compose with it
        self._pos = {k: i for i, k in enumerate(self.idx)}
        self._whole = None  # the one ROI array of a run without per-frame ROIs
        self._roi_refs: dict = {}  # id(mask) -> (mask, digest, ROI file reference)
        self._carried: tuple = (None, None)  # (frame, frame 0's ROI carried onto it)
        self.digests: dict = {}  # frame -> SHA-256 of its image, as read
        self._clock: tuple = (time.perf_counter(), None)  # (start, fraction then)

    def emit(self, stage: str, i: int, frac: float, message: str = "") -> None:
        """Report ``stage`` of frame ``idx[i]`` with the share ``frac`` of the
        run done, and the time left estimated from the frames computed."""
        t0, f0 = self._clock
        if f0 is None and stage == "frame_start":  # frames loaded from disk not timed
            self._clock = t0, f0 = time.perf_counter(), frac
        eta = None
        if f0 is not None and frac > f0:
            eta = (time.perf_counter() - t0) * (1 - frac) / (frac - f0)
        self.report(ProgressEvent(stage, frac, frame=self.idx[i], n_frames=len(self.idx) - 1,
                                  eta_s=eta, message=message, reference=self.ref_of(i)))

    def within(self, i: int) -> Callable[[ProgressEvent], None]:
        """``correlate``'s progress inside frame ``idx[i]``, as a share of the run."""
        n = len(self.idx) - 1
        return lambda ev: self.emit(ev.stage, i, (i - 1 + ev.fraction) / n, ev.message)

    # ------------------------------------------------------------ inputs
    def roi_for(self, k: int) -> np.ndarray:
        """ROI of the reference image ``k`` as a bool mask; without per-frame
        ROIs every frame shares one array (no full-size copy per result)."""
        shape = tuple(self.src.shape[1:])
        if self.rois is None:
            if self._whole is None:
                self._whole = validate_roi(self.roi, shape)
            return self._whole
        return validate_roi(self.rois(k) if callable(self.rois) else self.rois[k], shape)

    def roi_on(self, r: int) -> np.ndarray:
        """ROI of reference frame ``r`` on its own image: the given per-frame
        ROI, or frame 0's carried along the motion measured up to ``r``
        (material near a notch has moved; frame 0's mask would cut subsets
        where the notch was)."""
        roi = self.roi_for(r)
        if r == 0 or self.rois is not None:
            return roi
        if self._carried[0] != r:
            base = self.results[self._pos[r]]
            if base is _ON_DISK:
                base = self.load_frame(self._pos[r])
            self._carried = (r, roi if base is None else carry_roi(roi, base))
        return self._carried[1]

    def _digest(self, mask: np.ndarray) -> str:
        got = self._roi_refs.get(id(mask))
        if got is None or got[0] is not mask:
            if len(self._roi_refs) > 8:
                self._roi_refs.clear()
            got = self._roi_refs[id(mask)] = [mask, array_digest(mask), None]
        return got[1]

    def identity(self) -> dict:
        """Everything that defines this run (the run folder's manifest)."""
        refs = sorted({0} | {self.ref_of(i) for i in range(1, len(self.idx))})
        rec = {}
        for k in refs if self.rois is not None else [0]:
            m = self.roi_for(k)
            rec[str(k)] = roi_record(m, self._digest(m))
        return {"params": self.params.to_dict(), "reference": self.reference,
                "update_every": self.update_every, "frames": self.idx, "roi": rec["0"],
                "rois": rec if self.rois is not None else None,
                "refine": refine_record(self.refine), "meta": self.extra,
                "stack": stack_record(self.src, self.idx), "source": self.src.name}

    def ref_of(self, i: int) -> int:
        """Reference frame of ``idx[i]``."""
        k = self.idx[i]
        if self.reference == "incremental":
            return self.idx[i - 1]
        if self.update_every:
            r = (k - 1) // self.update_every * self.update_every
            return max(j for j in self.idx if j <= r)
        return 0

    def path_of(self, k: int):
        return None if self.out is None else self.out / f"frame_{k:05d}.npz"

    # ------------------------------------------------------------ outputs
    def save(self, res: DICResult, k: int) -> None:
        """Write frame ``k`` into the run folder, its ROI stored once per run."""
        res.meta["run_id"] = self.run_id
        ref = None
        if res.roi is not None:
            self._digest(res.roi)
            entry = self._roi_refs[id(res.roi)]
            if entry[2] is None:
                entry[2] = write_roi_file(self.out, res.roi)
            ref = entry[2]
        i = self._pos[k]
        with explained(self.store.path):  # e.g. a full disk under the field store
            self.store.write(i, res)  # the fields first: the result file says "done"
            path = res.save(self.path_of(k), roi_file=ref)
            self.store.mark_done(i, res, path)

    def load_frame(self, i: int) -> DICResult:
        return load_result(self.path_of(self.idx[i]))

    def partial(self, **meta) -> SequenceResult:
        frames = list(self.results)
        if self.out is not None:  # every finished frame is in its file: read when used
            frames = LazyFrames([None if r is None else self.path_of(k)
                                 for r, k in zip(frames, self.idx)])
        return SequenceResult(frames, self.params, self.reference,
                              {"frames": self.idx, "update_every": self.update_every,
                               "source": self.src.name, **meta})

    def failed(self, k: int, exc: Exception) -> TrackError:
        """The error of a frame that could not be analysed, carrying the
        frames finished so far."""
        n = sum(r is not None for r in self.results[1:])
        where = f" and in {self.out}" if self.out is not None else ""
        return TrackError(
            f"frame {k} ({self.src.frame_name(k)}) could not be analysed: {exc}. The {n} "
            f"finished frame(s) are kept (in the error's .partial{where})",
            self.partial(failed_frame=k, error=str(exc), cancelled=False), k)

    # ------------------------------------------------------------ running
    def execute(self, stack, scheduler, workers, cancel) -> SequenceResult:
        t0 = time.perf_counter()
        ref_img = self.start()
        todo = self.load_finished()
        if scheduler is None:
            cancelled = self.serial(todo, ref_img, cancel)
        else:
            cancelled = run_parallel(self, todo, scheduler, workers, cancel)
        if self.out is not None:
            record_digests(self.out, self.digests)
        return self.partial(seconds=time.perf_counter() - t0, cancelled=cancelled)

    def start(self):
        """Frame 0's result (a zero field on its nodes), saved if missing;
        returns frame 0's image."""
        ref_img = self.src[0]
        self.results[0] = reference_result(ref_img, roi=self.roi_for(0), params=self.params,
                                           refine=self.refine)
        self.results[0].meta.update(self.extra)
        self.results[0].meta[IMAGE_DIGEST] = self.digests[0] = array_digest(ref_img)
        if self.out is not None:
            try:
                self.store = FieldStore(self.out, self.run_id, self.idx,
                                        self.results[0].grid_xs, self.results[0].grid_ys)
            except ValueError as exc:
                raise RunFolderError(str(exc), self.out) from None
            except OSError as exc:
                raise explain_os_error(exc, self.out / STORE_NAME) from None  # a full disk
            if not self.path_of(0).exists():
                self.save(self.results[0], 0)
        return ref_img

    def load_finished(self) -> list[int]:
        """Find the frames already in ``out``; returns the indices still to
        do. Frames the store records as finished (with their result file
        unchanged) are not read; only those the remaining frames are
        composed with are loaded."""
        if self.out is None:
            return list(range(1, len(self.idx)))
        trusted = self.store.trusted()
        todo = []
        for i in range(len(self.idx)):
            pth = self.path_of(self.idx[i])
            if not os.path.lexists(pth):
                todo.append(i)
                continue
            self._check_frame(i, pth)
            if not trusted[i]:
                self._verify(i, pth)
            if i:
                self.results[i] = _ON_DISK
                self.emit("frame_loaded", i, i / (len(self.idx) - 1), pth.name)
        todo = [i for i in todo if i]
        for i in todo:
            self._users[self._pos[self.ref_of(i)]] += 1
        for j in self._users:
            if self.results[j] is _ON_DISK:
                self.results[j] = self.load_frame(j)
        return todo

    def _check_frame(self, i: int, pth: Path) -> None:
        """A finished frame's file is whole (CRCs), and the image it was
        computed from still holds the same pixels (its digest, recorded when
        the frame was read): else the run is refused, naming the frame."""
        k = self.idx[i]
        try:
            meta = frame_file_meta(pth)
        except ValueError as exc:
            raise RunFolderError(f"cannot read {pth} to resume the run: {exc}. Delete that "
                                 f"file to compute frame {k} again", self.out) from None
        recorded = meta.get(IMAGE_DIGEST)
        if isinstance(recorded, str):
            self.digests[k] = recorded
        if isinstance(recorded, str) and array_digest(self.src[k]) != recorded:
            raise RunFolderError(
                f"frame {k} ({self.src.frame_name(k)}) has changed since it was analysed: its "
                f"pixels differ from those {pth.name} was computed from. Resuming would mix "
                "two image sequences; put the original images back, or analyse into an "
                "empty folder", self.out)

    def _verify(self, i: int, pth: Path) -> None:
        """Check a result file not recorded in the store (a run killed
        between the two writes, or a folder of an earlier version) and add
        it to the store."""
        try:
            res = load_result(pth)
        except Exception as exc:  # damaged: say which file, and how to recover
            raise RunFolderError(f"cannot read {pth} to resume the run: {exc}. Delete "
                                 "that file to compute its frame again", self.out) from None
        if res.meta.get("run_id") != self.run_id:
            raise RunFolderError(f"{pth} belongs to another analysis than "
                                 f"{self.out / MANIFEST} (results must not mix); remove "
                                 "it or choose an empty folder", self.out)
        with explained(self.store.path):
            self.store.write(i, res)
            self.store.mark_done(i, res, pth)

    def finish(self, i: int, inc: DICResult) -> None:
        """Compose the increment of ``idx[i]`` back to frame 0, record, save
        and announce it."""
        k, r = self.idx[i], self.ref_of(i)
        digest = inc.meta.pop(IMAGE_DIGEST, None)
        shared = self.roi_for(r)
        if inc.roi is not None and inc.roi is not shared and np.array_equal(inc.roi, shared):
            inc.roi = shared  # a copy from a worker process: keep one array per run
        res = inc if r == 0 else compose(self.results[self.idx.index(r)], inc)
        res.meta.update(self.extra)
        res.meta["frame"] = k
        res.meta["reference_frame"] = r
        if digest is not None:
            res.meta[IMAGE_DIGEST] = self.digests[k] = digest
        res.meta.setdefault("inputs", {"reference": self.src.frame_name(r),
                                       "deformed": self.src.frame_name(k), "frame": k})
        self.results[i] = res
        if self.out is not None:
            self.save(res, k)
        if self.on_frame is not None:
            self.on_frame(k, res)
        self.emit("frame_done", i, i / (len(self.idx) - 1), f"{res.n_valid}/{len(res)} valid")
        if self.out is not None:  # keep only what later frames are composed with
            j = self._pos[r]
            self._users[j] -= 1
            for m in (i, j):
                if m and self._users[m] <= 0:
                    self.results[m] = _ON_DISK

    def extend(self, k: int) -> int:
        """Append frame ``k`` (after the last one) to a growing run; returns
        its index. The field store and the manifest are the caller's."""
        self.idx.append(int(k))
        self.results.append(None)
        i = self._pos[int(k)] = len(self.idx) - 1
        j = self._pos[self.ref_of(i)]
        self._users[j] += 1
        if self.results[j] is _ON_DISK:  # composed with frame k: needed in memory
            self.results[j] = self.load_frame(j)
        return i

    def serial(self, todo: list[int], ref_img, cancel) -> bool:
        """Correlate the frames of ``todo`` one after the other, each from the
        previous increment of its reference block; ``ref_img`` is frame 0.
        Returns True if cancelled."""
        chain = Chain(ref_img=ref_img)
        for i in todo:
            if cancel is not None and cancel():
                return True
            if i - 1 not in todo and i > 1:
                chain.prev = chain.before = None  # previous frame came from disk
            try:  # cancel also stops promptly inside a frame
                self.step(i, chain, cancel)
            except Cancelled:
                return True
        return False

    def step(self, i: int, chain: Chain, cancel=None) -> DICResult:
        """Correlate ``idx[i]`` from the guess ``chain`` holds (updated), then
        compose, save and announce it (:meth:`finish`); returns its increment.
        Raises :class:`~napari_aldic.engine.Cancelled` or :class:`TrackError`."""
        r, k = self.ref_of(i), self.idx[i]
        self.emit("frame_start", i, (i - 1) / max(len(self.idx) - 1, 1))
        try:
            if r != chain.ref_k:
                chain.ref_k, chain.ref_img, chain.prev, chain.before = r, self.src[r], None, None
            img = self.src[k]
            inc = correlate(chain.ref_img, img, roi=self.roi_on(r), params=self.params,
                            guess=_extrapolated(chain.prev, chain.before), refine=self.refine,
                            cancel=cancel, solver_cache=chain.solvers,
                            progress=self.within(i))
        except Cancelled:
            raise
        except Exception as exc:  # a bad frame: keep what is finished
            raise self.failed(k, exc) from exc
        inc.meta[IMAGE_DIGEST] = array_digest(img)  # checked when the run resumes
        chain.prev, chain.before = inc, chain.prev
        self.finish(i, inc)
        return inc


@dataclass
class Chain:
    """What serial correlation carries from frame to frame: the reference
    frame and image, the last two increments against it (the next frame's
    guess, :func:`_extrapolated`), and the AL-DIC solver cache (the global
    factor, reused while the mesh stays)."""

    ref_k: int = 0
    ref_img: object = None
    prev: DICResult | None = None
    before: DICResult | None = None
    solvers: dict = field(default_factory=dict)


def _extrapolated(prev: DICResult | None, before: DICResult | None) -> DICResult | None:
    """The initial guess of the next frame against the same reference: the
    last result moved on at the last frames' rate (``2 prev - before`` where
    both are valid on the same nodes), else ``prev``. A specimen that keeps
    moving (a test machine's crosshead) leaves the last frame's field a whole
    increment behind, beyond IC-GN's basin once the increment reaches a few
    speckles."""
    if prev is None or before is None or not (
            np.array_equal(prev.x, before.x) and np.array_equal(prev.y, before.y)):
        return prev
    both = prev.valid & before.valid
    if not both.any():
        return prev
    moved = {name: np.where(both, 2 * getattr(prev, name) - getattr(before, name),
                            getattr(prev, name))
             for name in ("u", "v", "dudx", "dudy", "dvdx", "dvdy")}
    return replace(prev, valid=both, **moved)
