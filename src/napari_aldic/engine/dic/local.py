"""Local DIC of one image pair: initial guess, IC-GN at every node, repair.

Stages (see ``solve_local``):

1. initial guess -- from a previous result (``guess``), from seed points
   (wave propagation), or from FFT cross-correlation at coarse nodes whose
   solutions then start every other node;
2. IC-GN at every usable node;
3. repair -- nodes that failed, correlate poorly or fail the median test are
   restarted from trusted neighbours wave by wave, then from their own
   cross-correlation search, and finally flagged.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..core.params import DICParams
from ..core.reasons import Reason
from .icgn import icgn_solve
from .init_guess import ncc_search_widening
from .interpolation import SplineImage, choose_order, prefilter, reference_gradients
from .mesh import NodeGrid
from .outliers import lattice_neighbours, median_test
from .subsets import SubsetMasks

__all__ = ["Images", "prepare_images", "solve_local", "correlation_floor"]

ProgressFn = Callable[[float, str], None]


@dataclass
class Images:
    """The pair as the kernels need it: reference values and spline
    gradients, and the deformed image's B-spline coefficients."""

    f: np.ndarray
    g: np.ndarray
    fgx: np.ndarray
    fgy: np.ndarray
    g_spline: SplineImage


def prepare_images(f: np.ndarray, g: np.ndarray, interpolation: str) -> Images:
    """Prefilter once: reference gradients and deformed-image coefficients
    (``interpolation="auto"`` picks the order from the speckle size)."""
    order = choose_order(interpolation, f)
    fgx, fgy = reference_gradients(prefilter(f, order))
    return Images(f, g, fgx, fgy, prefilter(g, order))


def correlation_floor(zncc: np.ndarray, converged: np.ndarray, params: DICParams) -> float:
    """Lowest acceptable ZNCC: ``zncc_min``, raised by the relative test
    (``1 - ZNCC`` above ``zncc_rel`` times the median of converged nodes, and
    0.1) so spurious matches of material that left the view are flagged."""
    zmin = params.zncc_min
    if params.zncc_rel > 0 and converged.any():
        floor = max(params.zncc_rel * float(np.median(1.0 - zncc[converged])), 0.1)
        zmin = max(zmin, 1.0 - floor)
    return zmin


def _propagate_seeds(im: Images, roi, grid: NodeGrid, sub: SubsetMasks, params: DICParams,
                     run, store, p, zncc, iters, reason):
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
    p_init[seed_nodes] = _ncc_guess(im, grid, sub, seed_nodes,
                                    params.replace(search_max=max(rows, cols, params.search)),
                                    accept=0.9)
    active = np.zeros(n, bool)
    active[seed_nodes] = True
    store(run(active, p_init), seed_nodes)
    solved = active & (reason == Reason.OK) & (zncc >= params.zncc_min)
    if not solved.any():
        raise ValueError("no seed could be matched in the deformed image; move the seeds to "
                         "well-textured material")
    tries = _grow(grid, lattice_neighbours(grid, roi, radius=1), solved, usable, run,
                  p, zncc, iters, reason, params.zncc_min, max_tries=1)
    # unreachable from any seed through converged nodes
    reason[usable & ~active & (tries == 0)] = Reason.NO_INITIAL_GUESS


def _grow(grid: NodeGrid, nbrs: np.ndarray, good: np.ndarray, eligible: np.ndarray, run,
          p, zncc, iters, reason, zmin: float, max_tries: int, report=None) -> np.ndarray:
    """Grow the ``good`` set into the other ``eligible`` nodes, wave by wave.

    Each eligible node next to a good one restarts IC-GN from its best good
    neighbour (highest ZNCC), extrapolated to first order with that
    neighbour's gradient; converged nodes with ZNCC >= ``zmin`` join the good
    set. A failed attempt only replaces a node's state when it had none yet
    (so earlier results are never lost). Each node gets ``max_tries``
    attempts. Used by seed propagation and by the repair stage. Updates
    ``good`` and the state arrays in place; returns the attempts per node.
    """
    tries = np.zeros(grid.n, np.int8)
    has = nbrs >= 0
    active = np.zeros(grid.n, bool)
    while True:
        if report is not None:
            report(0.8, "growing trusted regions")
        nb_good = np.zeros(nbrs.shape, bool)
        nb_good[has] = good[nbrs[has]]
        cand = np.nonzero(eligible & ~good & (tries < max_tries) & nb_good.any(axis=1))[0]
        if cand.size == 0:
            return tries
        score = np.where(nb_good[cand], zncc[np.where(has[cand], nbrs[cand], 0)], -np.inf)
        src = nbrs[cand, np.argmax(score, axis=1)]
        p_try = p.copy()
        p_try[cand] = _extrapolate(p[src], grid.x[cand] - grid.x[src],
                                   grid.y[cand] - grid.y[src])
        active[:] = False
        active[cand] = True
        rp, rz, ri, rr = run(active, p_try)
        ok = (rr[cand] == Reason.OK) & (rz[cand] >= zmin)
        take = cand[ok | ~np.isfinite(zncc[cand])]
        p[take], zncc[take], iters[take], reason[take] = rp[take], rz[take], ri[take], rr[take]
        tries[cand] += 1
        if not ok.any():
            return tries
        good[cand[ok]] = True


def _extrapolate(p_from: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """First-order extrapolation of affine parameters by (dx, dy) pixels."""
    p0 = p_from.copy()
    p0[:, 0] += p_from[:, 1] * dx + p_from[:, 2] * dy
    p0[:, 3] += p_from[:, 4] * dx + p_from[:, 5] * dy
    return p0


def _ncc_guess(im: Images, grid: NodeGrid, sub: SubsetMasks, nodes: np.ndarray,
               params: DICParams, accept: float = 0.5) -> np.ndarray:
    """Affine parameters from an NCC search at ``nodes`` (gradients zero)."""
    h = params.half
    masks = None
    if np.any(sub.slot[nodes] >= 0):
        masks = np.ones((nodes.size, params.subset, params.subset), np.uint8)
        cut = sub.slot[nodes] >= 0
        masks[cut] = sub.masks[sub.slot[nodes][cut]]
    res = ncc_search_widening(im.f, im.g, grid.x[nodes], grid.y[nodes], h, params.search,
                              params.resolved_search_max(im.f.shape), masks, accept=accept)
    p0 = np.zeros((nodes.size, 6))
    p0[:, 0] = res.u
    p0[:, 3] = res.v
    return p0


def solve_local(im: Images, roi, grid: NodeGrid, sub: SubsetMasks, params: DICParams,
                timing: dict, report: ProgressFn, guess=None):
    """Local IC-GN at every node.

    1. Initial guess: a previous result (``guess``), seed propagation, or NCC
       at coarse nodes (every k-th lattice node) whose IC-GN solutions start
       every other node (nearest converged coarse node, extrapolated to first
       order with its gradient).
    2. Repair: nodes that failed, correlate poorly or fail the median test
       restart from trusted neighbours wave by wave (:func:`_grow`), then
       from their own NCC search (FFT mode), and grow again.
    3. What still fails is flagged (LOW_CORRELATION, OUTLIER, or its reason).
    """
    n = grid.n
    usable = sub.reason == Reason.OK
    p = np.zeros((n, 6))
    zncc = np.full(n, np.nan)
    iters = np.zeros(n, np.int32)
    reason = sub.reason.astype(np.int8).copy()

    def run(active: np.ndarray, p_init: np.ndarray):
        out = (p.copy(), zncc.copy(), iters.copy(), reason.copy())
        return icgn_solve(im.f, im.fgx, im.fgy, im.g_spline, grid.x, grid.y, p_init, active,
                          sub.slot, sub.masks, params.half, params.max_iter, params.tol,
                          out=out)

    def store(res, nodes: np.ndarray):
        rp, rz, ri, rr = res
        p[nodes], zncc[nodes], iters[nodes], reason[nodes] = (rp[nodes], rz[nodes], ri[nodes],
                                                              rr[nodes])

    t = time.perf_counter()
    if guess is not None and np.any(guess.valid):
        # a previous result (e.g. the last frame of a sequence) as the guess
        p_init = _guess_from_result(grid, guess)
        timing["init"] = time.perf_counter() - t
        store(run(usable.copy(), p_init), np.nonzero(usable)[0])
    elif params.init == "seeds":
        _propagate_seeds(im, roi, grid, sub, params, run, store, p, zncc, iters, reason)
        timing["init"] = 0.0
    else:
        t = _coarse_to_fine(im, grid, sub, params, usable, run, store, zncc, reason, p,
                            timing, report)
    timing["icgn"] = time.perf_counter() - t
    report(0.8, "IC-GN done")

    t = time.perf_counter()
    _repair(im, roi, grid, sub, params, usable, run, p, zncc, iters, reason, report)
    timing["rescue"] = time.perf_counter() - t
    return p, zncc, iters, reason


def _guess_from_result(grid: NodeGrid, guess) -> np.ndarray:
    """Initial affine parameters from a previous result: each node starts
    from the nearest valid node of ``guess``, extrapolated to first order."""
    gv = np.nonzero(guess.valid)[0]
    tree = cKDTree(np.column_stack([guess.x[gv], guess.y[gv]]))
    _, j = tree.query(np.column_stack([grid.x, grid.y]))
    src = gv[j]
    pg = np.column_stack([guess.u, guess.dudx, guess.dudy, guess.v, guess.dvdx, guess.dvdy])
    return _extrapolate(pg[src], grid.x - guess.x[src], grid.y - guess.y[src])


def _coarse_to_fine(im: Images, grid: NodeGrid, sub: SubsetMasks, params: DICParams,
                    usable, run, store, zncc, reason, p, timing: dict,
                    report: ProgressFn) -> float:
    """FFT initial guess: NCC and IC-GN at coarse nodes (every k-th lattice
    node), then IC-GN at every other usable node from its nearest converged
    coarse node, extrapolated to first order (or from its own NCC search if
    none converged). Records ``timing["init"]``; returns the
    ``time.perf_counter()`` at which IC-GN started."""
    t = time.perf_counter()
    n = grid.n
    k = max(1, params.resolved_init_spacing() // params.step)
    coarse = np.nonzero(usable & (grid.ix >= 0) & (grid.ix % k == 0)
                        & (grid.iy % k == 0))[0]
    if coarse.size == 0:
        coarse = np.nonzero(usable)[0]
    p_init = np.zeros((n, 6))
    p_init[coarse] = _ncc_guess(im, grid, sub, coarse, params)
    timing["init"] = time.perf_counter() - t
    report(0.3, f"initial guess at {coarse.size} coarse nodes")

    t = time.perf_counter()
    active = np.zeros(n, bool)
    active[coarse] = True
    store(run(active, p_init), coarse)
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
            p_init[rest] = _ncc_guess(im, grid, sub, rest, params)
        active[:] = False
        active[rest] = True
        store(run(active, p_init), rest)
    return t


def _repair(im: Images, roi, grid: NodeGrid, sub: SubsetMasks, params: DICParams, usable,
            run, p, zncc, iters, reason, report: ProgressFn) -> None:
    """Repair failed, poorly correlated or inconsistent nodes, then flag what
    still fails (its best attempt kept). Updates the state arrays in place."""
    nbrs5 = lattice_neighbours(grid, roi)  # outlier test neighbourhoods (5 x 5)
    nbrs1 = lattice_neighbours(grid, roi, radius=1)  # propagation neighbours (3 x 3)
    zmin = correlation_floor(zncc, usable & (reason == Reason.OK), params)

    def good_nodes() -> np.ndarray:
        ok = usable & (reason == Reason.OK) & (zncc >= zmin)
        return ok & ~median_test(p[:, 0], p[:, 3], ok, nbrs5)

    def repair_waves() -> None:
        """Grow trusted regions into failed, poor or inconsistent nodes."""
        _grow(grid, nbrs1, good_nodes(), usable, run, p, zncc, iters, reason, zmin,
              max_tries=2, report=report)

    repair_waves()
    bad = np.nonzero(usable & ~good_nodes() & (reason != Reason.OUT_OF_IMAGE))[0]
    if bad.size and params.init == "fft":  # seeds: motion may exceed any FFT range
        p_try = p.copy()
        p_try[bad] = _ncc_guess(im, grid, sub, bad, params)
        active = np.zeros(grid.n, bool)
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
