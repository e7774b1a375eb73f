"""Local DVC: every node's subset matched on its own by 3-D IC-GN.

Stages: coefficients of both volumes; the rigid shift of the central block;
anchor nodes searched around it (FFT ZNCC) and solved; every node started
from its nearest solved anchor's affine map and solved in parallel; failed
nodes restarted from solved lattice neighbours; then the validity tests
(ZNCC, uncertainty, median test).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..core.params import DICParams
from ..core.reasons import Reason
from ..kernels.icgn3d import NPAR3, icgn3d
from .grid import VolumeGrid
from .init_guess import global_shift, ncc_search
from .spline import coefficients, gradients

__all__ = ["NodeState", "NODE_ARRAYS", "LocalState", "solve_local_volume", "run_icgn",
           "extrapolate"]

_BATCH = 1024  # nodes between two progress (and cancellation) points


@dataclass
class NodeState:
    """Per-node outputs of the local solve over a lattice: what AL-DVC, the
    validity tests and the result need (no images), so the blocks of a large
    volume can be merged into one."""

    grid: VolumeGrid
    params: DICParams
    timing: dict = field(default_factory=dict)
    #: ``report(stage, fraction, message)`` or None: progress and cancellation
    report: object = None

    def __post_init__(self):
        n = self.grid.n
        self.nodes = np.ascontiguousarray(self.grid.xyz)
        self.p = np.zeros((n, NPAR3))
        self.status = np.full(n, Reason.NO_INITIAL_GUESS, np.int8)
        self.iters = np.zeros(n, np.int32)
        self.zncc = np.full(n, np.nan)
        self.ustd = np.full((n, 3), np.nan)
        self.nvox = np.zeros(n, np.int64)
        self.hrow = np.zeros((n, 3, NPAR3))  # rows u, v, w of each Local H

    def good(self) -> np.ndarray:
        return (self.status == Reason.OK) & (self.zncc >= self.params.zncc_min)

    def take(self, rows: np.ndarray, grid: VolumeGrid) -> NodeState:
        """The state of nodes ``rows`` (which ``grid`` lists, in that order)."""
        out = NodeState(grid, self.params, dict(self.timing), self.report)
        for name in NODE_ARRAYS:
            setattr(out, name, getattr(self, name)[rows])
        return out


#: the per-node arrays of a :class:`NodeState` (what merging blocks copies)
NODE_ARRAYS = ("p", "status", "iters", "zncc", "ustd", "nvox", "hrow")


@dataclass(kw_only=True)
class LocalState(NodeState):
    """:class:`NodeState` with the inputs of the local solve: both volumes,
    the reference's gradients and the deformed volume's spline coefficients."""

    f: np.ndarray
    g: np.ndarray
    fg: np.ndarray
    gc: np.ndarray
    mask: np.ndarray
    search_max: int = 64


def run_icgn(st: LocalState, active: np.ndarray, mu: float = 0.0, target=None,
             ustd=None, span=None) -> None:
    """Solve the ``active`` nodes from their current ``st.p`` (with AL-DVC's
    penalty ``mu`` towards ``target`` when given; ``ustd`` receives the
    uncertainty instead of ``st.ustd``).

    With ``span = (stage, start, end)`` and ``st.report`` set, the nodes go in
    batches, each followed by ``st.report(stage, fraction, message)`` (its
    progress and cancellation point), the fraction running from ``start`` to
    ``end``."""
    pr = st.params
    target = st.p if target is None else np.ascontiguousarray(target)
    todo = np.flatnonzero(active).astype(np.int64)
    batches = [todo]
    if span is not None and st.report is not None and todo.size > 2 * _BATCH:
        batches = np.array_split(todo, -(-todo.size // _BATCH))
    done = 0
    for batch in batches:
        icgn3d(st.f, st.fg, st.gc, st.mask, st.nodes, st.p, batch, pr.subset // 2,
               pr.max_iter, pr.tol, pr.min_component, st.status, st.iters, st.zncc,
               st.ustd if ustd is None else ustd, st.nvox, float(mu), target, st.hrow)
        done += batch.size
        if span is not None and st.report is not None:
            stage, a, b = span
            st.report(stage, a + (b - a) * done / max(todo.size, 1),
                      f"{done}/{todo.size} nodes")


def extrapolate(p_src: np.ndarray, x_src: np.ndarray, x_dst: np.ndarray) -> np.ndarray:
    """Warps at ``x_dst`` from the affine maps ``p_src`` of nodes at ``x_src``."""
    out = p_src.copy()
    d = (x_dst - x_src).astype(float)
    for a in range(3):
        out[:, 4 * a] += (p_src[:, 4 * a + 1:4 * a + 4] * d).sum(1)
    return out


def _anchor_mask(grid: VolumeGrid, spacing: int) -> np.ndarray:
    """Every ``k``-th lattice node along each axis, ~``spacing`` apart."""
    step = max(int(grid.xs[1] - grid.xs[0]) if grid.xs.size > 1 else 1, 1)
    k = max(int(round(spacing / step)), 1)
    keep = []
    for idx, size in ((grid.ix, grid.xs.size), (grid.iy, grid.ys.size), (grid.iz, grid.zs.size)):
        on = np.zeros(size, bool)
        on[(size - 1 - (size - 1) // k * k) // 2::k] = True  # centred on the lattice
        keep.append(on[idx])
    return keep[0] & keep[1] & keep[2]


def _search(st: LocalState, nodes: np.ndarray, shifts: np.ndarray, near: int) -> None:
    """FFT ZNCC search of ``nodes`` around ``shifts`` (widened while the peak
    is on the range's edge or weak), then IC-GN from the integer match."""
    pr = st.params
    for k, s0 in zip(nodes, shifts):
        s = near
        while True:
            shift, zn, border = ncc_search(st.f, st.g, st.nodes[k], pr.subset // 2, s, s0)
            if (not border and zn >= pr.zncc_min) or s >= st.search_max:
                break
            s = min(2 * s, st.search_max)
        st.p[k] = 0.0
        st.p[k, [0, 4, 8]] = shift
    active = np.zeros(st.grid.n, bool)
    active[nodes] = True
    run_icgn(st, active)


def _anchors(st: LocalState, shift0) -> np.ndarray:
    """Search and solve the anchor nodes in two waves; returns their indices.

    The anchors near the volume centre are searched around the rigid shift;
    the outer ones start from the warp their nearest inner anchor's affine
    map predicts (rotation and strain grow the motion with the distance),
    and only those IC-GN cannot solve from it are searched, around that
    prediction."""
    pr = st.params
    spacing = pr.init_spacing or max(3 * pr.subset // 2, 24)
    anchors = np.flatnonzero(_anchor_mask(st.grid, spacing))
    centre = (np.array(st.f.shape[::-1]) - 1) / 2
    dist = np.linalg.norm(st.nodes[anchors] - centre, axis=1)
    inner = dist <= max(np.sort(dist)[min(7, dist.size - 1)], 0.3 * min(st.f.shape))
    near = max(min(pr.search, 8), 3)
    first = anchors[inner]
    _search(st, first, np.tile(np.asarray(shift0), (first.size, 1)), near)
    good = first[st.good()[first]]
    outer = anchors[~inner]
    if good.size and outer.size:
        # IC-GN straight from the predicted warp; FFT search only where that fails
        _, j = cKDTree(st.nodes[good]).query(st.nodes[outer])
        pred = extrapolate(st.p[good[j]], st.nodes[good[j]], st.nodes[outer])
        st.p[outer] = pred
        active = np.zeros(st.grid.n, bool)
        active[outer] = True
        run_icgn(st, active)
        lost = ~st.good()[outer]
        if lost.any():
            _search(st, outer[lost], np.rint(pred[lost][:, [0, 4, 8]]).astype(int),
                    max(near // 2, 3))
    elif outer.size:
        _search(st, outer, np.tile(np.asarray(shift0), (outer.size, 1)), near)
    return anchors


def _propagate(st: LocalState, src: np.ndarray, dst: np.ndarray) -> None:
    """Start ``dst`` nodes from their nearest ``src`` node's extrapolated warp."""
    if src.size == 0 or dst.size == 0:
        return
    _, j = cKDTree(st.nodes[src]).query(st.nodes[dst])
    st.p[dst] = extrapolate(st.p[src[j]], st.nodes[src[j]], st.nodes[dst])


def _retry(st: LocalState, rounds: int = 2) -> None:
    """Restart failed nodes from their nearest good node, a few rounds."""
    for _ in range(rounds):
        good = st.good()
        bad = np.flatnonzero(~good & (st.status != Reason.SMALL_COMPONENT))
        if bad.size == 0 or not good.any():
            return
        _propagate(st, np.flatnonzero(good), bad)
        before = st.good()
        active = np.zeros(st.grid.n, bool)
        active[bad] = True
        run_icgn(st, active)
        if st.good().sum() <= before.sum():
            return


def solve_local_volume(ref, dfm, mask, grid: VolumeGrid, params: DICParams, report=None,
                       end: float = 0.95) -> LocalState:
    """Local IC-GN at every node of ``grid``; returns the state with per-node
    warps, status codes (gauss-newton codes; not yet the final reasons).

    ``report(stage, fraction, message)`` (optional) is called between the
    stages and the batches of nodes, the fraction reaching ``end`` at the
    repair; it may raise to cancel."""
    say = report or (lambda *a: None)
    t0 = time.perf_counter()
    say("prefilter", 0.01, "prefiltering the volumes")
    f = np.ascontiguousarray(ref, np.float32)
    g = np.ascontiguousarray(dfm, np.float32)
    search_max = params.search_max or max(max(f.shape) // 4, 4 * params.search)
    st = LocalState(grid=grid, params=params, report=report, f=f, g=g,
                    fg=gradients(coefficients(f)), gc=coefficients(g), mask=mask,
                    search_max=search_max)
    t1 = time.perf_counter()
    say("initial_guess", 0.05 * end, "initial guess")
    shift0, _ = global_shift(f, g, params.search, search_max)
    anchors = _anchors(st, shift0)
    t2 = time.perf_counter()
    good = np.flatnonzero(st.good())
    rest = np.setdiff1d(np.arange(grid.n), anchors)
    if good.size == 0:  # no anchor matched: start every node from the rigid shift
        st.p[rest] = 0.0
        st.p[np.ix_(rest, [0, 4, 8])] = shift0
    _propagate(st, good, rest)
    active = np.zeros(grid.n, bool)
    active[rest] = True
    say("icgn", 0.1 * end, f"{grid.n} nodes")
    run_icgn(st, active, span=("icgn", 0.1 * end, 0.97 * end))
    say("repair", 0.97 * end, "restarting failed nodes")
    _retry(st)
    st.timing.update(prefilter=t1 - t0, init_guess=t2 - t1,
                     icgn=time.perf_counter() - t2)
    return st
