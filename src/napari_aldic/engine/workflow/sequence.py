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

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.files import RunFolderError, array_digest, write_roi_file
from ..core.images import validate_roi
from ..core.params import DICParams
from ..core.progress import Cancelled, ProgressEvent, event_callback
from ..core.reasons import Reason
from ..core.results import DICResult, LazyFrames, SequenceResult, load_result
from ..dic.correlate import correlate, reference_result
from ..dic.roi_warp import carry_roi
from ..io.stack import frame_numbers, open_stack
from ..io.zarrstore import FieldStore
from .cluster import run_parallel
from .runfolder import MANIFEST, refine_record, roi_record, run_folder, run_id, stack_record

__all__ = ["track", "TrackError", "RunFolderError"]

_ON_DISK = object()  # a finished frame kept only in the run folder


def _sample_on_lattice(res: DICResult, name: str, x: np.ndarray, y: np.ndarray):
    """Bilinear interpolation of a node field at points (NaN where not possible)."""
    from scipy.interpolate import RegularGridInterpolator

    gridv = res.to_grid(name)
    interp = RegularGridInterpolator((res.grid_ys.astype(float), res.grid_xs.astype(float)),
                                     gridv, bounds_error=False, fill_value=np.nan)
    return interp(np.column_stack([y, x]))


def _compose(base: DICResult, inc: DICResult) -> DICResult:
    """``u_0k(X) = u_0r(X) + du(X + u_0r(X))``, at the nodes of ``base``.

    ``du`` is interpolated bilinearly on the lattice of ``inc``; where that is
    not possible (next to an untrusted node, or between the lattice's last
    nodes and the image edge, where material moves after frame 0) the nearest
    trusted node is extrapolated with its gradient: within 0.75 steps inside
    the lattice (not across holes), 1.5 steps outside it. Nodes left without
    an increment are flagged with the reason that holds: OUT_OF_IMAGE when
    their subset has left the image, else the nearest increment node's.
    """
    from scipy.spatial import cKDTree

    xd = base.x + base.u
    yd = base.y + base.v
    out = DICResult(**{**base.__dict__})
    names = ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc")
    vals = {n: _sample_on_lattice(inc, n, xd, yd) for n in names}
    miss = base.valid & ~np.all([np.isfinite(v) for v in vals.values()], axis=0)
    inside = ((xd >= inc.grid_xs[0]) & (xd <= inc.grid_xs[-1])
              & (yd >= inc.grid_ys[0]) & (yd <= inc.grid_ys[-1]))
    good = np.nonzero(inc.valid)[0]
    step = float(inc.params.step)
    if miss.any() and good.size:
        # past the lattice edge, but a subset there is inside the image:
        # one extrapolation of the small increment, not of the total motion
        reach = np.where(inside[miss], 0.75, 1.5) * step
        d, j = cKDTree(np.column_stack([inc.x[good], inc.y[good]])).query(
            np.column_stack([xd[miss], yd[miss]]), distance_upper_bound=1.5 * step)
        hit = d <= reach
        src = good[np.where(hit, j, 0)]
        dx = xd[miss] - inc.x[src]
        dy = yd[miss] - inc.y[src]
        fill = {n: getattr(inc, n)[src].astype(float) for n in names}
        fill["u"] = fill["u"] + inc.dudx[src] * dx + inc.dudy[src] * dy
        fill["v"] = fill["v"] + inc.dvdx[src] * dx + inc.dvdy[src] * dy
        idx = np.nonzero(miss)[0][hit]
        for n in names:
            vals[n][idx] = fill[n][hit]
    # F_0k = (I + H_rk(x)) (I + H_0r(X)) - I
    A = np.stack([[1 + vals["dudx"], vals["dudy"]], [vals["dvdx"], 1 + vals["dvdy"]]])
    B = np.stack([[1 + base.dudx, base.dudy], [base.dvdx, 1 + base.dvdy]])
    C = np.einsum("ijn,jkn->ikn", A, B)
    uk, vk = base.u + vals["u"], base.v + vals["v"]
    # as in accumulative tracking, a subset that left frame k is not measured
    gone = _subset_left(inc, base.x, base.y, uk, vk, C - np.eye(2)[:, :, None])
    ok = base.valid & np.all([np.isfinite(v) for v in vals.values()], axis=0) & ~gone
    out.u, out.v = np.where(ok, uk, np.nan), np.where(ok, vk, np.nan)
    out.dudx, out.dudy = C[0, 0] - 1, C[0, 1]
    out.dvdx, out.dvdy = C[1, 0], C[1, 1] - 1
    out.zncc = vals["zncc"]
    out.valid = ok
    out.reason = np.where(ok, Reason.OK, base.reason).astype(np.int8)
    dropped = np.nonzero(base.valid & ~ok)[0]
    if dropped.size:
        _, jn = cKDTree(np.column_stack([inc.x, inc.y])).query(
            np.column_stack([xd[dropped], yd[dropped]]))
        why = inc.reason[jn]
        # a trusted nearest node that could not be used (too far): its
        # material is not covered by the increment's lattice
        why = np.where(why == Reason.OK, Reason.NO_INITIAL_GUESS, why)
        # without an increment, judge by the subset's place in frame k-1
        left = gone[dropped] | _subset_left(inc, xd[dropped], yd[dropped], 0.0, 0.0,
                                             np.zeros((2, 2, 1)))
        out.reason[dropped] = np.where(left, Reason.OUT_OF_IMAGE, why)
    out.meta = {**inc.meta}
    return out


def _subset_left(inc: DICResult, x, y, u, v, grad) -> np.ndarray:
    """Whether a corner of the subset at ``(x, y)``, warped by ``u, v`` and
    the displacement gradient ``grad`` (2, 2, n), leaves ``inc``'s image
    (False where the warp is not known)."""
    rows, cols = inc.image_shape
    h = inc.params.half
    out = np.zeros(np.shape(x), bool)
    with np.errstate(invalid="ignore"):
        for dx in (-h, h):
            for dy in (-h, h):
                xc = x + dx + u + grad[0, 0] * dx + grad[0, 1] * dy
                yc = y + dy + v + grad[1, 0] * dx + grad[1, 1] * dy
                out |= (xc < 0) | (xc > cols - 1) | (yc < 0) | (yc > rows - 1)
    return out


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


def track(stack, roi=None, subset: int = 31, step: int = 8, method: str = "local",
          reference: str = "accumulative", *, update_every: int | None = None,
          rois=None, frames=None, out_dir=None, params: DICParams | None = None,
          scheduler=None, workers: int | None = None, refine=None, meta: dict | None = None,
          progress: Callable[[ProgressEvent], None] | None = None,
          on_frame: Callable[[int, DICResult], None] | None = None,
          cancel: Callable[[], bool] | None = None, **kwargs) -> SequenceResult:
    """Track a sequence of images; every result refers to frame 0.

    Parameters
    ----------
    stack : (T, H, W) array, dask array, TIFF stack path or image folder
    roi : (H, W) bool, optional
        ROI in frame 0 (holes and cracks False).
    reference : {"accumulative", "incremental"}
    update_every : int, optional
        With ``"accumulative"``: use frame N, 2N, ... as the new reference.
    rois : sequence of (H, W) bool or callable(k) -> mask, optional
        Per-frame ROI of the *reference* image used for frame k (e.g. a
        growing crack); the frame-0 ROI defaults to ``roi``.
    frames : sequence of int, optional
        Frames to analyse (must start with 0 and increase); default all.
    out_dir : path, optional
        A run folder: each frame is written as it finishes (``frame_#####.npz``
        and the field store ``fields.zarr``) and a rerun resumes. The folder is
        locked while written; a folder of another analysis, or whose inputs
        changed, is refused (:mod:`~napari_aldic.engine.workflow.runfolder`).
        Only frames later frames are composed with stay in memory.
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
        Called with a :class:`~napari_aldic.engine.ProgressEvent` when a frame
        starts, is loaded from ``out_dir`` or is done, and at the stages of
        each frame's ``correlate`` (serial runs); ``event.frame`` is the
        frame number in ``stack``, ``event.fraction`` the share of the run
        done, ``event.eta_s`` the time left. A 0.1 callback ``(frame,
        fraction, message)`` still works (deprecated; frame events only).
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
    if reference not in ("accumulative", "incremental"):
        raise ValueError(f"reference={reference!r} must be 'accumulative' or 'incremental'")
    if update_every is not None and (update_every < 1 or reference != "accumulative"):
        raise ValueError("update_every must be >= 1 and needs reference='accumulative'")
    src = open_stack(stack)
    if params is None:
        params = DICParams(subset=subset, step=step, method=method, **kwargs)
    idx = frame_numbers(frames, len(src))
    run = _SequenceRun(src, idx, reference, update_every, roi, rois, params, refine,
                       _with_file_units(src, meta), event_callback(progress, "track"), on_frame)
    if out_dir is None:
        return run.execute(stack, scheduler, workers, cancel)
    info = run.identity()
    with run_folder(out_dir, info) as out:
        run.out, run.run_id = out, run_id(info)
        return run.execute(stack, scheduler, workers, cancel)


def _with_file_units(src, meta: dict | None) -> dict:
    """``meta`` with the pixel size / frame interval the stack's file records
    (and where they came from) when it gives no ``"units"`` itself."""
    meta = dict(meta or {})
    if "units" not in meta and getattr(src, "units", None) is not None:
        meta.update(units=src.units.to_dict(), units_source=src.units_source)
    return meta


@dataclass
class _SequenceRun:
    """One ``track`` run: its frames, the results so far (index ``i`` of
    ``idx``), and how a frame's increment becomes its frame-0 result."""

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
        return self.partial(seconds=time.perf_counter() - t0, cancelled=cancelled)

    def start(self):
        """Frame 0's result (a zero field on its nodes), saved if missing;
        returns frame 0's image."""
        ref_img = self.src[0]
        self.results[0] = reference_result(ref_img, roi=self.roi_for(0), params=self.params,
                                           refine=self.refine)
        self.results[0].meta.update(self.extra)
        if self.out is not None:
            try:
                self.store = FieldStore(self.out, self.run_id, self.idx,
                                        self.results[0].grid_xs, self.results[0].grid_ys)
            except ValueError as exc:
                raise RunFolderError(str(exc), self.out) from None
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
            if not pth.exists():
                todo.append(i)
            elif not trusted[i]:
                self._verify(i, pth)
            if i and pth.exists():
                self.results[i] = _ON_DISK
                self.emit("frame_loaded", i, i / (len(self.idx) - 1), pth.name)
        todo = [i for i in todo if i]
        for i in todo:
            self._users[self._pos[self.ref_of(i)]] += 1
        for j in self._users:
            if self.results[j] is _ON_DISK:
                self.results[j] = self.load_frame(j)
        return todo

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
        self.store.write(i, res)
        self.store.mark_done(i, res, pth)

    def finish(self, i: int, inc: DICResult) -> None:
        """Compose the increment of ``idx[i]`` back to frame 0, record, save
        and announce it."""
        k, r = self.idx[i], self.ref_of(i)
        shared = self.roi_for(r)
        if inc.roi is not None and inc.roi is not shared and np.array_equal(inc.roi, shared):
            inc.roi = shared  # a copy from a worker process: keep one array per run
        res = inc if r == 0 else _compose(self.results[self.idx.index(r)], inc)
        res.meta.update(self.extra)
        res.meta["frame"] = k
        res.meta["reference_frame"] = r
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

    def serial(self, todo: list[int], ref_img, cancel) -> bool:
        """Correlate the frames of ``todo`` one after the other, each from the
        previous increment of its reference block; ``ref_img`` is frame 0.
        Returns True if cancelled."""
        ref_k, prev_inc, before = 0, None, None
        solvers: dict = {}  # AL-DIC global factor, reused while the mesh stays
        for i in todo:
            if cancel is not None and cancel():
                return True
            r, k = self.ref_of(i), self.idx[i]
            if i - 1 not in todo and i > 1:
                prev_inc = before = None  # previous frame came from disk: no increment
            self.emit("frame_start", i, (i - 1) / (len(self.idx) - 1))
            try:  # cancel also stops promptly inside a frame
                if r != ref_k:
                    ref_k, ref_img, prev_inc, before = r, self.src[r], None, None
                inc = correlate(ref_img, self.src[k], roi=self.roi_on(r), params=self.params,
                                guess=_extrapolated(prev_inc, before), refine=self.refine,
                                cancel=cancel, solver_cache=solvers,
                                progress=self.within(i))
            except Cancelled:
                return True
            except Exception as exc:  # a bad frame: keep what is finished
                raise self.failed(k, exc) from exc
            prev_inc, before = inc, prev_inc
            self.finish(i, inc)
        return False


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
