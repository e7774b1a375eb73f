"""``correlate``: DIC of one reference/deformed image pair."""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numba
import numpy as np

from ..core.compiling import compile_seconds
from ..core.files import array_digest
from ..core.images import as_gray_float, validate_pair, validate_roi
from ..core.params import DICParams
from ..core.progress import CancelFn, ProgressEvent, check_cancel, event_callback
from ..core.reasons import Reason
from ..core.results import DICResult
from .admm import image_local_step
from .aldic import aldic_stage
from .global_solve import Q4Mesh, uniform_mesh
from .icgn import convergence_record, warn_iteration_cap
from .images import Images, prepare_images
from .interpolation import choose_order
from .local import solve_local
from .mesh import NodeGrid, make_grid
from .quadtree import Refinement, build_quadtree, resolve_refinement
from .regularise import gradient_noise_gain
from .reliability import SubsetStats, Validity, image_noise
from .result_quality import maps_job, probe_job, result_quality, speckle_job
from .static import flag_static_features, prefetch_static, prefetch_static_deformed
from .subsets import SubsetMasks, split_subsets
from .uncertainty_aldic import ADMMLinearisation

__all__ = ["correlate", "reference_result"]

log = logging.getLogger("napari_aldic.engine")

ProgressFn = Callable[[ProgressEvent], None]


@contextmanager
def _numba_threads(n: int | None):
    if n is None:
        yield
        return
    old = numba.get_num_threads()
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        numba.set_num_threads(old)


def _versions() -> dict[str, str]:
    import scipy

    from ..core.version import __version__

    return {"napari-aldic": __version__, "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__}


def correlate(reference, deformed, roi=None, subset: int | None = None,
              step: int | None = None, method: str | None = None, *,
              params: DICParams | None = None,
              refine=None, guess: DICResult | None = None,
              progress: ProgressFn | None = None, cancel: CancelFn | None = None,
              solver_cache: dict | None = None, **kwargs) -> DICResult:
    """Measure the displacement field between two images by subset DIC.

    Parameters
    ----------
    reference, deformed : (H, W) array
        Grey images (integer or float; RGB is converted with a warning).
    roi : (H, W) bool array or None
        Region of interest, True where material is analysed; holes and
        cracks False. None analyses the whole image.
    subset, step : int, optional
        Odd full subset width (31 -> 31 x 31) and node spacing in pixels
        (defaults: :class:`~napari_aldic.engine.DICParams`', 31 and 8).
    method : {"local", "aldic"}, optional
        Local IC-GN (the default), or augmented Lagrangian DIC.
    params : DICParams, optional
        All parameters at once; ``subset``, ``step``, ``method`` and
        ``kwargs`` given explicitly override its fields, always.
    refine : None, "light", "medium", "strong", Refinement or dict
        Adaptive quadtree refinement of the mesh (see
        :mod:`napari_aldic.engine.dic.quadtree`); overrides ``params.refine``.
        Refined nodes are extra DIC points; with ``method="aldic"`` the
        global solve constrains hanging nodes.
    guess : DICResult, optional
        A previous result whose displacements (extrapolated from its nearest trusted
        node with its gradient) start every node instead of the cross-correlation or
        seed guess; nodes that then fail are rescued as usual (``track`` passes one).
    progress : callable(ProgressEvent), optional
        Called as the analysis advances (``str(event)`` is its text); a 0.1
        callback ``(fraction, message)`` still works (deprecated).
    cancel : callable() -> bool, optional
        Polled between stages (and between repair waves and ADMM
        iterations); returning True raises :class:`~napari_aldic.engine.Cancelled`.
    solver_cache : dict, optional
        AL-DIC: a dictionary kept between calls (``track`` passes one per
        sequence). The factorised global system is stored there and reused
        by later calls with the same mesh, trusted nodes and penalties.
    **kwargs
        Any other :class:`DICParams` field (``search``, ``tol``, ...).

    Returns
    -------
    DICResult
        Node coordinates, displacements (pixels, Lagrangian), gradients,
        ``valid``/``reason`` flags and ZNCC per node.

    Examples
    --------
    >>> from napari_aldic.engine import correlate, synthetic
    >>> ref, dfm = synthetic.speckle_pair((128, 128), synthetic.Translation(0.4, -0.2))
    >>> res = correlate(ref, dfm, subset=31, step=8)
    >>> round(float(res.u[res.valid].mean()), 2), round(float(res.v[res.valid].mean()), 2)
    (0.4, -0.2)
    """
    t_start, c_start = time.perf_counter(), compile_seconds()
    params = DICParams.combine(params, kwargs, subset=subset, step=step, method=method)
    _check_guess(guess)
    report, timing = _reporter(progress, cancel), {}  # timing: stage -> seconds
    f, g, mask, params = _validated(reference, deformed, roi, params)
    ref_spec = resolve_refinement(refine if refine is not None else params.refine)
    im, base, grid, qmesh = _prepare(f, g, mask, ref_spec, params, timing, report,
                                     _reference_cache(solver_cache, reference))
    meta = {"versions": _versions(),
            "interpolation": "cubic" if im.g_spline.order == 3 else "quintic"}
    with _background(im):
        with _numba_threads(params.n_threads):
            sol = _analyse(im, mask, grid, qmesh, params, timing, report, guess, solver_cache)
            if ref_spec is not None and ref_spec.error:
                grid, qmesh, sol = _refine_by_error(im, mask, base, grid, qmesh, sol, ref_spec,
                                                    params, timing, report, solver_cache, meta)
        quality = _quality(im, mask, grid, sol, params, timing, meta)
    sol.reason = _uncertain_as_exported(sol, quality, params)
    _record(meta, sol, ref_spec, grid, params, timing, (t_start, c_start), im.j_sigma)
    report("done", 1.0, "done")
    return _assemble(sol, grid, f.shape, params, meta, mask, quality)


@contextmanager
def _background(im: Images):
    """One thread for work on the reference alone, started ahead
    (``Images.prefetch``); what still runs at the end finishes on its own
    (``Images.memo`` did not wait for it)."""
    im.background = ThreadPoolExecutor(1, initializer=_yielding)
    try:
        yield
    finally:
        im.background.shutdown(wait=False, cancel_futures=True)
        im.background, im.pending = None, {}


def _yielding() -> None:
    """Lower this thread's priority (Linux; elsewhere nothing): the work it
    runs ahead should fill the cores the analysis leaves idle, not slow the
    analysis down (paired runs at 1024²: 0.73 -> 0.57 s with it, 0.70 s
    without)."""
    # only Linux keeps a nice value per thread (setpriority(2)); elsewhere a
    # thread id given as a process id could name another process
    if not sys.platform.startswith("linux"):
        return
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 15)
    except OSError:  # not allowed
        pass


def _check_guess(guess) -> None:
    if guess is not None and not isinstance(guess, DICResult):
        raise TypeError("guess must be a DICResult (e.g. the previous frame's result), not "
                        f"{type(guess).__name__}")


def _reporter(progress, cancel):
    """``report(stage, fraction, message)``: the caller's progress (a
    :class:`ProgressEvent`), and a cancellation point."""
    user_report = event_callback(progress, "correlate", stacklevel=4)

    def report(stage: str, frac: float, msg: str = "") -> None:
        check_cancel(cancel)  # every progress point is a cancellation point
        user_report(ProgressEvent(stage, frac, message=msg))

    return report


def _validated(reference, deformed, roi, params: DICParams):
    """The two images as float arrays, the ROI mask and the parameters fitted to them."""
    f, g = validate_pair(reference, deformed)
    return f, g, validate_roi(roi, f.shape), params.fitted_to(f.shape)


def _reference_cache(solver_cache: dict | None, reference) -> dict | None:
    """The part of ``solver_cache`` kept for this reference image (the same
    array object as in the last call; it must not change in place)."""
    if solver_cache is None:
        return None
    held = solver_cache.get("reference")
    if held is None or held[0] is not reference:
        held = solver_cache["reference"] = (reference, {})
    return held[1]


def _prepare(f, g, mask, ref_spec, params: DICParams, timing: dict, report, ref_cache=None):
    """Node grid (with the quadtree when refining) and the interpolating splines."""
    t = time.perf_counter()
    base = make_grid(mask, params.subset, params.step)
    grid, qmesh = _nodes(base, mask, ref_spec, params)
    timing["setup"] = time.perf_counter() - t
    report("setup", 0.05, f"{grid.n} nodes")
    t = time.perf_counter()
    im = prepare_images(f, g, params.interpolation, params.extra.get("jacobian_sigma"),
                        ref_cache)
    timing["prefilter"] = time.perf_counter() - t
    report("prefilter", 0.15, "interpolation ready")
    return im, base, grid, qmesh


def _refine_by_error(im, mask, base, grid, qmesh, sol, ref_spec, params, timing, report,
                     solver_cache, meta):
    """A-posteriori criterion: refine around poorly correlated nodes and solve again."""
    bad = _poorly_correlated(sol.zncc, sol.reason, sol.sub.reason == Reason.OK)
    meta["error_refined_nodes"] = int(bad.sum())
    if not bad.any():
        return grid, qmesh, sol
    t = time.perf_counter()
    only_error = replace(ref_spec, error=True, mask_boundary=False, roi_boundary=False,
                         brush=None, elements=(), points=(), levels=1)
    grid, qmesh = _nodes(base, mask, only_error, params,
                         cells=qmesh.cells if qmesh else None,
                         bad_xy=np.column_stack([grid.x[bad], grid.y[bad]]))
    timing["setup"] += time.perf_counter() - t
    sol = _analyse(im, mask, grid, qmesh, params, timing, report, None, solver_cache)
    return grid, qmesh, sol


def _record(meta: dict, sol, ref_spec, grid, params: DICParams, timing: dict,
            t_start: tuple[float, float], j_sigma: float) -> None:
    """What the result's ``meta`` tells about the run (refinement, ADMM, timing,
    IC-GN's convergence, with a warning when many nodes ended at the cap)."""
    if ref_spec is not None:
        meta["refine"] = _describe(ref_spec)
    for key, value in (("admm_history", sol.history), ("regularisation", sol.regularisation),
                       ("validity", sol.validity)):
        if value is not None:
            meta[key] = value
    timing["total"] = time.perf_counter() - t_start[0]
    # Numba's first-run compilation, reported apart from the analysis (core/compiling.py)
    timing["compile"] = compile_seconds() - t_start[1]
    timing["analysis"] = max(timing["total"] - timing["compile"], 0.0)
    meta["timing"] = timing
    meta["n_nodes"] = grid.n
    meta["n_valid"] = int(np.count_nonzero(sol.reason == Reason.OK))
    meta["convergence"] = convergence_record(sol.reason, sol.iters, sol.sub.reason == Reason.OK,
                                             params.max_iter)
    meta["convergence"]["jacobian_sigma_px"] = float(j_sigma)
    log.debug("correlate: %d nodes, %d trusted, %.3f s analysis, %.3f s compiling kernels",
              grid.n, meta["n_valid"], timing["analysis"], timing["compile"])
    warn_iteration_cap(meta["convergence"], stacklevel=4)


@dataclass
class _Solution:
    """Displacements of one pass (local, or AL-DIC global field)."""

    sub: SubsetMasks
    u: np.ndarray
    v: np.ndarray
    grad: np.ndarray  # (n, 4): du/dx, du/dy, dv/dx, dv/dy
    zncc: np.ndarray
    reason: np.ndarray
    iters: np.ndarray
    mesh: Q4Mesh | None
    u_local: np.ndarray | None = None
    v_local: np.ndarray | None = None
    history: list | None = None
    regularisation: dict | None = None
    std: np.ndarray | None = None  # (n, 2) standard uncertainty of the local u, v (px)
    validity: dict | None = None  # noise levels behind the validity tests
    admm: ADMMLinearisation | None = None  # AL-DIC: for the uncertainty of u, v


def reference_result(image, roi=None, params: DICParams | None = None,
                     refine=None) -> DICResult:
    """The zero field at the nodes ``correlate`` would use for ``image`` as
    reference (frame 0 of a sequence), without correlating anything: nodes
    whose mask component is too small keep that reason, the rest are valid."""
    params = params or DICParams()
    img = as_gray_float(image, "reference image")
    mask = validate_roi(roi, img.shape)
    base = make_grid(mask, params.subset, params.step)
    grid, qmesh = _nodes(base, mask, resolve_refinement(refine if refine is not None
                                                        else params.refine), params)
    sub = split_subsets(mask, grid, params.subset, params.min_component)
    n = grid.n
    mesh = qmesh.mesh if qmesh is not None else None
    sol = _Solution(sub, np.zeros(n), np.zeros(n), np.zeros((n, 4)),
                    np.where(sub.reason == Reason.OK, 1.0, np.nan), sub.reason.copy(),
                    np.zeros(n, np.int32), mesh)
    meta = {"versions": _versions(), "n_nodes": n, "frame": 0,
            "n_valid": int(np.count_nonzero(sub.reason == Reason.OK))}
    order = choose_order(params.interpolation, img)
    quality = result_quality(img, None, order, mask, grid.x, grid.y, params.subset,
                             zncc=None, u=None, v=None, grad=None,
                             shape_function=getattr(params, "shape_function", "affine"))
    return _assemble(sol, grid, img.shape, params, meta, mask, quality)


def _analyse(im: Images, roi, grid: NodeGrid, qmesh, params: DICParams, timing: dict,
             report: ProgressFn, guess, solver_cache: dict | None = None) -> _Solution:
    """Local DIC at the nodes, then AL-DIC on their mesh if asked."""
    sub = split_subsets(roi, grid, params.subset, params.min_component)
    prefetch_static(im, roi, grid, sub, params)
    probes_ahead = None
    if params.extra.get("quality", True):
        inputs = _quality_inputs(im, roi, grid, params)
        speckle = speckle_job(*inputs)
        im.prefetch(*speckle)
        if params.method == "aldic":
            def probes_ahead():
                _prefetch_probes(im, inputs, speckle[0], params.mu)
    prefetch_static_deformed(im)  # queued after the jobs needed more
    validity = _validity(im, roi, grid, sub, params, timing)
    p, zncc, iters, reason, evidence = solve_local(im, roi, grid, sub, params, timing, report,
                                                   validity, guess=guess)
    t = time.perf_counter()  # matches explained by features that do not move (issue 22)
    reason = flag_static_features(im, roi, grid, sub, p, zncc, reason, evidence, validity,
                                  params)
    timing["static"] = time.perf_counter() - t
    mesh = qmesh.mesh if qmesh is not None else None
    sol = _Solution(sub, p[:, 0].copy(), p[:, 3].copy(), p[:, [1, 2, 4, 5]].copy(), zncc,
                    reason, iters, mesh, std=validity.std(zncc),
                    validity=validity.summary(zncc, reason == Reason.OK))
    if params.method != "aldic":
        return sol
    report("aldic", 0.85, "AL-DIC iterations")
    if mesh is None:
        mesh = uniform_mesh(grid, roi)
    jgx, jgy = (im.fgx, im.fgy) if im.jgx is None else (im.jgx, im.jgy)  # method.md 5.1
    step = image_local_step(im.f, jgx, jgy, im.g_spline, grid.x, grid.y, sub.slot, sub.masks,
                            params.half, params.max_iter, params.tol, lin=(im.fgx, im.fgy))
    out = aldic_stage(step, mesh, validity, sol.u, sol.v, sol.grad, zncc, reason,
                      sub.slot >= 0, params, timing, solver_cache=solver_cache,
                      on_iteration=lambda k: report("aldic", 0.85 + 0.1 * k / params.admm_max_iter,
                                                    f"ADMM iteration {k}"),
                      on_factorise=probes_ahead)
    iters = np.where(out.reason == Reason.OK, out.iters, iters).astype(np.int32)
    return _Solution(sub, out.u, out.v, out.grad, out.zncc, out.reason, iters, mesh,
                     sol.u, sol.v, out.history, out.regularisation, sol.std, out.validity,
                     out.admm)


def _prefetch_probes(im: Images, inputs: tuple, speckle_key, mu: float) -> None:
    """Start the noise probes of AL-DIC's u_std propagation and what the
    propagation makes of them (``result_quality``'s, the reference's alone) on
    the background thread. AL-DIC calls this as its global system is
    factorised: SuperLU runs on one core, and ~0.15 CPU-s of probes (1024²,
    16 probes) fit beside it instead of slowing IC-GN and the smoothing choice."""
    _, grads, _, mask, x, y, subset, shape, jacobian = inputs
    probes = probe_job(grads, mask, x, y, subset, shape, jacobian,
                       ADMMLinearisation.seed, ADMMLinearisation.probes)
    im.prefetch(*probes)
    jobs = [im.pending.get(speckle_key), im.pending.get(probes[0])]
    if None not in jobs:
        im.prefetch(*maps_job((speckle_key, jobs[0]), (probes[0], jobs[1]), mu))


def _validity(im: Images, roi, grid: NodeGrid, sub: SubsetMasks, params: DICParams,
              timing: dict) -> Validity:
    """The validity tests of this pair: image noise, and the subset
    statistics that IC-GN fills in as it solves the nodes."""
    t = time.perf_counter()
    stats = SubsetStats.empty(grid.n)
    image_var = params.extra.get("image_var")  # a tiled run's, of the whole pair
    if image_var is None:
        f_noise = im.memo(("noise", array_digest(roi)), lambda: image_noise(im.f, roi))
        image_var = 0.5 * (f_noise ** 2 + image_noise(im.g, roi) ** 2)
    timing["validity"] = time.perf_counter() - t
    return Validity(stats, image_var, gradient_noise_gain(im.g_spline.order), params)


def _quality(im: Images, mask, grid: NodeGrid, sol: _Solution, params: DICParams,
             timing: dict, meta: dict) -> dict | None:
    """Speckle quality (SSSIG, MIG) and the standard uncertainty of the
    displacements (``dic.quality``; for AL-DIC: of the smoothed ``u``, ``v``,
    which ``meta["u_std"]`` names); None when ``params.extra["quality"]`` is
    False (the IC-GN model's ``u_std`` only)."""
    if not params.extra.get("quality", True):
        return None
    t = time.perf_counter()
    local = sol.u_local is not None
    aldic = sol.admm
    if local and aldic is None:
        # past the direct solver's size every probe solve is an iterative one
        # (16 probes x 2 components x each ADMM iteration): too slow to propagate
        meta["u_std"] = ("Local model of u_local (the AL-DIC propagation is skipped on "
                         "meshes solved iteratively; the smoothed u is usually less noisy)")
    elif aldic is not None:
        meta["u_std"] = "AL-DIC: propagated through the linearised ADMM run"
    f, grads, order, roi, x, y, subset, shape, jacobian = _quality_inputs(im, mask, grid, params)
    out = result_quality(f, grads, order, roi, x, y, subset, zncc=sol.zncc,
                         u=sol.u_local if local else sol.u, v=sol.v_local if local else sol.v,
                         grad=sol.grad, shape_function=shape, jacobian=jacobian,
                         aldic=aldic, memo=im.memo)
    timing["quality"] = time.perf_counter() - t
    return out


def _quality_inputs(im: Images, mask, grid: NodeGrid, params: DICParams) -> tuple:
    """``result_quality``'s first arguments for this pair (``speckle_job``'s too)."""
    return (im.f, (im.fgx, im.fgy), im.g_spline.order, mask, grid.x, grid.y, params.subset,
            getattr(params, "shape_function", "affine"),
            # the steepest-descent images IC-GN (and AL-DIC's local step)
            # matched with, when smoothed
            None if im.jgx is None else (im.jgx, im.jgy, im.j_sigma))


def _uncertain_as_exported(sol: _Solution, quality: dict | None, params: DICParams):
    """``sol.reason`` with valid nodes whose *exported* ``u_std``/``v_std`` is
    above ``max_uncertainty`` or not finite flagged UNCERTAIN (issue 22).

    The UNCERTAIN test of the validity stage judges the IC-GN noise model
    before the final uncertainty is known; the exported one (the quality
    stage's, for AL-DIC propagated through the ADMM run) can be larger or
    undefined, and a valid node must never carry an uncertainty the run
    promised not to accept."""
    limit = params.max_uncertainty
    if limit is None:
        return sol.reason
    if quality is not None and quality.get("u_std") is not None:
        s = np.maximum(quality["u_std"], quality["v_std"])
    elif sol.std is not None:
        s = np.max(sol.std, axis=1)
    else:
        return sol.reason
    with np.errstate(invalid="ignore"):
        bad = (sol.reason == Reason.OK) & ~(s <= limit)
    return np.where(bad, np.int8(Reason.UNCERTAIN), sol.reason).astype(sol.reason.dtype)


def _assemble(sol: _Solution, grid: NodeGrid, shape, params: DICParams, meta: dict,
              roi, quality: dict | None = None) -> DICResult:
    valid = sol.reason == Reason.OK
    if quality is None:
        quality = {"u_std": None if sol.std is None else sol.std[:, 0],
                   "v_std": None if sol.std is None else sol.std[:, 1]}
    return DICResult(
        x=grid.x.astype(np.float64), y=grid.y.astype(np.float64), u=sol.u, v=sol.v,
        dudx=sol.grad[:, 0], dudy=sol.grad[:, 1], dvdx=sol.grad[:, 2], dvdy=sol.grad[:, 3],
        valid=valid, zncc=sol.zncc, reason=sol.reason, iterations=sol.iters,
        grid_ix=grid.ix, grid_iy=grid.iy, grid_xs=grid.xs, grid_ys=grid.ys,
        image_shape=tuple(shape), params=params, meta=meta,
        u_local=sol.u_local, v_local=sol.v_local,
        **quality,
        elements=None if sol.mesh is None else sol.mesh.elements,
        hanging=None if sol.mesh is None else sol.mesh.hanging,
        roi=roi,
    )


def _describe(ref: Refinement) -> dict:
    d = {k: getattr(ref, k) for k in ("mask_boundary", "roi_boundary", "error", "levels",
                                      "min_size", "margin")}
    d["brush"] = ref.brush is not None
    d["elements"] = [int(e) for e in ref.elements]
    d["points"] = [list(map(float, pt)) for pt in ref.points]
    return d


def _nodes(base: NodeGrid, roi: np.ndarray, ref: Refinement | None, params: DICParams,
           cells=None, bad_xy=None):
    """DIC nodes: the base lattice, plus quadtree nodes when refining."""
    if ref is None:
        return base, None
    qm = build_quadtree(base, roi, ref, params.half, bad_nodes_xy=bad_xy, cells=cells)
    extra = np.column_stack([qm.mesh.x[base.n:], qm.mesh.y[base.n:]]).astype(np.int64)
    return base.with_extra(extra[:, 0], extra[:, 1]), qm


def _poorly_correlated(zncc, reason, usable) -> np.ndarray:
    """Nodes the a-posteriori criterion refines around: usable but failed,
    or matching clearly worse than the image's typical node."""
    conv = usable & (reason == Reason.OK)
    if not conv.any():
        return usable & (reason != Reason.OK)
    floor = max(3.0 * float(np.median(1.0 - zncc[conv])), 0.02)
    return usable & ((reason != Reason.OK) | ~(1.0 - zncc <= floor))
