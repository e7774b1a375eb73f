"""Local DIC of one image pair: initial guess, IC-GN at every node, repair.

Stages (see ``solve_local``):

1. initial guess -- from a previous result (``guess``), from seed points
   (wave propagation), or from FFT cross-correlation at coarse nodes (each
   searched around the motion predicted from a few widely searched anchors,
   so large motion needs no wider search) whose solutions then start every
   other node; where the plain search fails at
   many nodes (large rotations), rotated subsets are searched for at a few;
2. IC-GN at every usable node;
3. repair -- nodes that failed, match poorly or fail the median test are
   restarted from trusted neighbours wave by wave, then from a rotated
   search at a few of them, then from their own cross-correlation search,
   and finally flagged by the validity tests (:mod:`.reliability`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from ..core.params import DICParams
from ..core.reasons import DICError, Reason
from .icgn import icgn_solve
from .images import Images
from .init_guess import ncc_search_widening
from .mesh import NodeGrid
from .outliers import MedianTest, lattice_neighbours
from .reliability import Validity
from .rotation import rotated_search, spread_nodes
from .static import STATIC_FRACTION, STATIC_MIN_MOTION
from .subsets import SubsetMasks

__all__ = ["solve_local"]

ProgressFn = Callable[[str, float, str], None]  # report(stage, fraction, message)

#: most nodes searched with rotated subsets (once per analysis, when no
#: coarse node, or no node at all after the repair waves, matches)
ROTATION_NODES = 8
#: fewest anchor nodes worth searching before the coarse nodes (fewer: the
#: coarse nodes are searched around zero motion, as without anchors)
ANCHOR_MIN = 4
#: first search half-range (px) of a coarse node centred on the motion its
#: anchor predicts (at most ``search``): the prediction is first-order from
#: a matched anchor, so the match is near it; a peak on the range's border or
#: below the acceptance widens the search as for any node (8 -> 16 -> ...).
#: An FFT of 48² instead of 72² per node at search=20 and subset 31.
PREDICTED_SEARCH = 8
#: IC-GN attempts remembered per node (start and outcome), replayed when a
#: node is started from one of them again (:meth:`_State.run`): the repair
#: waves retry from a neighbour, then the node's own search, then the
#: neighbour again
REPLAYED = 2


class _State:
    """Per-node state of a local analysis and the IC-GN runs that update it:
    affine parameters ``p``, ``zncc``, ``iters``, ``reason``, and the
    zero-motion evidence ``static`` (n, 2) that affine IC-GN computes at its
    converged nodes (:mod:`.static`); ``beyond`` marks nodes whose own search
    reached ``search_max`` without a convincing peak."""

    def __init__(self, im: Images, roi, grid: NodeGrid, sub: SubsetMasks,
                 params: DICParams, validity: Validity):
        self.im, self.roi, self.grid, self.sub = im, roi, grid, sub
        self.params, self.validity = params, validity
        n = grid.n
        self.usable = sub.reason == Reason.OK
        self.p = np.zeros((n, 6))
        self.zncc = np.full(n, np.nan)
        self.iters = np.zeros(n, np.int32)
        self.reason = sub.reason.astype(np.int8).copy()
        self.static = np.full((n, 2), np.nan)
        self.beyond = np.zeros(n, bool)
        self.searched = np.zeros(n, bool)  # own NCC search done
        self.rotation_tried = False
        self.version = 0  # bumped by every store (the repair stage's memo)
        self._nbrs5 = None
        self._median = MedianTest()
        self._stats_scratch = np.empty((n, 5))
        # each node's last REPLAYED IC-GN starts and their outcomes
        # (p, zncc, iters, reason, static), the latest first
        r = REPLAYED
        self._last = (np.full((r, n, 6), np.nan), np.empty((r, n, 6)), np.empty((r, n)),
                      np.empty((r, n), np.int32), np.empty((r, n), np.int8),
                      np.empty((r, n, 2)))
        # diagnostics (in ``meta["timing"]``): matched anchors; nodes the
        # repair stage had to retry, and those it searched on their own
        self.counts = {"anchors": 0, "rescue_nodes": 0, "rescue_searches": 0}

    @property
    def nbrs5(self) -> np.ndarray:
        """Outlier-test neighbourhoods (5 x 5 lattice nodes seen in the ROI)."""
        if self._nbrs5 is None:
            self._nbrs5 = lattice_neighbours(self.grid, self.roi)
        return self._nbrs5

    def run(self, active: np.ndarray, p_init: np.ndarray):
        """IC-GN at ``active`` from ``p_init``; copies of the state arrays
        ``(p, zncc, iters, reason, static)`` with those nodes updated.

        A node started from exactly the warp of one of its last
        :data:`REPLAYED` attempts gets that attempt's outcome again without
        solving: IC-GN is deterministic, and the repair waves restart a failed
        node from the same neighbour's warp until a neighbour changes (on the
        open-hole pair, nodes off the coupon: 60 % of all IC-GN steps)."""
        out = (self.p.copy(), self.zncc.copy(), self.iters.copy(), self.reason.copy())
        static = self.static.copy()
        nodes = np.nonzero(active)[0]
        starts, kept = self._last[0], self._last[1:]
        same = np.all(starts[:, nodes] == p_init[nodes], axis=2)  # (REPLAYED, m)
        again = same.any(axis=0)
        if again.any():
            active = active.copy()
            active[nodes[again]] = False
            slot, again = np.argmax(same[:, again], axis=0), nodes[again]
            for a, b in zip((*out, static), kept):
                a[again] = b[slot, again]
        self._solve(active, p_init, out, static)
        fresh = np.nonzero(active)[0]
        if len(starts):  # REPLAYED = 0: every attempt solved
            for b in self._last:  # the oldest attempt makes way
                b[1:, fresh] = b[:-1, fresh]
            starts[0, fresh] = p_init[fresh]
            for a, b in zip((*out, static), kept):
                b[0, fresh] = a[fresh]
        return (*out, static)

    def _solve(self, active: np.ndarray, p_init: np.ndarray, out: tuple, static: np.ndarray):
        """IC-GN at ``active`` from ``p_init`` into ``out`` and ``static``."""
        if not active.any():
            return
        im, g, prm = self.im, self.grid, self.params
        jgx, jgy = (im.fgx, im.fgy) if im.jgx is None else (im.jgx, im.jgy)
        icgn_solve(im.f, jgx, jgy, im.g_spline, g.x, g.y, p_init, active,
                         self.sub.slot, self.sub.masks, prm.half, prm.max_iter, prm.tol,
                         out=out, stats=self._stats_scratch, shape=prm.shape_function,
                         lin=(im.fgx, im.fgy),
                         static=(im.g, self.validity.image_var, STATIC_MIN_MOTION, static,
                                 STATIC_FRACTION))
        self._fill_stats(active)

    def _fill_stats(self, active: np.ndarray) -> None:
        """The validity tests' subset statistics of the ``active`` nodes, once
        per node: the kernels sum them from the unsmoothed gradients (the
        noise model's) while they gather each subset."""
        table = self.validity.stats.table
        todo = np.nonzero(active & np.isnan(table[:, 0]))[0]
        table[todo] = self._stats_scratch[todo]

    def outliers(self, trusted: np.ndarray) -> np.ndarray:
        """:func:`median_test` flags of the current ``u``, ``v`` at ``trusted``
        nodes (the repair stage and the final flags ask up to three times per
        run, 15 ms each at 15k nodes: :class:`MedianTest` tests again only
        where the inputs changed)."""
        return self._median.flags(self.p[:, 0], self.p[:, 3], trusted, self.nbrs5)

    def store(self, res, nodes: np.ndarray) -> None:
        rp, rz, ri, rr, rs = res
        self.p[nodes], self.zncc[nodes] = rp[nodes], rz[nodes]
        self.iters[nodes], self.reason[nodes] = ri[nodes], rr[nodes]
        self.static[nodes] = rs[nodes]
        self.version += 1

    def floor(self) -> np.ndarray:
        """Lowest acceptable ZNCC per node, from the current state."""
        return self.validity.zncc_floor(self.zncc, self.usable & (self.reason == Reason.OK))

    def acceptable(self, zmin: np.ndarray) -> np.ndarray:
        return self.usable & (self.reason == Reason.OK) & (self.zncc >= zmin)

    def ncc_guess(self, nodes: np.ndarray, params: DICParams | None = None,
                  accept: float = 0.5, centre: np.ndarray | None = None) -> np.ndarray:
        """Affine parameters from an NCC search at ``nodes`` (gradients
        zero), around ``centre`` ((m, 2) predicted u, v; default 0); marks
        ``beyond`` where the search ended at ``search_max`` on the border of
        the range or without a peak >= ``accept``."""
        prm = params or self.params
        im, grid, sub = self.im, self.grid, self.sub
        masks = None
        if np.any(sub.slot[nodes] >= 0):
            masks = np.ones((nodes.size, prm.subset, prm.subset), np.uint8)
            cut = sub.slot[nodes] >= 0
            masks[cut] = sub.masks[sub.slot[nodes][cut]]
        top = prm.resolved_search_max(im.f.shape)
        cu = cv = None
        if centre is not None:
            cu, cv = np.rint(centre).astype(np.int64).T
        first = min(prm.search, top)
        if centre is not None:
            first = min(first, PREDICTED_SEARCH)
        res = ncc_search_widening(im.f, im.g, grid.x[nodes], grid.y[nodes], prm.half,
                                  first, top, masks, accept=accept, cu=cu, cv=cv)
        self.beyond[nodes] = (res.search >= top) & (res.on_border | ~(res.peak >= accept))
        if params is None:
            self.searched[nodes] = True
        p0 = np.zeros((nodes.size, 6))
        p0[:, 0] = res.u
        p0[:, 3] = res.v
        return p0


def solve_local(im: Images, roi, grid: NodeGrid, sub: SubsetMasks, params: DICParams,
                timing: dict, report: ProgressFn, validity: Validity, guess=None):
    """Local IC-GN at every node.

    1. Initial guess: a previous result (``guess``), seed propagation, or NCC
       at coarse nodes (every k-th lattice node) whose IC-GN solutions start
       every other node (nearest converged coarse node, extrapolated to first
       order with its gradient).
    2. Repair: nodes that failed, match poorly or fail the median test
       restart from trusted neighbours wave by wave (:func:`_grow`), then
       from rotated searches at a few of them and from their own NCC search
       (FFT mode), and grow again.
    3. What still fails is flagged by the validity tests (:func:`_flag`).

    Returns ``(p, zncc, iters, reason, static)`` (``static``: the
    zero-motion evidence of :mod:`.static` at the converged affine nodes).
    """
    st = _State(im, roi, grid, sub, params, validity)
    t = time.perf_counter()
    if guess is not None and np.any(guess.valid) and params.extra.get("guess_of_this_pair"):
        # a coarse result of this very pair (tiled runs): within IC-GN's basin
        p_init = _guess_from_result(grid, guess)
        timing["init"] = time.perf_counter() - t
        st.store(st.run(st.usable.copy(), p_init), np.nonzero(st.usable)[0])
    elif guess is not None and np.any(guess.valid):
        # a previous frame's result predicts the motion: the coarse nodes
        # search around it, as around the anchors' prediction, because the
        # motion may have moved on by more than IC-GN's basin (a few speckles)
        t = _coarse_to_fine(st, timing, report, prediction=_guess_from_result(grid, guess))
    elif params.init == "seeds":
        _propagate_seeds(st)
        timing["init"] = 0.0
    else:
        t = _coarse_to_fine(st, timing, report)
    timing["icgn"] = time.perf_counter() - t
    report("icgn", 0.8, "IC-GN done")

    t = time.perf_counter()
    _repair(st, report)
    _flag(st)
    timing["rescue"] = time.perf_counter() - t
    timing.update({k: float(c) for k, c in st.counts.items()})
    return st.p, st.zncc, st.iters, st.reason, st.static


def _seed_nodes(st: _State) -> np.ndarray:
    """The usable node nearest each seed (errors name a seed outside the ROI,
    a ROI region without a seed or without usable nodes)."""
    from scipy import ndimage

    roi, grid, params = st.roi, st.grid, st.params
    rows, cols = roi.shape
    seeds = np.asarray(params.seeds, float).reshape(-1, 2)
    labels, _ = ndimage.label(roi)
    seed_region = []
    for sx, sy in seeds:
        ix, iy = int(round(sx)), int(round(sy))
        if not (0 <= ix < cols and 0 <= iy < rows) or not roi[iy, ix]:
            raise DICError("seed_outside_roi", f"seed ({sx:g}, {sy:g}) is outside the ROI; "
                           "place seeds on analysed material", x=sx, y=sy)
        seed_region.append(labels[iy, ix])
    node_region = labels[grid.y, grid.x]
    for r in np.unique(node_region[st.usable]):
        if r not in seed_region:
            ys, xs = np.nonzero(labels == r)
            raise ValueError(
                f"ROI region {r} (x {xs.min()}-{xs.max()}, y {ys.min()}-{ys.max()}, "
                f"{xs.size} px) has no seed; add a seed point inside it")
    nodes = []
    for (sx, sy), r in zip(seeds, seed_region):
        cand = np.nonzero(st.usable & (node_region == r))[0]
        if cand.size == 0:
            raise ValueError(f"seed ({sx:g}, {sy:g}): its ROI region has no usable node; "
                             "enlarge the region or reduce the subset")
        nodes.append(cand[np.argmin(np.hypot(grid.x[cand] - sx, grid.y[cand] - sy))])
    return np.unique(np.asarray(nodes))


def _propagate_seeds(st: _State) -> None:
    """Seed-propagation initial guess.

    Each seed is solved at its nearest usable node by a cross-correlation
    search over the whole image and IC-GN (with rotated subsets when the
    plain search gives no acceptable match); the solution then spreads, wave
    by wave, to mask-connected lattice neighbours, each starting from its
    best solved neighbour extrapolated to first order with that neighbour's
    gradient (``u + F dX``). Every connected ROI region needs a seed.
    """
    seed_nodes = _seed_nodes(st)
    n = st.grid.n
    whole = st.params.replace(search_max=max(*st.roi.shape, st.params.search))
    p_init = np.zeros((n, 6))
    # a seed may have moved anywhere: widen until the peak is convincing
    p_init[seed_nodes] = st.ncc_guess(seed_nodes, whole, accept=0.9)
    active = np.zeros(n, bool)
    active[seed_nodes] = True
    st.store(st.run(active, p_init), seed_nodes)
    zmin = st.floor()
    solved = active & st.acceptable(zmin)
    missing = seed_nodes[~solved[seed_nodes]]
    if missing.size:  # perhaps a large rotation
        solved[_rotated_rescue(st, missing, zmin, whole, all_nodes=True)] = True
    if not solved.any():
        raise DICError("no_seed_match", "no seed could be matched in the deformed image; "
                       "move the seeds to well-textured material")
    tries = _grow(st, lattice_neighbours(st.grid, st.roi, radius=1), solved, st.usable,
                  zmin, max_tries=1)
    # unreachable from any seed through converged nodes
    st.reason[st.usable & ~active & (tries == 0)] = Reason.NO_INITIAL_GUESS


def _grow(st: _State, nbrs: np.ndarray, good: np.ndarray, eligible: np.ndarray,
          zmin: np.ndarray, max_tries: int, report=None) -> np.ndarray:
    """Grow the ``good`` set into the other ``eligible`` nodes, wave by wave.

    Each eligible node next to a good one restarts IC-GN from its best good
    neighbour (highest ZNCC), extrapolated to first order with that
    neighbour's gradient; converged nodes with ZNCC >= ``zmin`` (per node)
    join the good set. A failed attempt only replaces a node's state when it
    had none yet (so earlier results are never lost). Each node gets
    ``max_tries`` attempts. Used by seed propagation and by the repair stage.
    Updates ``good`` and the state in place; returns the attempts per node.
    """
    grid, p, zncc = st.grid, st.p, st.zncc
    tries = np.zeros(grid.n, np.int8)
    has = nbrs >= 0
    active = np.zeros(grid.n, bool)
    while True:
        if report is not None:
            report("repair", 0.8, "growing trusted regions")
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
        res = st.run(active, p_try)
        rz, rr = res[1], res[3]
        ok = (rr[cand] == Reason.OK) & (rz[cand] >= zmin[cand])
        st.store(res, cand[ok | ~np.isfinite(zncc[cand])])
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


def _rotated_rescue(st: _State, candidates: np.ndarray, zmin: np.ndarray,
                    params: DICParams | None = None, all_nodes: bool = False) -> np.ndarray:
    """Rotated-subset search (over ``search_max``) and IC-GN from the best
    angle at the ``candidates``, or at up to :data:`ROTATION_NODES` of them
    (the two nearest the middle of the ROI, then spread over the rest), two
    at a time until one matches; returns the nodes now acceptable (their
    state stored)."""
    prm = params or st.params
    st.rotation_tried = True
    top = prm.resolved_search_max(st.im.f.shape)
    if all_nodes:
        rounds = [candidates]
    else:
        # first the two nearest the middle of the ROI (a specimen turns about
        # a point inside it, where displacements are smallest), then spread
        x, y = st.grid.x[candidates], st.grid.y[candidates]
        use = st.usable
        d = np.hypot(x - st.grid.x[use].mean(), y - st.grid.y[use].mean())
        near = candidates[np.argsort(d, kind="stable")[:2]]
        rest = np.setdiff1d(candidates, near)
        pick = np.concatenate([near, rest[spread_nodes(st.grid.x[rest], st.grid.y[rest],
                                                       ROTATION_NODES - near.size)]])
        rounds = [pick[i:i + 2] for i in range(0, pick.size, 2)]
    for nodes in rounds:
        p0, _ = rotated_search(st.im.f, st.im.g, st.roi, st.grid.x[nodes],
                               st.grid.y[nodes], prm.half, top)
        p_try = st.p.copy()
        p_try[nodes] = p0
        active = np.zeros(st.grid.n, bool)
        active[nodes] = True
        res = st.run(active, p_try)
        rz, rr = res[1], res[3]
        ok = (rr[nodes] == Reason.OK) & (rz[nodes] >= zmin[nodes])
        st.store(res, nodes[ok])
        if ok.any():
            return nodes[ok]
    return nodes[:0]


def _guess_from_result(grid: NodeGrid, guess) -> np.ndarray:
    """Initial affine parameters from a previous result: each node starts
    from the nearest valid node of ``guess``, extrapolated to first order."""
    gv = np.nonzero(guess.valid)[0]
    tree = cKDTree(np.column_stack([guess.x[gv], guess.y[gv]]))
    _, j = tree.query(np.column_stack([grid.x, grid.y]))
    src = gv[j]
    pg = np.column_stack([guess.u, guess.dudx, guess.dudy, guess.v, guess.dvdx, guess.dvdy])
    return _extrapolate(pg[src], grid.x - guess.x[src], grid.y - guess.y[src])


def _coarse_to_fine(st: _State, timing: dict, report: ProgressFn,
                    prediction: np.ndarray | None = None) -> float:
    """FFT initial guess: NCC and IC-GN at coarse nodes (every k-th lattice
    node; rotated searches at a few when many fail), then IC-GN at every
    other usable node from its nearest acceptable coarse node, extrapolated
    to first order (or from its own NCC search if none is acceptable). The
    coarse nodes search around ``prediction`` ((n, 6) affine warps of every
    node, e.g. from a previous frame) when given, else around the anchors'
    (:func:`_anchor_prediction`). Records ``timing["init"]``; returns the
    ``time.perf_counter()`` at which IC-GN started."""
    t = time.perf_counter()
    grid, params, usable = st.grid, st.params, st.usable
    n = grid.n
    k = max(1, params.resolved_init_spacing() // params.step)
    coarse = np.nonzero(usable & (grid.ix >= 0) & (grid.ix % k == 0)
                        & (grid.iy % k == 0))[0]
    if coarse.size == 0:
        coarse = np.nonzero(usable)[0]
    p_init = np.zeros((n, 6))
    pred = _anchor_prediction(st, coarse, k) if prediction is None else prediction[coarse]
    if pred is None:
        p_init[coarse] = st.ncc_guess(coarse)
    else:
        # predicted out of view: IC-GN confirms it (OUT_OF_IMAGE) without a
        # search, which would only widen in vain; the repair waves retry them
        gone = _leaves_image(st, coarse, pred)
        p_init[coarse[gone]] = pred[gone]
        p_init[coarse[~gone]] = st.ncc_guess(coarse[~gone], centre=pred[~gone][:, [0, 3]])
    timing["init"] = time.perf_counter() - t
    report("initial_guess", 0.3, f"initial guess at {coarse.size} coarse nodes")

    t = time.perf_counter()
    active = np.zeros(n, bool)
    active[coarse] = True
    st.store(st.run(active, p_init), coarse)
    zmin = st.floor()
    good = st.acceptable(zmin)
    failed = coarse[~good[coarse] & (st.reason[coarse] != Reason.OUT_OF_IMAGE)]
    if failed.size and not good[coarse].any():
        _rotated_rescue(st, failed, zmin)  # e.g. a large rotation
        good = st.acceptable(zmin)
    good_c = coarse[good[coarse]]
    rest = np.nonzero(usable & ~active)[0]
    if rest.size:
        if good_c.size:
            tree = cKDTree(np.column_stack([grid.x[good_c], grid.y[good_c]]))
            _, j = tree.query(np.column_stack([grid.x[rest], grid.y[rest]]))
            src = good_c[j]
            p_init[rest] = _extrapolate(st.p[src], grid.x[rest] - grid.x[src],
                                        grid.y[rest] - grid.y[src])
        else:
            p_init[rest] = st.ncc_guess(rest)
        active[:] = False
        active[rest] = True
        st.store(st.run(active, p_init), rest)
    return t


def _anchor_prediction(st: _State, coarse: np.ndarray, k: int) -> np.ndarray | None:
    """Predicted affine warps ``(m, 6)`` of the ``coarse`` nodes from a few anchors.

    Anchors (every ``anchor_spacing``-th lattice node among the coarse ones)
    get the widening NCC search and IC-GN; each coarse node is predicted
    from its nearest acceptable anchor, extrapolated to first order with the
    anchor's full affine warp, so its own search needs no wider range than
    for small motion. ``None`` (search around zero) when anchors are off,
    too few for the lattice to gain from them, or none matches (e.g. a large
    rotation: the rotated search then takes over)."""
    grid, prm = st.grid, st.params
    ka = prm.resolved_anchor_spacing() // prm.step
    if ka <= k or coarse.size < 4 * ANCHOR_MIN:
        return None
    # offset by half a spacing: away from the image border, where material
    # leaves the view and a search would widen in vain
    off = (ka // k // 2) * k
    anchors = coarse[(grid.ix[coarse] % ka == off) & (grid.iy[coarse] % ka == off)]
    if anchors.size < ANCHOR_MIN:
        return None
    p_init = np.zeros((grid.n, 6))
    p_init[anchors] = st.ncc_guess(anchors)
    active = np.zeros(grid.n, bool)
    active[anchors] = True
    st.store(st.run(active, p_init), anchors)
    good = anchors[st.acceptable(st.floor())[anchors]]
    st.counts["anchors"] = int(good.size)
    if good.size == 0:
        return None
    tree = cKDTree(np.column_stack([grid.x[good], grid.y[good]]))
    _, j = tree.query(np.column_stack([grid.x[coarse], grid.y[coarse]]))
    src = good[j]
    return _extrapolate(st.p[src], grid.x[coarse] - grid.x[src], grid.y[coarse] - grid.y[src])


def _leaves_image(st: _State, nodes: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Whether the affine warps ``p`` take a corner of the nodes' subsets out
    of the deformed image."""
    rows, cols = st.im.g.shape
    h = st.params.half
    out = np.zeros(nodes.size, bool)
    for dx, dy in ((-h, -h), (-h, h), (h, -h), (h, h)):
        x = st.grid.x[nodes] + dx + p[:, 0] + p[:, 1] * dx + p[:, 2] * dy
        y = st.grid.y[nodes] + dy + p[:, 3] + p[:, 4] * dx + p[:, 5] * dy
        out |= (x < 0) | (x > cols - 1) | (y < 0) | (y > rows - 1)
    return out


def _repair(st: _State, report: ProgressFn) -> None:
    """Repair failed, poorly matching or inconsistent nodes: grow trusted
    regions into them, then (FFT mode) try rotated searches at a few when no
    node matches at all, and each node's own search, growing again after
    each."""
    grid, roi, usable = st.grid, st.roi, st.usable
    nbrs1 = lattice_neighbours(grid, roi, radius=1)  # propagation neighbours (3 x 3)
    zmin = st.floor()
    memo = [-1, None]  # the good nodes of a state version (the median test's cost)

    def good_nodes() -> np.ndarray:
        if memo[0] != st.version:
            ok = st.acceptable(zmin)
            memo[:] = st.version, ok & ~st.outliers(ok)
        return memo[1].copy()

    def bad_nodes() -> np.ndarray:
        # a flat or singular reference subset is NO_TEXTURE before any step
        # (0 iterations) from every start: retrying it, or searching it ever
        # wider, cannot change it (a saturated region of the crack sample: 1,490
        # nodes, 18 s of searches at the widest range)
        flat = (st.reason == Reason.NO_TEXTURE) & (st.iters == 0)
        return np.nonzero(usable & ~good_nodes() & (st.reason != Reason.OUT_OF_IMAGE)
                          & ~flat)[0]

    def repair_waves() -> None:
        """Grow trusted regions into failed, poor or inconsistent nodes."""
        _grow(st, nbrs1, good_nodes(), usable, zmin, max_tries=2, report=report)

    st.counts["rescue_nodes"] = int(bad_nodes().size)
    repair_waves()
    if st.params.init != "fft":  # seeds: motion may exceed any FFT range
        return
    bad = bad_nodes()
    if bad.size and not st.rotation_tried and not good_nodes().any():
        if _rotated_rescue(st, bad, zmin).size:  # e.g. a large rotation
            repair_waves()
    bad = bad_nodes()
    bad = bad[~st.searched[bad]]  # a node's own search gives the same peak again
    if bad.size:
        st.counts["rescue_searches"] = int(bad.size)
        p_try = st.p.copy()
        p_try[bad] = st.ncc_guess(bad)
        active = np.zeros(grid.n, bool)
        active[bad] = True
        res = st.run(active, p_try)
        rz, rr = res[1], res[3]
        ok = (rr[bad] == Reason.OK) & (rz[bad] >= zmin[bad])
        was = (st.reason[bad] == Reason.OK) & (st.zncc[bad] >= rz[bad])
        st.store(res, bad[ok & ~was])
        repair_waves()


def _flag(st: _State) -> None:
    """Flag what still fails (its best attempt kept): ZNCC below
    ``zncc_min`` (LOW_CORRELATION) or below the noise-relative floor
    (POOR_MATCH, or BEYOND_SEARCH when the node's own search reached
    ``search_max`` without a convincing peak), the median test (OUTLIER),
    and a predicted uncertainty above ``max_uncertainty`` (UNCERTAIN)."""
    conv = st.usable & (st.reason == Reason.OK)
    zmin = st.validity.zncc_floor(st.zncc, conv)
    low = conv & ~(st.zncc >= st.params.zncc_min)
    poor = conv & ~low & ~(st.zncc >= zmin)
    st.reason[low] = Reason.LOW_CORRELATION
    st.reason[poor] = Reason.POOR_MATCH
    st.reason[(low | poor) & st.beyond] = Reason.BEYOND_SEARCH
    trusted = st.reason == Reason.OK
    st.reason[st.outliers(trusted)] = Reason.OUTLIER
    trusted = st.reason == Reason.OK
    st.reason[st.validity.uncertain(st.zncc, trusted)] = Reason.UNCERTAIN
