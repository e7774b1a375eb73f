"""Frames of ``track`` in parallel: local threads or a dask cluster.

The frame pairs do not depend on each other, so they run concurrently; the
client composes their increments back to frame 0 in frame order (``run``:
the ``SequenceRun`` of :mod:`.sequence`).

On a dask cluster nothing large travels with a task:

* a stack read from files (TIFF stack, image folder, list of files) is sent
  to every worker once as its :class:`~napari_aldic.engine.io.FrameSource`
  (a path, no pixels); each worker keeps it, and its open TIFF file, for all
  its tasks and reads its frames itself;
* the reference image of ``"accumulative"`` runs, the ROI and a painted
  refinement region are scattered to every worker once;
* a task carries only the frame numbers (frames of a stack held in memory
  are scattered one by one as their tasks are submitted: pass a path for
  long sequences);
* at most a few tasks per worker thread are in flight, and a finished
  task's result is released as soon as the client has composed and written
  it, so client memory does not grow with the number of frames.

Each task runs with one Numba thread (``params.n_threads`` when set), so a
worker with N threads runs N frames on N cores.
"""

from __future__ import annotations

import os
import re

from ..core.files import array_digest
from ..dic.correlate import correlate
from ..io.stack import FrameSource
from .runfolder import IMAGE_DIGEST


def _pair_job(source, ref, ref_k: int, k: int, roi, params, refine):
    """One frame pair, on a worker: ``source`` is a FrameSource (frames read
    here) or frame ``k`` itself; ``ref`` the reference image or None (frame
    ``ref_k`` of ``source``)."""
    if ref is None:
        ref = source[ref_k]
    img = source[k] if isinstance(source, FrameSource) else source
    inc = correlate(ref, img, roi=roi, params=params, refine=refine)
    inc.meta[IMAGE_DIGEST] = array_digest(img)  # hashed as read: checked when resuming
    return inc


class _Collector:
    """Keeps finished increments until their reference frame is final, then
    hands them to ``run.finish`` in frame order; raises the first failure."""

    def __init__(self, run):
        self.run = run
        self.incs: dict = {}

    def flush(self) -> None:
        run = self.run
        for i in sorted(self.incs):
            if run.results[run.idx.index(run.ref_of(i))] is None:
                break  # its reference frame is not final yet (composition order)
            run.finish(i, self.incs.pop(i))

    def collect(self, done: list, others) -> None:
        bad = None
        for fu, i in sorted(done, key=lambda fi: fi[1]):
            try:
                self.incs[i] = fu.result()
            except Exception as exc:
                bad = bad or (i, exc)
        self.flush()
        if bad is not None:
            for other in others:
                other.cancel()
            raise self.run.failed(self.run.idx[bad[0]], bad[1]) from bad[1]


def one_thread(params):
    """``params`` with one Numba thread per task unless ``n_threads`` is set."""
    return params if params.n_threads is not None else params.replace(n_threads=1)


def check_scheduler(scheduler, workers) -> None:
    """Refuse a ``scheduler`` or ``workers`` that :func:`run_parallel` cannot
    use, before anything is read or written."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers={workers!r} must be a whole number >= 1 (or None)")
    if scheduler is None or scheduler in ("threads", "processes"):
        return
    if isinstance(scheduler, str):
        if re.fullmatch(r"(tcp|tls|ucx|inproc|ws|wss)://\S+|[\w.\-]+:\d+", scheduler):
            return
    elif hasattr(scheduler, "submit") and hasattr(scheduler, "scatter"):
        return  # a dask.distributed Client
    raise ValueError(f"scheduler={scheduler!r} must be None, 'threads', 'processes', a "
                     "dask.distributed Client or the address of its scheduler (e.g. "
                     "'tcp://host:8786')")


def run_parallel(run, todo: list[int], scheduler, workers, cancel) -> bool:
    """Run the pairs of ``todo`` concurrently (``scheduler``: "threads",
    "processes", a dask Client or its address); returns True if cancelled."""
    if scheduler == "threads":
        return _run_threads(run, todo, workers, cancel)
    from distributed import Client, LocalCluster

    cluster = None
    if scheduler == "processes":
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(scheduler) if isinstance(scheduler, str) else scheduler
    try:
        return _run_dask(run, client, todo, cancel)
    finally:
        if client is not scheduler:
            client.close()
        if cluster is not None:
            cluster.close()


def _run_threads(run, todo, workers, cancel) -> bool:
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    n = workers or os.cpu_count() or 1
    one = run.params.replace(n_threads=1)  # frames are the parallel unit
    col = _Collector(run)
    with ThreadPoolExecutor(max_workers=n) as ex:
        # the run's own source: one open TIFF file shared by the threads
        futs = {ex.submit(_pair_job, run.src, None, run.ref_of(i), run.idx[i],
                          run.roi_for(run.ref_of(i)), one, run.refine): i for i in todo}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            col.collect([(fu, futs.pop(fu)) for fu in done], pending)
            if cancel is not None and cancel():
                for fu in pending:
                    fu.cancel()
                return True
    return False


class _Shipper:
    """What the tasks of one run need on the workers, sent once each."""

    def __init__(self, run, client):
        self.run, self.client = run, client
        self.files = not run.src.in_memory
        # hash=False: a new key per run, so no worker reuses a source (and its
        # open file) of an earlier run on a file rewritten since
        self.source = (client.scatter(run.src, broadcast=True, hash=False) if self.files
                       else None)
        self.refine = (client.scatter(run.refine, broadcast=True, hash=False)
                       if run.refine is not None else None)
        self._refs: dict = {}  # reference frame -> scattered image (accumulative)
        self._rois: dict = {}  # id(mask) -> (mask, scattered mask)

    def roi(self, mask):
        got = self._rois.get(id(mask))
        if got is None or got[0] is not mask:
            if len(self._rois) > 8:
                self._rois.clear()
            got = self._rois[id(mask)] = (mask, self.client.scatter(mask, broadcast=True,
                                                                     hash=False))
        return got[1]

    def ref(self, r: int):
        """The scattered reference image of frame ``r`` (None: the worker
        reads it from the source, e.g. the previous frame of an incremental
        run)."""
        if self.run.reference == "incremental":
            if self.files:
                return None
            return self.client.scatter(self.run.src[r], hash=False)
        if r not in self._refs:
            self._refs.clear()  # blocks follow each other: keep one reference
            self._refs[r] = self.client.scatter(self.run.src[r], broadcast=True, hash=False)
        return self._refs[r]

    def submit(self, i: int, params):
        run = self.run
        r, k = run.ref_of(i), run.idx[i]
        source = self.source if self.files else self.client.scatter(run.src[k], hash=False)
        return self.client.submit(_pair_job, source, self.ref(r), r, k,
                                  self.roi(run.roi_for(r)), params, self.refine, pure=False)


def _run_dask(run, client, todo: list[int], cancel) -> bool:
    from distributed import as_completed

    ship = _Shipper(run, client)
    params = one_thread(run.params)
    queue = iter(todo)
    futs: dict = {}
    ac = as_completed()
    col = _Collector(run)

    def top_up() -> None:
        """Two tasks per worker thread in flight (workers may join late, e.g.
        batch jobs that start after the run)."""
        window = max(2, 2 * sum(client.nthreads().values()))
        while len(futs) < window:
            i = next(queue, None)
            if i is None:
                return
            fu = ship.submit(i, params)
            futs[fu] = i
            ac.add(fu)

    top_up()
    for fu in ac:
        i = futs.pop(fu)
        col.collect([(fu, i)], list(futs))
        del fu  # the result is composed and written: release it on the cluster
        if cancel is not None and cancel():
            for other in futs:
                other.cancel()
            return True
        top_up()
    return False
