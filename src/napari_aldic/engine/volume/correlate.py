"""``correlate_volume``: the public DVC entry (Local IC-GN or AL-DVC)."""

from __future__ import annotations

import os
import time

import numba
import numpy as np

from ..core.params import DICParams
from ..core.progress import ProgressEvent, check_cancel, event_callback
from ..core.reasons import Reason
from ..core.version import __version__
from ..core.volresults import VolumeResult
from ..io.volumes import open_volume
from .grid import make_volume_grid
from .local import NodeState, solve_local_volume
from .validity import final_reasons

__all__ = ["correlate_volume"]


def _check_inputs(ref, dfm, roi):
    ref, dfm = np.asarray(ref), np.asarray(dfm)
    for name, a in (("reference", ref), ("deformed", dfm)):
        if a.ndim != 3:
            raise ValueError(f"the {name} volume must be 3-D (z, y, x); it has shape {a.shape}")
        if a.dtype.kind not in "biuf":
            raise ValueError(f"the {name} volume holds {a.dtype}, not grey levels")
    if ref.shape != dfm.shape:
        raise ValueError(f"the reference {ref.shape} and deformed {dfm.shape} volumes differ "
                         "in shape (z, y, x)")
    f = np.asarray(ref, np.float32)  # read only: no copy of float32 volumes
    g = np.asarray(dfm, np.float32)
    # a float64 sum of float32 values cannot overflow: it is finite iff every value is
    if ref.dtype.kind == "f" and not np.isfinite(f.sum(dtype=np.float64)) \
            or dfm.dtype.kind == "f" and not np.isfinite(g.sum(dtype=np.float64)):
        raise ValueError("a volume holds NaN or infinite grey levels")
    if roi is None:
        mask = np.ones(ref.shape, np.uint8)
    else:
        roi = np.asarray(roi)
        if roi.shape != ref.shape:
            raise ValueError(f"the ROI has shape {roi.shape} but the volumes {ref.shape}")
        mask = np.ascontiguousarray(roi.astype(bool).astype(np.uint8))
    return f, g, mask


def _result(st: NodeState, reason, params, shape, roi, meta, p=None) -> VolumeResult:
    g = st.grid
    p = st.p if p is None else p
    xyz = g.xyz.astype(np.float64)
    grads = {k: p[:, i].copy() for k, i in zip(
        ("dudx", "dudy", "dudz", "dvdx", "dvdy", "dvdz", "dwdx", "dwdy", "dwdz"),
        (1, 2, 3, 5, 6, 7, 9, 10, 11))}
    return VolumeResult(
        x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], u=p[:, 0].copy(), v=p[:, 4].copy(),
        w=p[:, 8].copy(), **grads, valid=reason == Reason.OK,
        zncc=st.zncc.copy(), reason=reason.astype(np.int8), iterations=st.iters.copy(),
        grid_ix=g.ix, grid_iy=g.iy, grid_iz=g.iz, grid_xs=g.xs, grid_ys=g.ys, grid_zs=g.zs,
        volume_shape=tuple(int(s) for s in shape), params=params, meta=meta,
        u_std=st.ustd[:, 0].copy(), v_std=st.ustd[:, 1].copy(), w_std=st.ustd[:, 2].copy(),
        roi=None if roi is None else np.asarray(roi, bool))


def _reporter(progress, cancel):
    """``report(stage, fraction, message)``: a :class:`ProgressEvent` to the
    caller and a cancellation point (``cancel``: a callable returning True
    to stop, or a ``threading.Event``)."""
    user = event_callback(progress, "correlate", stacklevel=4)
    poll = getattr(cancel, "is_set", cancel)
    if poll is not None and not callable(poll):
        raise TypeError(f"cancel must be a callable or a threading.Event, not "
                        f"{type(cancel).__name__}")

    def report(stage: str, frac: float, msg: str = "") -> None:
        check_cancel(poll)
        user(ProgressEvent(stage, float(frac), message=msg))

    return report


def _blocked(ref, dfm, roi, params, block, report, t0) -> VolumeResult:
    """``correlate_volume(..., block=N)``: Local DVC read block by block, then
    (``method="aldic"``) the ADMM on the merged nodes."""
    from .blocked import correlate_blocks

    ref, dfm = (open_volume(v) if isinstance(v, (str, os.PathLike)) else v for v in (ref, dfm))
    roi = open_volume(roi) if isinstance(roi, (str, os.PathLike)) else roi
    report("setup", 0.0, "reading the volumes block by block")
    threads = numba.get_num_threads()
    if params.n_threads:
        numba.set_num_threads(min(int(params.n_threads), numba.config.NUMBA_NUM_THREADS))
    try:
        st, reason, info = correlate_blocks(ref, dfm, roi, params, int(block), report)
        p, admm = None, None
        if params.method == "aldic":
            from .aldvc import solve_aldvc
            p, admm = solve_aldvc(st, 0.5, 0.95)
            reason = final_reasons(st, p)
    finally:
        numba.set_num_threads(threads)
    meta = {"timing": {"blocks": info["seconds"]}, "blocked": info}
    return _finish(st, reason, params, tuple(ref.shape), None, meta, p, admm, t0, report)


def _finish(st: NodeState, reason, params, shape, roi, meta: dict, p, admm, t0,
            report) -> VolumeResult:
    """The result of either entry (whole or blocked): ``meta`` completed with
    the versions, the ADMM's record (AL-DVC) and the counts."""
    meta.update(versions={"napari-aldic": __version__, "numpy": np.__version__,
                          "numba": numba.__version__}, n_nodes=st.grid.n, kind="volume")
    if admm is not None:
        meta.update(admm_history=admm["history"], regularisation=admm["regularisation"])
        meta["timing"].update(admm["timing"])
    meta["timing"]["total"] = time.perf_counter() - t0
    meta["n_valid"] = int(np.count_nonzero(reason == Reason.OK))
    res = _result(st, reason, params, shape, roi, meta, p)
    if p is not None:
        res.u_local, res.v_local, res.w_local = (st.p[:, i].copy() for i in (0, 4, 8))
    report("done", 1.0, f"{meta['n_valid']}/{st.grid.n} valid")
    return res


def correlate_volume(ref, dfm, roi=None, subset: int = 21, step: int = 8,
                     method: str = "local", *, params: DICParams | None = None,
                     progress=None, cancel=None, block: int | None = None,
                     **options) -> VolumeResult:
    """Displacement of a deformed volume against a reference (DVC).

    Parameters
    ----------
    ref, dfm : (nz, ny, nx) arrays
        Reference and deformed volumes (any numeric dtype).
    roi : (nz, ny, nx) bool or None
        Material to analyse: nodes lie on voxels inside it and every subset
        keeps only its voxels inside it.
    subset, step : int
        Full width of the cubic subset and node spacing, voxels.
    method : {"local", "aldic"}
        Local 3-D IC-GN, or AL-DVC (ADMM: local IC-GN and a global
        trilinear-hexahedral solve, as 2-D AL-DIC).
    params : DICParams, optional
        Every parameter at once (then ``subset``/``step``/``method`` and
        ``options`` are ignored); lengths in voxels.
    **options
        Other :class:`~..core.params.DICParams` fields (``max_iter``,
        ``tol``, ``zncc_min``, ``search``, ``mu``, ``beta``, ``n_threads``...).
    progress : callable(ProgressEvent), optional
        Called between the stages (``"setup"``, ``"prefilter"``,
        ``"initial_guess"``, ``"icgn"``, ``"repair"``, ``"aldic"``, ``"done"``,
        as ``correlate``) and after every batch of ~1000 nodes.
    cancel : callable() -> bool or threading.Event, optional
        Polled at every progress point; when it is set the call raises
        :class:`~napari_aldic.engine.Cancelled` (within one batch of nodes).
    block : int, optional
        Read and solve the volumes in blocks of about ``block`` voxels a side
        (:mod:`.blocked`; AL-DVC's ADMM then runs on the merged nodes, in
        memory proportional to them): ``ref``, ``dfm`` (and ``roi``) may then be
        zarr arrays, memory-mapped arrays or paths of zarr folders, tiled
        TIFFs or ``.npy`` files, never loaded whole. The result's ``roi`` is
        not kept.

    Returns
    -------
    VolumeResult
        ``x, y, z`` node voxels (x = axis 2, y = axis 1, z = axis 0), ``u, v,
        w`` Lagrangian displacement (voxels), ``valid`` and ``reason``.
    """
    t0 = time.perf_counter()
    report = _reporter(progress, cancel)
    if params is None:
        params = DICParams(subset=subset, step=step, method=method, **options)
    if block:
        return _blocked(ref, dfm, roi, params, block, report, t0)
    report("setup", 0.0, "checking the volumes")
    f, g, mask = _check_inputs(ref, dfm, roi)
    grid = make_volume_grid(f.shape, params.subset, params.step, roi)
    threads = numba.get_num_threads()
    if params.n_threads:
        numba.set_num_threads(min(int(params.n_threads), numba.config.NUMBA_NUM_THREADS))
    try:
        aldic = params.method == "aldic"
        st = solve_local_volume(f, g, mask, grid, params, report, 0.5 if aldic else 0.95)
        p, admm = None, None
        if aldic:
            from .aldvc import solve_aldvc  # the ADMM needs scipy.sparse only here
            p, admm = solve_aldvc(st, 0.5, 0.95)
        reason = final_reasons(st, p)
    finally:
        numba.set_num_threads(threads)
    return _finish(st, reason, params, f.shape, roi, {"timing": dict(st.timing)}, p, admm, t0,
                   report)
