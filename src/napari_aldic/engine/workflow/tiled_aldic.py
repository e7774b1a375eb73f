"""AL-DIC of a pair larger than memory: the ADMM local step block by block.

:func:`~.tiled.correlate_tiled` first runs Local DIC block by block. The
AL-DIC stage (:func:`~napari_aldic.engine.dic.aldic.aldic_stage`, the same
code as for images in memory) then works on the node arrays of the whole
lattice, which are small (1.56 million nodes for a 40,000 px image at step
32), and solves the global step on the whole mesh (algebraic-multigrid
preconditioned CG beyond the direct solver's size). Only its local step
touches the images: each ADMM iteration reads every block's window of the
two images again, prefilters it, and runs the translation-only IC-GN of the
block's own nodes. A node's local step depends on its subset alone, so the
window needs no halo nodes; it reaches far enough for the subset at the
node's current displacement (plus the B-spline prefilter margin), and the
result equals the one of the whole images to float precision.

Before the iterations one more pass over the reference gives the validity
tests their per-node subset statistics (the Gauss-Newton matrix and grey
variance of every subset), so that the regularisation choice and the
reasons of the result are the in-memory run's.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from ..core.images import as_gray_float
from ..core.params import DICParams
from ..core.progress import check_cancel
from ..core.reasons import Reason
from ..core.results import DICResult
from ..dic.aldic import aldic_stage
from ..dic.global_solve import uniform_mesh
from ..dic.icgn import icgn_solve_translation
from ..dic.interpolation import (
    PREFILTER_MARGIN,
    jacobian_smoothing,
    prefilter,
    reference_gradients,
    steepest_descent_gradients,
)
from ..dic.mesh import EDGE, NodeGrid
from ..dic.regularise import gradient_noise_gain
from ..dic.reliability import SubsetStats, Validity, image_noise, subset_statistics
from ..dic.subsets import split_subsets

__all__ = ["aldic_tiled"]

#: pixels an ADMM local step may move a node beyond its current displacement
#: and still read inside its block's window
SLACK = 8


class _Blocks:
    """The nodes of a tiled Local result grouped by the blocks of its plan,
    and the image window each block needs."""

    def __init__(self, local: DICResult, per_block: int, params: DICParams):
        self.shape = local.image_shape
        self.params = params
        self.grid = NodeGrid(local.x.astype(np.int64), local.y.astype(np.int64),
                             local.grid_ix, local.grid_iy, local.grid_xs, local.grid_ys)
        idx = self.grid.index_image()
        ny, nx = idx.shape
        self.ids = []
        for iy0 in range(0, ny, per_block):
            for ix0 in range(0, nx, per_block):
                ids = idx[iy0:iy0 + per_block, ix0:ix0 + per_block]
                ids = ids[ids >= 0]
                if ids.size:
                    self.ids.append(np.sort(ids))

    def __len__(self) -> int:
        return len(self.ids)

    def window(self, ids, reach: float):
        """``(r0, r1, c0, c1)``: the pixels within ``reach`` (plus the subset,
        the kernels' edge and the prefilter margin) of the nodes ``ids``."""
        m = self.params.half + EDGE + int(math.ceil(reach)) + PREFILTER_MARGIN
        x, y = self.grid.x[ids], self.grid.y[ids]
        r0, c0 = max(0, int(y.min()) - m), max(0, int(x.min()) - m)
        return r0, min(self.shape[0], int(y.max()) + m + 1), c0, min(self.shape[1],
                                                                    int(x.max()) + m + 1)

    def subsets(self, roi, ids, r0, r1, c0, c1):
        """The subsets of the nodes ``ids`` in the window (ROI-cut ones masked),
        and the nodes in window coordinates; None when none is usable."""
        band = (np.ones((r1 - r0, c1 - c0), bool) if roi is None
                else np.asarray(roi[r0:r1, c0:c1]) != 0)
        x, y = self.grid.x[ids] - c0, self.grid.y[ids] - r0
        g = NodeGrid(x, y, self.grid.ix[ids], self.grid.iy[ids], self.grid.xs, self.grid.ys)
        try:
            return split_subsets(band, g, self.params.subset, self.params.min_component), x, y
        except ValueError:  # every subset of the block is cut too much by the ROI
            return None, x, y


def _order(params: DICParams) -> int:
    """The B-spline order ``correlate_tiled`` fixed for the whole pair."""
    return {"cubic": 3, "quintic": 5}[params.interpolation]


def _map(fn, items, workers: int, cancel):
    """``fn`` over ``items``, ``workers`` threads at a time (the Numba threads
    shared among them), in order."""
    total = numba.get_num_threads()

    def one(item):
        check_cancel(cancel)
        numba.set_num_threads(max(1, total // workers))
        return fn(item)

    if workers == 1:
        return [one(item) for item in items]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(one, items))


def _statistics(ref, dfm, roi, blocks: _Blocks, workers: int, cancel):
    """The validity tests of the pair (subset statistics of every node from
    the reference's windows; image noise sampled as in memory) and the nodes
    whose subset the ROI cuts."""
    n = blocks.grid.n
    table = np.full((n, 5), np.nan)
    cut = np.zeros(n, bool)
    usable = np.zeros(n, bool)
    p = blocks.params
    order = _order(p)

    def one(ids):
        r0, r1, c0, c1 = blocks.window(ids, 0.0)
        sub, x, y = blocks.subsets(roi, ids, r0, r1, c0, c1)
        if sub is None:
            return ids, None, None, None
        f = as_gray_float(ref[r0:r1, c0:c1], "reference image")
        fgx, fgy = reference_gradients(prefilter(f, order))
        stats = subset_statistics(f, fgx, fgy, x, y, sub.slot, sub.masks, p.half)
        return ids, stats.table, sub.slot >= 0, sub.reason == Reason.OK

    for ids, tab, c, ok in _map(one, blocks.ids, workers, cancel):
        if tab is not None:
            table[ids], cut[ids], usable[ids] = tab, c, ok
    table[~usable] = np.nan  # as in memory: unusable subsets are never solved
    image_var = 0.5 * (image_noise(ref, roi) ** 2 + image_noise(dfm, roi) ** 2)
    return Validity(SubsetStats(table), image_var, gradient_noise_gain(order), p), cut


class _TiledLocalStep:
    """The ADMM local step (:data:`~napari_aldic.engine.dic.admm.LocalStep`)
    of a pair read block by block."""

    def __init__(self, ref, dfm, roi, blocks: _Blocks, workers: int, cancel, report):
        self.ref, self.dfm, self.roi, self.blocks = ref, dfm, roi, blocks
        self.workers, self.cancel, self.report = workers, cancel, report
        p = blocks.params
        self.order = _order(p)
        self.jacobian_sigma = p.extra.get("jacobian_sigma")
        self.passes = 0

    def __call__(self, start, F, target, mu, active, curvature, prior=None, settled=None):
        n = start.shape[0]
        uv = np.array(start, np.float64, copy=True)
        zn = np.full(n, np.nan)
        it = np.zeros(n, np.int32)
        rs = np.full(n, Reason.NOT_CONVERGED, np.int8)
        self.passes += 1
        self.report(self.passes, 0.0)
        done = itertools.count(1)  # next() is atomic: blocks finish in worker threads

        def one(ids):
            out = self._block(ids, start, F, target, mu, active, curvature, prior, settled)
            self.report(self.passes, next(done) / len(self.blocks))
            return ids, out

        for ids, out in _map(one, self.blocks.ids, self.workers, self.cancel):
            if out is not None:
                uv[ids], zn[ids], it[ids], rs[ids] = out
        return uv, zn, it, rs

    def _block(self, ids, start, F, target, mu, active, curvature, prior, settled):
        act = active[ids]
        if not act.any():
            return None
        p = self.blocks.params
        disp = np.concatenate([start[ids][act].ravel(), target[ids][act].ravel()])
        grad = np.abs(F[ids][act]).max(initial=0.0)
        reach = float(np.abs(disp[np.isfinite(disp)]).max(initial=0.0)) + grad * p.half + SLACK
        r0, r1, c0, c1 = self.blocks.window(ids, reach)
        sub, x, y = self.blocks.subsets(self.roi, ids, r0, r1, c0, c1)
        if sub is None:
            return None
        f = as_gray_float(self.ref[r0:r1, c0:c1], "reference image")
        g = as_gray_float(self.dfm[r0:r1, c0:c1], "deformed image")
        sigma = self.jacobian_sigma
        jgx, jgy = steepest_descent_gradients(
            f, self.order, jacobian_smoothing(f) if sigma is None else sigma)
        lin = reference_gradients(prefilter(f, self.order))
        curv = None if curvature is None else curvature[ids]
        return icgn_solve_translation(f, jgx, jgy, prefilter(g, self.order), x, y, start[ids],
                                      F[ids], target[ids], mu, act, sub.slot, sub.masks,
                                      p.half, p.max_iter, p.tol, curvature=curv, lin=lin,
                                      prior=None if prior is None else prior[ids],
                                      settled=None if settled is None else settled[ids])


def aldic_tiled(ref, dfm, roi, local: DICResult, params: DICParams, per_block: int, *,
                workers: int = 1, progress=None, cancel=None) -> DICResult:
    """AL-DIC from the tiled Local result ``local`` of the pair ``ref``, ``dfm``
    (lazy images), reading the images block by block (``per_block`` lattice
    nodes a side); ``progress(fraction, message)`` runs from 0 to 1."""
    t0 = time.perf_counter()
    report = progress or (lambda frac, msg: None)
    timing: dict[str, float] = {}
    blocks = _Blocks(local, per_block, params)
    report(0.0, "AL-DIC: subset statistics")
    validity, cut = _statistics(ref, dfm, roi, blocks, workers, cancel)
    timing["validity"] = time.perf_counter() - t0
    t = time.perf_counter()
    mesh = uniform_mesh(blocks.grid, roi)
    timing["mesh"] = time.perf_counter() - t
    n_iter = params.admm_max_iter

    def step_report(k, frac):
        report(0.05 + 0.95 * min(1.0, (k - 1 + frac) / n_iter),
               f"AL-DIC: ADMM iteration {k}, block {int(round(frac * len(blocks)))}/"
               f"{len(blocks)}")

    step = _TiledLocalStep(ref, dfm, roi, blocks, workers, cancel, step_report)
    grad = np.column_stack([local.dudx, local.dudy, local.dvdx, local.dvdy])
    out = aldic_stage(step, mesh, validity, local.u, local.v, grad, local.zncc, local.reason,
                      cut, params, timing, on_iteration=lambda k: check_cancel(cancel))
    iters = np.where(out.reason == Reason.OK, out.iters, local.iterations).astype(np.int32)
    meta = dict(local.meta)
    meta.update(admm_history=out.history, regularisation=out.regularisation,
                validity=out.validity, n_valid=int(np.count_nonzero(out.reason == Reason.OK)),
                u_std="Local model of u_local (block-wise AL-DIC does not propagate it "
                      "through the ADMM iterations; the smoothed u is usually less noisy)")
    timing["admm_passes"] = float(step.passes)
    timing["aldic_total"] = time.perf_counter() - t0
    meta["timing"] = {**local.meta.get("timing", {}), **timing}
    return dataclasses.replace(
        local,
        u=out.u, v=out.v, dudx=out.grad[:, 0], dudy=out.grad[:, 1], dvdx=out.grad[:, 2],
        dvdy=out.grad[:, 3], zncc=out.zncc, reason=out.reason,
        valid=out.reason == Reason.OK, iterations=iters, u_local=local.u, v_local=local.v,
        elements=mesh.elements, hanging=mesh.hanging, params=params, meta=meta)
