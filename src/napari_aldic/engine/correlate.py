"""``correlate``: DIC of one reference/deformed image pair."""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import replace
from typing import Callable

import numba
import numpy as np
from scipy.spatial import cKDTree

from .admm import run_admm
from .global_solve import uniform_mesh
from .quadtree import Refinement, build_quadtree, resolve_refinement
from .icgn import icgn_solve
from .images import validate_pair, validate_roi
from .init_guess import ncc_search_widening
from .interpolation import prefilter, reference_gradients
from .mesh import NodeGrid, make_grid
from .outliers import lattice_neighbours, median_test
from .params import DICParams
from .reasons import Reason
from .results import DICResult
from .subsets import SubsetMasks, split_subsets

__all__ = ["correlate"]

ProgressFn = Callable[[float, str], None]


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

    from .. import __version__

    return {"napari-aldic": __version__, "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__}


def correlate(reference, deformed, roi=None, subset: int = 31, step: int = 8,
              method: str = "local", *, params: DICParams | None = None,
              refine=None, guess: DICResult | None = None,
              progress: ProgressFn | None = None, **kwargs) -> DICResult:
    """Measure the displacement field between two images by subset DIC.

    Parameters
    ----------
    reference, deformed : (H, W) array
        Grey images (integer or float; RGB is converted with a warning).
    roi : (H, W) bool array or None
        Region of interest, True where material is analysed; holes and
        cracks False. None analyses the whole image.
    subset : int
        Odd full subset width in pixels (31 -> 31 x 31).
    step : int
        Node spacing in pixels.
    method : {"local", "aldic"}
        Local IC-GN, or augmented Lagrangian DIC.
    params : DICParams, optional
        All parameters at once; ``subset``, ``step``, ``method`` and
        ``kwargs`` then override its fields only when given explicitly.
    refine : None, "light", "medium", "strong", Refinement or dict
        Adaptive quadtree refinement of the mesh (see
        :mod:`napari_aldic.engine.quadtree`); overrides ``params.refine``.
        Refined nodes are extra DIC points; with ``method="aldic"`` the
        global solve constrains hanging nodes.
    guess : DICResult, optional
        A previous result whose displacements (extrapolated from its nearest
        trusted node with its gradient) start every node, instead of the
        cross-correlation or seed guess; nodes that then fail are rescued as
        usual. ``track`` passes the previous frame.
    progress : callable(fraction, message), optional
        Called as the analysis advances.
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
    t_start = time.perf_counter()
    if params is None:
        params = DICParams(subset=subset, step=step, method=method, **kwargs)
    else:
        changes = dict(kwargs)
        defaults = DICParams()
        for name, val in (("subset", subset), ("step", step), ("method", method)):
            if val != getattr(defaults, name):
                changes[name] = val
        params = params.replace(**changes) if changes else params
    report = progress or (lambda frac, msg: None)
    timing: dict[str, float] = {}

    def lap(name: str, t0: float) -> float:
        t1 = time.perf_counter()
        timing[name] = timing.get(name, 0.0) + t1 - t0
        return t1

    t = time.perf_counter()
    f, g = validate_pair(reference, deformed)
    mask = validate_roi(roi, f.shape)
    base = make_grid(mask, params.subset, params.step)
    ref_spec = resolve_refinement(refine if refine is not None else params.refine)
    grid, qmesh = _nodes(base, mask, ref_spec, params)
    sub = split_subsets(mask, grid, params.subset, params.min_component)
    t = lap("setup", t)
    report(0.05, f"{grid.n} nodes")

    order = 3 if params.interpolation == "cubic" else 5
    f_spline = prefilter(f, order)
    fgx, fgy = reference_gradients(f_spline)
    del f_spline
    g_spline = prefilter(g, order)
    t = lap("prefilter", t)
    report(0.15, "interpolation ready")

    meta = {"versions": _versions()}
    with _numba_threads(params.n_threads):
        p, zncc, iters, reason = _solve_local(f, g, fgx, fgy, g_spline, mask, grid, sub,
                                              params, timing, report, guess=guess)
        state = None
        if params.method == "aldic" or (ref_spec is not None and ref_spec.error):
            mesh = qmesh.mesh if qmesh is not None else uniform_mesh(grid, mask)
            if params.method == "aldic":
                report(0.85, "AL-DIC iterations")
                state = _solve_aldic(f, fgx, fgy, g_spline, grid, sub, mesh, params, p,
                                     reason, timing)
            if ref_spec is not None and ref_spec.error:
                # a-posteriori criterion: refine around poorly correlated nodes, resolve
                zz = zncc if state is None else np.where(np.isfinite(state.zncc),
                                                         state.zncc, zncc)
                rr = reason if state is None else np.where(reason == Reason.OK,
                                                           state.reason, reason)
                bad = _poorly_correlated(zz, rr, sub.reason == Reason.OK, params)
                meta["error_refined_nodes"] = int(bad.sum())
                if bad.any():
                    t = time.perf_counter()
                    grid, qmesh = _nodes(base, mask, replace(ref_spec, error=True,
                                         mask_boundary=False, roi_boundary=False,
                                         brush=None, elements=(), points=(), levels=1),
                                         params, cells=qmesh.cells if qmesh else None,
                                         bad_xy=np.column_stack([grid.x[bad], grid.y[bad]]))
                    sub = split_subsets(mask, grid, params.subset, params.min_component)
                    lap("setup", t)
                    p, zncc, iters, reason = _solve_local(f, g, fgx, fgy, g_spline, mask,
                                                          grid, sub, params, timing, report)
                    if params.method == "aldic":
                        state = _solve_aldic(f, fgx, fgy, g_spline, grid, sub, qmesh.mesh,
                                             params, p, reason, timing)
            if qmesh is None:
                qmesh_mesh = mesh
            else:
                qmesh_mesh = qmesh.mesh
        else:
            qmesh_mesh = qmesh.mesh if qmesh is not None else None

    u, v = p[:, 0].copy(), p[:, 3].copy()
    grad = p[:, [1, 2, 4, 5]].copy()
    local = None
    if state is not None:
        local = (u, v)
        u, v = state.uh, state.vh
        grad = state.grad
        zncc = np.where(np.isfinite(state.zncc), state.zncc, zncc)
        reason = np.where(reason == Reason.OK, state.reason, reason).astype(np.int8)
        # the same correlation test as the local result
        conv = reason == Reason.OK
        if conv.any():
            zmin = params.zncc_min
            if params.zncc_rel > 0:
                zmin = max(zmin, 1.0 - max(params.zncc_rel
                                           * float(np.median(1.0 - zncc[conv])), 0.1))
            reason[conv & ~(zncc >= zmin)] = Reason.LOW_CORRELATION
        iters = np.where(reason == Reason.OK, state.iterations, iters).astype(np.int32)
        meta["admm_history"] = state.history
    valid = reason == Reason.OK
    timing["total"] = time.perf_counter() - t_start
    meta["timing"] = timing
    meta["n_nodes"] = grid.n
    meta["n_valid"] = int(valid.sum())
    if ref_spec is not None:
        meta["refine"] = _describe(ref_spec)
    report(1.0, "done")
    return DICResult(
        x=grid.x.astype(np.float64), y=grid.y.astype(np.float64), u=u, v=v,
        dudx=grad[:, 0], dudy=grad[:, 1], dvdx=grad[:, 2], dvdy=grad[:, 3],
        valid=valid, zncc=zncc, reason=reason, iterations=iters,
        grid_ix=grid.ix, grid_iy=grid.iy, grid_xs=grid.xs, grid_ys=grid.ys,
        image_shape=tuple(f.shape), params=params, meta=meta,
        u_local=None if local is None else local[0],
        v_local=None if local is None else local[1],
        elements=None if qmesh_mesh is None else qmesh_mesh.elements,
        hanging=None if qmesh_mesh is None else qmesh_mesh.hanging,
        roi=mask,
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


def _poorly_correlated(zncc, reason, usable, params: DICParams) -> np.ndarray:
    """Nodes the a-posteriori criterion refines around: usable but failed,
    or matching clearly worse than the image's typical node."""
    conv = usable & (reason == Reason.OK)
    if not conv.any():
        return usable & (reason != Reason.OK)
    floor = max(3.0 * float(np.median(1.0 - zncc[conv])), 0.02)
    return usable & ((reason != Reason.OK) | ~(1.0 - zncc <= floor))


def _solve_aldic(f, fgx, fgy, g_spline, grid: NodeGrid, sub: SubsetMasks, mesh,
                 params: DICParams, p: np.ndarray, reason: np.ndarray, timing: dict):
    """ADMM on a Q4 mesh of the nodes, from the local result."""
    trusted = reason == Reason.OK
    state, _ = run_admm(
        f, fgx, fgy, g_spline, grid.x, grid.y, sub.slot, sub.masks, params.half, mesh,
        p[:, 0], p[:, 3], p[:, [1, 2, 4, 5]], trusted, trusted,
        mu=params.mu, beta=params.beta, step=params.step, max_iter=params.admm_max_iter,
        tol=params.admm_tol, icgn_max_iter=params.max_iter, icgn_tol=params.tol)
    for k, val in state.timing.items():
        timing["admm_" + k] = timing.get("admm_" + k, 0.0) + val
    return state


def _propagate_seeds(f, g, roi, grid: NodeGrid, sub: SubsetMasks, params: DICParams,
                     run, accept, p, zncc, reason):
    """Seed-propagation initial guess.

    Each seed is solved by a cross-correlation search over the whole image
    and IC-GN at its nearest usable node; the solution then spreads, wave by
    wave, to mask-connected lattice neighbours, each starting from its best
    solved neighbour extrapolated to first order with that neighbour's
    gradient (``u + F dX``). Every connected ROI region needs a seed.
    """
    from scipy import ndimage

    rows, cols = roi.shape
    seeds = np.asarray(params.seeds, float).reshape(-1, 2)
    labels, _ = ndimage.label(roi)
    seed_region = []
    for sx, sy in seeds:
        ix, iy = int(round(sx)), int(round(sy))
        if not (0 <= ix < cols and 0 <= iy < rows) or not roi[iy, ix]:
            raise ValueError(f"seed ({sx:g}, {sy:g}) is outside the ROI; place seeds on "
                             "analysed material")
        seed_region.append(labels[iy, ix])
    usable = sub.reason == Reason.OK
    node_region = labels[grid.y, grid.x]
    for r in np.unique(node_region[usable]):
        if r not in seed_region:
            ys, xs = np.nonzero(labels == r)
            raise ValueError(
                f"ROI region {r} (x {xs.min()}-{xs.max()}, y {ys.min()}-{ys.max()}, "
                f"{xs.size} px) has no seed; add a seed point inside it")
    seed_nodes = []
    for (sx, sy), r in zip(seeds, seed_region):
        cand = np.nonzero(usable & (node_region == r))[0]
        if cand.size == 0:
            raise ValueError(f"seed ({sx:g}, {sy:g}): its ROI region has no usable node; "
                             "enlarge the region or reduce the subset")
        seed_nodes.append(cand[np.argmin(np.hypot(grid.x[cand] - sx, grid.y[cand] - sy))])
    seed_nodes = np.unique(np.asarray(seed_nodes))
    n = grid.n
    p_init = np.zeros((n, 6))
    # a seed may have moved anywhere: widen until the peak is convincing
    p_init[seed_nodes] = _ncc_guess(f, g, grid, sub, seed_nodes,
                                    params.replace(search_max=max(rows, cols, params.search)),
                                    accept=0.9)
    active = np.zeros(n, bool)
    active[seed_nodes] = True
    accept(run(active, p_init), seed_nodes, only_better=False)
    solved = active & (reason == Reason.OK) & (zncc >= params.zncc_min)
    if not solved.any():
        raise ValueError("no seed could be matched in the deformed image; move the seeds to "
                         "well-textured material")
    attempted = active.copy()
    nbrs = lattice_neighbours(grid, roi, radius=1)
    while True:
        has = nbrs >= 0
        nb_solved = np.zeros(nbrs.shape, bool)
        nb_solved[has] = solved[nbrs[has]]
        cand = np.nonzero(usable & ~attempted & nb_solved.any(axis=1))[0]
        if cand.size == 0:
            break
        score = np.where(nb_solved[cand], zncc[np.where(has[cand], nbrs[cand], 0)], -np.inf)
        src = nbrs[cand, np.argmax(score, axis=1)]
        p_init[cand] = _extrapolate(p[src], grid.x[cand] - grid.x[src],
                                    grid.y[cand] - grid.y[src])
        active[:] = False
        active[cand] = True
        accept(run(active, p_init), cand, only_better=False)
        attempted[cand] = True
        solved[cand] = (reason[cand] == Reason.OK) & (zncc[cand] >= params.zncc_min)
    never = usable & ~attempted  # unreachable from any seed through converged nodes
    reason[never] = Reason.NO_INITIAL_GUESS


def _extrapolate(p_from: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """First-order extrapolation of affine parameters by (dx, dy) pixels."""
    p0 = p_from.copy()
    p0[:, 0] += p_from[:, 1] * dx + p_from[:, 2] * dy
    p0[:, 3] += p_from[:, 4] * dx + p_from[:, 5] * dy
    return p0


def _ncc_guess(f, g, grid: NodeGrid, sub: SubsetMasks, nodes: np.ndarray,
               params: DICParams, accept: float = 0.5) -> np.ndarray:
    """Affine parameters from an NCC search at ``nodes`` (gradients zero)."""
    h = params.half
    masks = None
    if np.any(sub.slot[nodes] >= 0):
        masks = np.ones((nodes.size, params.subset, params.subset), np.uint8)
        cut = sub.slot[nodes] >= 0
        masks[cut] = sub.masks[sub.slot[nodes][cut]]
    res = ncc_search_widening(f, g, grid.x[nodes], grid.y[nodes], h, params.search,
                              params.resolved_search_max(f.shape), masks, accept=accept)
    p0 = np.zeros((nodes.size, 6))
    p0[:, 0] = res.u
    p0[:, 3] = res.v
    return p0


def _solve_local(f, g, fgx, fgy, g_spline, roi, grid: NodeGrid, sub: SubsetMasks,
                 params: DICParams, timing: dict, report: ProgressFn, guess=None):
    """Local IC-GN at every node with a coarse-to-fine initial guess.

    1. NCC at coarse nodes (every k-th lattice node), IC-GN there.
    2. Every other node starts from its nearest converged coarse node,
       extrapolated to first order with that node's gradient; IC-GN.
    3. Nodes that fail (no convergence, low ZNCC, divergence) are retried
       from their nearest converged neighbour, then from their own NCC search;
       a retry is kept only if it converges with a higher ZNCC.
    """
    n = grid.n
    h = params.half
    usable = sub.reason == Reason.OK
    p = np.zeros((n, 6))
    zncc = np.full(n, np.nan)
    iters = np.zeros(n, np.int32)
    reason = sub.reason.astype(np.int8).copy()

    def run(active: np.ndarray, p_init: np.ndarray):
        out = (p.copy(), zncc.copy(), iters.copy(), reason.copy())
        return icgn_solve(f, fgx, fgy, g_spline, grid.x, grid.y, p_init, active,
                          sub.slot, sub.masks, h, params.max_iter, params.tol, out=out)

    def accept(res, nodes: np.ndarray, only_better: bool):
        rp, rz, ri, rr = res
        take = nodes
        if only_better:
            new_ok = (rr[nodes] == Reason.OK) & (rz[nodes] >= params.zncc_min)
            old_ok = (reason[nodes] == Reason.OK) & (zncc[nodes] >= params.zncc_min)
            take = nodes[new_ok & (~old_ok | (rz[nodes] > zncc[nodes]))]
        p[take] = rp[take]
        zncc[take] = rz[take]
        iters[take] = ri[take]
        reason[take] = rr[take]

    p_init = np.zeros((n, 6))
    active = np.zeros(n, bool)
    if guess is not None and np.any(guess.valid):
        # a previous result (e.g. the last frame of a sequence) as the guess
        t = time.perf_counter()
        gv = np.nonzero(guess.valid)[0]
        tree = cKDTree(np.column_stack([guess.x[gv], guess.y[gv]]))
        _, j = tree.query(np.column_stack([grid.x, grid.y]))
        src = gv[j]
        pg = np.column_stack([guess.u, guess.dudx, guess.dudy, guess.v, guess.dvdx, guess.dvdy])
        p_init[:] = _extrapolate(pg[src], grid.x - guess.x[src], grid.y - guess.y[src])
        timing["init"] = time.perf_counter() - t
        active[:] = usable
        accept(run(active, p_init), np.nonzero(usable)[0], only_better=False)
    elif params.init == "seeds":
        t = time.perf_counter()
        _propagate_seeds(f, g, roi, grid, sub, params, run, accept, p, zncc, reason)
        timing["init"] = 0.0
    else:
        t = time.perf_counter()
        k = max(1, params.resolved_init_spacing() // params.step)
        coarse = np.nonzero(usable & (grid.ix >= 0) & (grid.ix % k == 0)
                            & (grid.iy % k == 0))[0]
        if coarse.size == 0:
            coarse = np.nonzero(usable)[0]
        p_init[coarse] = _ncc_guess(f, g, grid, sub, coarse, params)
        timing["init"] = time.perf_counter() - t
        report(0.3, f"initial guess at {coarse.size} coarse nodes")

        t = time.perf_counter()
        active[coarse] = True
        accept(run(active, p_init), coarse, only_better=False)
        good_c = coarse[(reason[coarse] == Reason.OK) & (zncc[coarse] >= params.zncc_min)]
        rest = np.nonzero(usable & ~active)[0]
        if rest.size:
            if good_c.size:
                tree = cKDTree(np.column_stack([grid.x[good_c], grid.y[good_c]]))
                _, j = tree.query(np.column_stack([grid.x[rest], grid.y[rest]]))
                src = good_c[j]
                p_init[rest] = _extrapolate(p[src], grid.x[rest] - grid.x[src],
                                            grid.y[rest] - grid.y[src])
            else:
                p_init[rest] = _ncc_guess(f, g, grid, sub, rest, params)
            active[:] = False
            active[rest] = True
            accept(run(active, p_init), rest, only_better=False)
    timing["icgn"] = time.perf_counter() - t
    report(0.8, "IC-GN done")

    # --- repair: failed, poorly correlated or inconsistent nodes
    t = time.perf_counter()
    nbrs5 = lattice_neighbours(grid, roi)  # outlier test neighbourhoods (5 x 5)
    nbrs1 = lattice_neighbours(grid, roi, radius=1)  # propagation neighbours (3 x 3)
    conv = usable & (reason == Reason.OK)
    zmin = params.zncc_min
    if params.zncc_rel > 0 and conv.any():
        floor = max(params.zncc_rel * float(np.median(1.0 - zncc[conv])), 0.1)
        zmin = max(zmin, 1.0 - floor)

    def good_nodes() -> np.ndarray:
        ok = usable & (reason == Reason.OK) & (zncc >= zmin)
        return ok & ~median_test(p[:, 0], p[:, 3], ok, nbrs5)

    def repair_waves() -> None:
        """Grow trusted regions into bad ones, as seed propagation does: each
        bad node next to a trusted one restarts from it (first-order
        extrapolation); converged nodes join the trusted set, wave by wave."""
        good = good_nodes()
        tries = np.zeros(n, np.int8)
        has = nbrs1 >= 0
        while True:
            nb_good = np.zeros(nbrs1.shape, bool)
            nb_good[has] = good[nbrs1[has]]
            cand = np.nonzero(usable & ~good & (tries < 2) & nb_good.any(axis=1))[0]
            if cand.size == 0:
                return
            score = np.where(nb_good[cand], zncc[np.where(has[cand], nbrs1[cand], 0)], -np.inf)
            src = nbrs1[cand, np.argmax(score, axis=1)]
            p_try = p.copy()
            p_try[cand] = _extrapolate(p[src], grid.x[cand] - grid.x[src],
                                       grid.y[cand] - grid.y[src])
            active[:] = False
            active[cand] = True
            rp, rz, ri, rr = run(active, p_try)
            ok = (rr[cand] == Reason.OK) & (rz[cand] >= zmin)
            take = cand[ok]
            p[take], zncc[take], iters[take], reason[take] = rp[take], rz[take], ri[take], rr[take]
            # a failed attempt keeps the node's earlier result (and reason)
            tries[cand] += 1
            tries[take] = 2
            if take.size == 0:
                return
            good[take] = True

    repair_waves()
    bad = np.nonzero(usable & ~good_nodes() & (reason != Reason.OUT_OF_IMAGE))[0]
    if bad.size and params.init == "fft":  # seeds: motion may exceed any FFT range
        p_try = p_init.copy()
        p_try[bad] = _ncc_guess(f, g, grid, sub, bad, params)
        active[:] = False
        active[bad] = True
        rp, rz, ri, rr = run(active, p_try)
        ok = (rr[bad] == Reason.OK) & (rz[bad] >= zmin)
        take = bad[ok & ~((reason[bad] == Reason.OK) & (zncc[bad] >= rz[bad]))]
        p[take], zncc[take], iters[take], reason[take] = rp[take], rz[take], ri[take], rr[take]
        repair_waves()
    # whatever still fails keeps its best attempt, flagged
    low = usable & (reason == Reason.OK) & ~(zncc >= zmin)
    reason[low] = Reason.LOW_CORRELATION
    trusted = reason == Reason.OK
    reason[median_test(p[:, 0], p[:, 3], trusted, nbrs5)] = Reason.OUTLIER
    timing["rescue"] = time.perf_counter() - t
    return p, zncc, iters, reason
