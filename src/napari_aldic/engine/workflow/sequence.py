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
every finished frame, and a rerun with the same ``out_dir`` and parameters
resumes where it stopped.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.files import atomic_write
from ..core.params import DICParams
from ..core.progress import Cancelled
from ..core.results import DICResult, SequenceResult, load_result
from ..dic.correlate import correlate, reference_result
from ..io.stack import open_stack

__all__ = ["track"]

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
    not possible inside the lattice (next to an untrusted node) the nearest
    trusted node within 0.75 steps is extrapolated with its gradient. Material
    that moved past the lattice edge is flagged (reason OUT_OF_IMAGE).
    """
    from scipy.spatial import cKDTree

    xd = base.x + base.u
    yd = base.y + base.v
    out = DICResult(**{**base.__dict__})
    names = ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc")
    vals = {n: _sample_on_lattice(inc, n, xd, yd) for n in names}
    miss = base.valid & ~np.all([np.isfinite(v) for v in vals.values()], axis=0)
    # only inside the lattice: extrapolating past its edge accumulates the
    # edge nodes' errors frame after frame
    miss &= ((xd >= inc.grid_xs[0]) & (xd <= inc.grid_xs[-1])
             & (yd >= inc.grid_ys[0]) & (yd <= inc.grid_ys[-1]))
    good = np.nonzero(inc.valid)[0]
    if miss.any() and good.size:
        step = float(inc.params.step)
        d, j = cKDTree(np.column_stack([inc.x[good], inc.y[good]])).query(
            np.column_stack([xd[miss], yd[miss]]), distance_upper_bound=0.75 * step)
        hit = np.isfinite(d)
        src = good[np.where(hit, j, 0)]
        dx = xd[miss] - inc.x[src]
        dy = yd[miss] - inc.y[src]
        fill = {n: getattr(inc, n)[src].astype(float) for n in names}
        fill["u"] = fill["u"] + inc.dudx[src] * dx + inc.dudy[src] * dy
        fill["v"] = fill["v"] + inc.dvdx[src] * dx + inc.dvdy[src] * dy
        idx = np.nonzero(miss)[0][hit]
        for n in names:
            vals[n][idx] = fill[n][hit]
    ok = base.valid & np.all([np.isfinite(v) for v in vals.values()], axis=0)
    out.u = np.where(ok, base.u + vals["u"], np.nan)
    out.v = np.where(ok, base.v + vals["v"], np.nan)
    # F_0k = (I + H_rk(x)) (I + H_0r(X)) - I
    A = np.stack([[1 + vals["dudx"], vals["dudy"]], [vals["dvdx"], 1 + vals["dvdy"]]])
    B = np.stack([[1 + base.dudx, base.dudy], [base.dvdx, 1 + base.dvdy]])
    C = np.einsum("ijn,jkn->ikn", A, B)
    out.dudx, out.dudy = C[0, 0] - 1, C[0, 1]
    out.dvdx, out.dvdy = C[1, 0], C[1, 1] - 1
    out.zncc = vals["zncc"]
    out.valid = ok
    # nodes whose material is not covered by a trusted increment are flagged
    out.reason = np.where(ok, 0, np.where(base.valid, 3, base.reason)).astype(np.int8)
    out.meta = {**inc.meta}
    return out


def _pair_job(stack, ref_k: int, k: int, roi, params: DICParams, refine=None) -> DICResult:
    """One frame pair (runs in a worker thread or process)."""
    src = open_stack(stack)
    return correlate(src[ref_k], src[k], roi=roi, params=params, refine=refine)


def _run_parallel(stack, src, todo, idx, ref_of, roi_for, params, scheduler, workers,
                  finish, results, cancel, report, refine=None) -> bool:
    """Run the pairs of ``todo`` concurrently; finish frames in order as their
    references become available. Returns True if cancelled."""
    spec = src.name if src.name is not None else stack
    incs: dict = {}

    def flush():
        for i in sorted(incs):
            r = ref_of(i)
            if results[idx.index(r)] is None:
                break  # its reference frame is not final yet (composition order)
            finish(i, incs.pop(i))

    if scheduler == "threads":
        from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

        n = workers or os.cpu_count() or 1
        one = params.replace(n_threads=1)  # frames are the parallel unit
        with ThreadPoolExecutor(max_workers=n) as ex:
            futs = {ex.submit(_pair_job, spec, ref_of(i), idx[i], roi_for(ref_of(i)), one,
                              refine): i for i in todo}
            pending = set(futs)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fu in done:
                    incs[futs[fu]] = fu.result()
                flush()
                if cancel is not None and cancel():
                    for fu in pending:
                        fu.cancel()
                    return True
        return False
    from distributed import Client, as_completed

    client = Client(scheduler) if isinstance(scheduler, str) else scheduler
    try:
        futs = {}
        for i in todo:
            fu = client.submit(_pair_job, spec, ref_of(i), idx[i], roi_for(ref_of(i)), params,
                               refine, pure=False)
            futs[fu] = i
        ac = as_completed(list(futs))
        for fu in ac:
            incs[futs[fu]] = fu.result()
            flush()
            if cancel is not None and cancel():
                for other in futs:
                    other.cancel()
                return True
        return False
    finally:
        if isinstance(scheduler, str):
            client.close()


def track(stack, roi=None, subset: int = 31, step: int = 8, method: str = "local",
          reference: str = "accumulative", *, update_every: int | None = None,
          rois=None, frames=None, out_dir=None, params: DICParams | None = None,
          scheduler=None, workers: int | None = None, refine=None,
          progress: Callable[[int, float, str], None] | None = None,
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
        Write each frame's result as it finishes; rerunning resumes.
    scheduler : None, "threads", a ``dask.distributed.Client`` or its address
        ``None`` runs frames one after the other, each starting from the
        previous frame's field. Otherwise the frame pairs, which do not
        depend on each other, run concurrently: on local threads (the Numba
        kernels release the GIL; each frame then uses one thread) or on a
        dask cluster; each frame then starts from its own FFT/seed guess.
    workers : int, optional
        Concurrent frames for ``scheduler="threads"`` (default: CPU count).
    refine : preset name, Refinement or dict, optional
        Quadtree refinement for every frame (as in ``correlate``), e.g. a
        ``Refinement(brush=mask)`` painted region.
    progress : callable(frame, fraction, message), optional
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
    """
    if reference not in ("accumulative", "incremental"):
        raise ValueError(f"reference={reference!r} must be 'accumulative' or 'incremental'")
    if update_every is not None and (update_every < 1 or reference != "accumulative"):
        raise ValueError("update_every must be >= 1 and needs reference='accumulative'")
    src = open_stack(stack)
    if params is None:
        params = DICParams(subset=subset, step=step, method=method, **kwargs)
    idx = list(range(len(src))) if frames is None else [int(k) for k in frames]
    if idx[0] != 0 or any(b <= a for a, b in zip(idx, idx[1:])) or idx[-1] >= len(src):
        raise ValueError(f"frames must start at 0, increase and stay below {len(src)}")
    out = _open_out_dir(out_dir, {"params": params.to_dict(), "reference": reference,
                                  "update_every": update_every, "frames": idx,
                                  "source": src.name})
    t0 = time.perf_counter()
    run = _SequenceRun(src, idx, reference, update_every, roi, rois, params, refine, out,
                       progress or (lambda k, frac, msg: None), on_frame)
    ref_img = run.start()
    todo = run.load_finished()
    if scheduler is None:
        cancelled = run.serial(todo, ref_img, cancel)
    else:
        cancelled = _run_parallel(stack, src, todo, idx, run.ref_of, run.roi_for, params,
                                  scheduler, workers, run.finish, run.results, cancel,
                                  run.report, refine)
    meta = {"seconds": time.perf_counter() - t0, "frames": idx, "cancelled": cancelled,
            "update_every": update_every, "source": src.name}
    return SequenceResult(run.results, params, reference, meta)


def _open_out_dir(out_dir, info: dict) -> Path | None:
    """Create ``out_dir`` and its manifest ``sequence.json`` (the analysis
    ``info``), or check that an existing manifest describes the same analysis
    (a rerun resumes). None without ``out_dir``."""
    if out_dir is None:
        return None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    manifest = out / "sequence.json"
    if manifest.exists():
        old = json.loads(manifest.read_text())
        if {k: old.get(k) for k in info} != info:
            raise ValueError(f"{out} holds results of a different analysis; choose an "
                             "empty folder or the same parameters to resume")
    else:
        with atomic_write(manifest) as tmp:
            tmp.write_text(json.dumps(info, indent=1))
    return out


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
    out: Path | None
    report: Callable[[int, float, str], None]
    on_frame: Callable[[int, DICResult], None] | None
    results: list = field(init=False)

    def __post_init__(self):
        self.results = [None] * len(self.idx)

    def roi_for(self, k: int):
        """ROI of the reference image ``k``."""
        if self.rois is None:
            return self.roi
        return self.rois(k) if callable(self.rois) else self.rois[k]

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

    def start(self):
        """Frame 0's result (a zero field on its nodes), saved if missing;
        returns frame 0's image."""
        ref_img = self.src[0]
        self.results[0] = reference_result(ref_img, roi=self.roi_for(0), params=self.params,
                                           refine=self.refine)
        if self.out is not None and not (self.out / "frame_00000.npz").exists():
            self.results[0].save(self.out / "frame_00000.npz")
        return ref_img

    def load_finished(self) -> list[int]:
        """Load the frames already in ``out``; returns the indices still to do."""
        todo = []
        for i in range(1, len(self.idx)):
            pth = self.path_of(self.idx[i])
            if pth is not None and pth.exists():
                self.results[i] = load_result(pth)
                self.report(self.idx[i], i / (len(self.idx) - 1),
                            f"frame {self.idx[i]}: loaded from {pth.name}")
            else:
                todo.append(i)
        return todo

    def finish(self, i: int, inc: DICResult) -> None:
        """Compose the increment of ``idx[i]`` back to frame 0, record, save
        and announce it."""
        k, r = self.idx[i], self.ref_of(i)
        res = inc if r == 0 else _compose(self.results[self.idx.index(r)], inc)
        res.meta["frame"] = k
        res.meta["reference_frame"] = r
        res.meta.setdefault("inputs", {"reference": self.src.frame_name(r),
                                       "deformed": self.src.frame_name(k), "frame": k})
        self.results[i] = res
        if self.path_of(k) is not None:
            res.save(self.path_of(k))
        if self.on_frame is not None:
            self.on_frame(k, res)
        self.report(k, i / (len(self.idx) - 1),
                    f"frame {k} done: {res.n_valid}/{len(res)} valid")

    def serial(self, todo: list[int], ref_img, cancel) -> bool:
        """Correlate the frames of ``todo`` one after the other, each from the
        previous increment of its reference block; ``ref_img`` is frame 0.
        Returns True if cancelled."""
        ref_k, prev_inc = 0, None
        solvers: dict = {}  # AL-DIC global factor, reused while the mesh stays
        for i in todo:
            if cancel is not None and cancel():
                return True
            r = self.ref_of(i)
            if r != ref_k:
                ref_k, ref_img, prev_inc = r, self.src[r], None
            if i - 1 not in todo and i > 1:
                prev_inc = None  # previous frame came from disk: no increment at hand
            self.report(self.idx[i], (i - 1) / (len(self.idx) - 1),
                        f"frame {self.idx[i]} against frame {r}")
            try:  # cancel also stops promptly inside a frame
                inc = correlate(ref_img, self.src[self.idx[i]], roi=self.roi_for(r),
                                params=self.params, guess=prev_inc, refine=self.refine,
                                cancel=cancel, solver_cache=solvers)
            except Cancelled:
                return True
            prev_inc = inc
            self.finish(i, inc)
        return False
