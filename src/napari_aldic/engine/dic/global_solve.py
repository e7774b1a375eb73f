"""Q4 finite-element meshes of the DIC nodes and the global compatibility solve.

The AL-DIC global step finds a continuous displacement field ``û`` on a mesh
of bilinear quadrilaterals (Q4) whose corners are the DIC nodes. Each node's
displacement gradient ``(Dû)_i`` is the average, over the mesh elements that
have node i as a corner, of that element's bilinear gradient evaluated at
the corner. ``D`` acts on each displacement component separately, so the
system matrix

    A = β Gᵀ diag(w_g) G + μ diag(w)

(G: the scalar nodal-gradient operator; w: 1 for trusted nodes, a tiny
weight for untrusted ones; w_g: 1 for trusted nodes, 0 for untrusted ones,
whose local gradients are unknown) is shared by u and v and factorised once.

Handling of awkward elements (documented behaviour):

* an element whose area is not entirely inside the ROI (it spans a hole, a
  crack or the outline) is left out of the mesh, so the two faces of a crack
  are never tied together;
* an element with an untrusted corner node stays in the mesh: that node's
  data weight is tiny (``w = 1e-6``), so its ``û`` is interpolated from its
  trusted neighbours through the gradient term instead of pulling them
  towards a wrong local value;
* a node that belongs to no element keeps its local displacement
  (``û = u - v``), since nothing constrains it.

Hanging nodes of a quadtree mesh (mid-edge nodes where a refined element
meets a coarser one) are constrained to the mean of the two end nodes of
that edge, ``û_h = (û_a + û_b) / 2``, by eliminating them:
``û = T û_free`` with a prolongation matrix ``T``; the reduced system
``Tᵀ A T`` is solved and ``û`` expanded, so the constraint holds to
rounding error and ``û`` is continuous across level transitions.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .linear_solvers import DIRECT_MAX_UNKNOWNS, SPDSolver, solver_method
from .subsets import integral_image, rect_sums

__all__ = ["Q4Mesh", "uniform_mesh", "gradient_operator", "GlobalSolver",
           "element_inside_roi", "CurvatureEstimator", "curvature_operator",
           "second_difference_operators", "level_transition_nodes", "solver_method", "SPDSolver",
           "DIRECT_MAX_UNKNOWNS"]

UNTRUSTED_WEIGHT = 1e-6


@dataclass
class Q4Mesh:
    """Quadrilateral mesh over DIC nodes.

    Attributes
    ----------
    x, y : (N,) float64
        Node coordinates in pixels.
    elements : (E, 4) int64
        Corner node indices, in the order (x0, y0), (x1, y0), (x1, y1), (x0, y1).
    hanging : (H, 3) int64
        Rows ``(h, a, b)``: node h is constrained to the mean of nodes a and b.
    level : (E,) int
        Refinement level of each element (0 = base mesh).
    """

    x: np.ndarray
    y: np.ndarray
    elements: np.ndarray
    hanging: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    level: np.ndarray | None = None

    @property
    def n_nodes(self) -> int:
        return int(self.x.size)

    @property
    def n_elements(self) -> int:
        return int(self.elements.shape[0])

    def prolongation(self) -> tuple[sp.csr_matrix, np.ndarray]:
        """``(T, free)``: û = T @ û[free]; hanging nodes expressed by free ones
        (built once per mesh; not to be modified)."""
        return _cached(self, "prolongation", _prolongation)

    def reduced(self, A: sp.spmatrix) -> sp.csr_matrix:
        """``Tᵀ A T`` (CSR): the nodal operator ``A`` on the free nodes; on a
        mesh without hanging nodes (``T`` the identity) ``A`` as it is, without
        the two sparse products (11 ms for the curvature operator at 15k nodes):
        then possibly ``A`` itself (a cached operator), not to be modified."""
        if not self.hanging.size:
            return A.tocsr()
        T, _ = self.prolongation()
        return (T.T @ A @ T).tocsr()


def _prolongation(mesh: Q4Mesh) -> tuple[sp.csr_matrix, np.ndarray]:
    """:meth:`Q4Mesh.prolongation`, built."""
    n = mesh.n_nodes
    is_h = np.zeros(n, bool)
    is_h[mesh.hanging[:, 0]] = True
    free = np.nonzero(~is_h)[0]
    col = -np.ones(n, np.int64)
    col[free] = np.arange(free.size)
    # rows as dicts; resolve chains (a parent may itself be hanging)
    parents = {int(h): (int(a), int(b)) for h, a, b in mesh.hanging}

    def expand(i, w, out):
        if i in parents:
            a, b = parents[i]
            expand(a, 0.5 * w, out)
            expand(b, 0.5 * w, out)
        else:
            out[col[i]] = out.get(col[i], 0.0) + w

    rows, cols, vals = [free], [np.arange(free.size)], [np.ones(free.size)]
    for h in parents:
        acc: dict[int, float] = {}
        expand(h, 1.0, acc)
        rows.append(np.full(len(acc), h))
        cols.append(np.fromiter(acc.keys(), np.int64, len(acc)))
        vals.append(np.fromiter(acc.values(), float, len(acc)))
    T = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, free.size))
    return T, free


def uniform_mesh(grid, roi: np.ndarray) -> Q4Mesh:
    """Q4 mesh of a node lattice: one element per lattice cell whose four
    corner nodes exist and whose rectangle lies inside the ROI."""
    idx = grid.index_image()
    c0 = idx[:-1, :-1].ravel()
    c1 = idx[:-1, 1:].ravel()
    c2 = idx[1:, 1:].ravel()
    c3 = idx[1:, :-1].ravel()
    e = np.column_stack([c0, c1, c2, c3])
    e = e[(e >= 0).all(axis=1)]
    x = grid.x.astype(np.float64)
    y = grid.y.astype(np.float64)
    if roi is not None:
        e = e[_elements_inside(x, y, e, roi)]
    return Q4Mesh(x, y, e.astype(np.int64), level=np.zeros(e.shape[0], np.int64))


#: ROI pixels read at a time when elements are tested against a mask that is
#: not in memory (tiled runs read the mask of a mosaic band by band)
MESH_BAND_PIXELS = 16_000_000


def _elements_inside(x, y, e, roi) -> np.ndarray:
    """:func:`element_inside_roi` of lattice elements (row-major, as
    :func:`uniform_mesh` makes them); a mask that is not an array in memory is
    read in bands of element rows."""
    if isinstance(roi, np.ndarray) and not isinstance(roi, np.memmap):
        return element_inside_roi(x, y, e, roi if roi.dtype == bool else roi != 0)
    top = y[e[:, 0]]
    rows = np.unique(top)
    keep = np.zeros(e.shape[0], bool)
    height = float(np.max(y[e[:, 2]] - top)) if e.size else 1.0
    per_band = max(1, int(MESH_BAND_PIXELS // max(1.0, height * roi.shape[1])))
    for b in range(0, rows.size, per_band):
        lo, hi = rows[b], rows[min(rows.size, b + per_band) - 1]
        sel = (top >= lo) & (top <= hi)
        r0 = int(np.rint(lo))
        r1 = int(np.rint(y[e[sel, 2]].max())) + 1
        band = np.asarray(roi[r0:r1, :]) != 0
        keep[sel] = element_inside_roi(x, y - r0, e[sel], band)
    return keep


def element_inside_roi(x: np.ndarray, y: np.ndarray, elements: np.ndarray,
                       roi: np.ndarray) -> np.ndarray:
    """True for elements whose whole rectangle (pixels) lies in the ROI."""
    if roi.all():
        return np.ones(elements.shape[0], bool)
    ii = integral_image((~roi).view(np.uint8))
    x0 = np.rint(x[elements[:, 0]]).astype(np.int64)
    y0 = np.rint(y[elements[:, 0]]).astype(np.int64)
    x1 = np.rint(x[elements[:, 2]]).astype(np.int64)
    y1 = np.rint(y[elements[:, 2]]).astype(np.int64)
    return rect_sums(ii, x0, y0, x1, y1) == 0


def gradient_operator(mesh: Q4Mesh) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray]:
    """Nodal gradient operators ``(Gx, Gy, covered)`` of a scalar nodal field.

    ``(Gx @ s)[i]`` is ds/dx at node i: the mean over the elements having i
    as a corner of the bilinear element gradient evaluated at that corner.
    ``covered[i]`` is False for nodes in no element (their rows are zero).
    """
    e = mesh.elements
    E = e.shape[0]
    n = mesh.n_nodes
    if E == 0:
        z = sp.csr_matrix((n, n))
        return z, z, np.zeros(n, bool)
    s = (mesh.x[e[:, 1]] - mesh.x[e[:, 0]]).astype(float)
    t = (mesh.y[e[:, 3]] - mesh.y[e[:, 0]]).astype(float)
    count = np.bincount(e.ravel(), minlength=n).astype(float)
    inv = np.divide(1.0, count, out=np.zeros(n), where=count > 0)
    # corner c of a Q4 element: at (x0, y0) d/dx = (s1 - s0)/s, d/dy = (s3 - s0)/t, etc.:
    # (neighbour along x, its sign) and (neighbour along y, its sign) of corners 0..3
    Gx = _corner_differences(e, n, (1, 0, 3, 2), (1, -1, -1, 1), s, inv)
    Gy = _corner_differences(e, n, (3, 2, 1, 0), (1, 1, -1, -1), t, inv)
    return Gx, Gy, count > 0


def _corner_differences(e, n: int, neighbour, sign, length, inv) -> sp.csr_matrix:
    """One axis of :func:`gradient_operator`: at each corner ``c`` of every
    element ``sign[c] * (s[neighbour[c]] - s[c]) / length``, averaged over the
    node's elements (``inv``: 1 / their number). Filled in place, two entries
    per corner: on a 1.5 M-node mesh the triplets are the peak memory."""
    E = e.shape[0]
    rows = np.empty(8 * E, np.int64)
    cols = np.empty(8 * E, np.int64)
    vals = np.empty(8 * E)
    for c in range(4):
        a, b = slice(2 * c * E, (2 * c + 1) * E), slice((2 * c + 1) * E, (2 * c + 2) * E)
        rows[a] = rows[b] = cols[b] = e[:, c]
        cols[a] = e[:, neighbour[c]]
        vals[a] = sign[c] / length
        vals[b] = -vals[a]
    vals *= inv[rows]
    G = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    G.eliminate_zeros()
    return G


_CACHE_LOCK = threading.Lock()


def _cached(mesh: Q4Mesh, key: str, build):
    """Mesh-derived operators, built once per mesh object (the SURE choice, the
    global solver and the curvature estimate of one analysis share them).
    Threads that ask for one while another builds it wait for that build:
    the smoothing choice's two threads ask for the same operators at once,
    and each built them (2 x 30 ms at 15k nodes). Only a build in progress
    is a Future in the mesh's store (a mesh stays picklable)."""
    with _CACHE_LOCK:
        store = mesh.__dict__.setdefault("_operators", {})
        entry = store.get(key)
        mine = entry is None
        if mine:
            entry = store[key] = Future()
    if not isinstance(entry, Future):
        return entry
    if not mine:
        return entry.result()
    try:
        value = build(mesh)
    except BaseException as exc:
        with _CACHE_LOCK:  # not kept: the next call tries again
            del store[key]
        entry.set_exception(exc)
        raise
    with _CACHE_LOCK:
        store[key] = value
    entry.set_result(value)
    return value


def _axis_neighbours(mesh: Q4Mesh) -> np.ndarray:
    """(N, 4) nearest edge neighbour of every node towards -x, +x, -y, +y
    (-1 where the node has none), from the element edges."""
    e = mesh.elements
    n = mesh.n_nodes
    pairs = np.concatenate([e[:, [0, 1]], e[:, [3, 2]], e[:, [0, 3]], e[:, [1, 2]]])
    a, b = pairs[:, 0], pairs[:, 1]  # b lies to the +x or +y of a
    horiz = mesh.y[a] == mesh.y[b]
    d = np.where(horiz, mesh.x[b] - mesh.x[a], mesh.y[b] - mesh.y[a])
    nb = -np.ones((n, 4), np.int64)
    for node, direc, other in ((b, np.where(horiz, 0, 2), a), (a, np.where(horiz, 1, 3), b)):
        key = node * 4 + direc
        order = np.lexsort((d, key))  # by slot, nearest first
        key, other = key[order], other[order]
        first = np.r_[True, key[1:] != key[:-1]]
        nb.ravel()[key[first]] = other[first]
    return nb


def second_difference_operators(mesh: Q4Mesh):
    """Sparse second-derivative operators of a scalar nodal field (1/px).

    Returns ``(Dxx, Dyy, Dxy, has_xx, has_yy)``: ``Dxx``/``Dyy`` (N x N) are
    three-point second differences along x/y at nodes with an edge neighbour
    on both sides (zero rows elsewhere, ``has_xx``/``has_yy`` False);
    ``Dxy`` (E x N) is the twist ``(s00 - s10 + s11 - s01) / (dx dy)`` of
    each element. All vanish exactly for affine fields.
    """
    return _cached(mesh, "second_differences", _second_differences)


def _second_differences(mesh: Q4Mesh):
    nb = _cached(mesh, "axis_neighbours", _axis_neighbours)
    n = mesh.n_nodes
    ops, has = [], []
    for lo, hi, coord in ((0, 1, mesh.x), (2, 3, mesh.y)):
        ok = (nb[:, lo] >= 0) & (nb[:, hi] >= 0)
        i = np.nonzero(ok)[0]
        l_, r_ = nb[i, lo], nb[i, hi]
        d1 = coord[i] - coord[l_]
        d2 = coord[r_] - coord[i]
        w = 2.0 / (d1 + d2)
        rows = np.concatenate([i, i, i])
        cols = np.concatenate([l_, i, r_])
        vals = np.concatenate([w / d1, -w / d1 - w / d2, w / d2])
        ops.append(sp.csr_matrix((vals, (rows, cols)), shape=(n, n)))
        has.append(ok)
    e = mesh.elements
    E = e.shape[0]
    area = (mesh.x[e[:, 1]] - mesh.x[e[:, 0]]) * (mesh.y[e[:, 3]] - mesh.y[e[:, 0]])
    sign = np.array([1.0, -1.0, 1.0, -1.0])
    Dxy = sp.csr_matrix(((sign[None, :] / area[:, None]).ravel(),
                         (np.repeat(np.arange(E), 4), e.ravel())), shape=(E, n))
    return ops[0], ops[1], Dxy, has[0], has[1]


def level_transition_nodes(mesh: Q4Mesh) -> np.ndarray:
    """True for nodes where second differences of the FE field are not
    meaningful: hanging nodes (the constraint makes the field linear along
    their edge), nodes with a hanging edge neighbour, and nodes whose edge
    neighbours sit at unequal distances (quadtree level transitions)."""
    def build(m):
        nb = _cached(m, "axis_neighbours", _axis_neighbours)
        n = m.n_nodes
        hang = np.zeros(n, bool)
        hang[m.hanging[:, 0]] = True
        present = nb >= 0
        nbc = np.maximum(nb, 0)
        dist = np.abs(m.x[nbc] - m.x[:, None]) + np.abs(m.y[nbc] - m.y[:, None])
        # a node without edge neighbours (in no element) has no spread: -inf
        spread = (np.where(present, dist, -np.inf).max(axis=1)
                  - np.where(present, dist, np.inf).min(axis=1))
        out = hang | (present & hang[nbc]).any(axis=1) | (spread > 0)
        return out

    return _cached(mesh, "level_transition", build)


def curvature_operator(mesh: Q4Mesh, weights: np.ndarray | None = None) -> sp.csr_matrix:
    """Thin-plate penalty ``Kᵀ K`` of a scalar nodal field: the sum over nodes of
    ``u_xx² + u_yy²`` plus, per element, ``2 u_xy²`` (1/px⁴). Zero for any
    affine field (uniform strain and rotation), so it smooths noise without
    biasing them; with weight ``ℓ⁴`` against a unit data weight per node it
    damps a displacement wave of wavenumber ``k`` by ``1/(1 + (kℓ)⁴)``.

    ``weights`` (N,), optional: a per-node weight of the node's second
    differences (an element's twist takes the mean of its corners'), the
    spatially varying ``ℓ_i⁴`` of the adaptive smoothing."""
    def build(m):
        Dxx, Dyy, Dxy, _, _ = second_difference_operators(m)
        return (Dxx.T @ Dxx + Dyy.T @ Dyy + 2.0 * (Dxy.T @ Dxy)).tocsr()

    if weights is None:
        return _cached(mesh, "curvature", build)
    Dxx, Dyy, Dxy, _, _ = second_difference_operators(mesh)
    w = sp.diags(np.asarray(weights, float))
    we = sp.diags(2.0 * np.asarray(weights, float)[mesh.elements].mean(axis=1))
    return (Dxx.T @ w @ Dxx + Dyy.T @ w @ Dyy + Dxy.T @ we @ Dxy).tocsr()


def _fill_from_inside(D: sp.csr_matrix, has: np.ndarray, nb2: np.ndarray) -> sp.csr_matrix:
    """Rows of ``D`` for nodes lacking one (``~has``) copied from their
    neighbour (-side, else +side) that has one; left zero otherwise."""
    src = np.arange(D.shape[0])
    for k in (0, 1):
        j = nb2[:, k]
        take = (~has) & (src == np.arange(D.shape[0])) & (j >= 0)
        take &= np.where(j >= 0, has[np.maximum(j, 0)], False)
        src = np.where(take, j, src)
    P = sp.csr_matrix((np.ones(src.size), (np.arange(src.size), src)), shape=(src.size,) * 2)
    return (P @ D).tocsr()


class CurvatureEstimator:
    """Nodal second derivatives of a displacement field, smoothed first.

    The field is fitted by the thin-plate smoother of length ``length``
    (pixels) at the ``data`` nodes (others, e.g. subsets cut by a hole, are
    filled in by the thin-plate interpolation), then differentiated: three-
    point second differences (nodes without neighbours on both sides along
    an axis take that derivative from the neighbour inwards) and element
    twists averaged over each node's elements. Nodes in no element and nodes
    at quadtree level transitions (:func:`level_transition_nodes`) get zeros.
    The smoothing keeps high-wavenumber noise out, so feeding the estimate
    back into the local step stays a contraction.
    """

    def __init__(self, mesh: Q4Mesh, length: float, data: np.ndarray | None = None,
                 T: sp.csr_matrix | None = None, free: np.ndarray | None = None):
        n = mesh.n_nodes
        self.T, self.free = mesh.prolongation() if T is None else (T, free)
        Dxx, Dyy, Dxy, hx, hy = second_difference_operators(mesh)
        K = mesh.reduced(curvature_operator(mesh))
        wd = np.ones(n) if data is None else np.where(data, 1.0, UNTRUSTED_WEIGHT)
        self._Wd = self.T.T @ sp.diags(wd)
        # well conditioned (length ~ step): warm-started CG beats a factor
        self._smoother = SPDSolver((mesh.reduced(sp.diags(wd)) + length**4 * K).tocsc(),
                                   "jacobi", rtol=1e-6)
        self._factor = None  # TriangularSolver of this matrix (__call__'s direct)
        nb = _cached(mesh, "axis_neighbours", _axis_neighbours)
        e = mesh.elements
        cnt = np.bincount(e.ravel(), minlength=n).astype(float)
        twist_to_nodes = sp.csr_matrix(((1.0 / np.maximum(cnt[e], 1)).ravel(),
                                        (e.ravel(), np.repeat(np.arange(e.shape[0]), 4))),
                                       shape=(n, e.shape[0]))
        self._Dxx = _fill_from_inside(Dxx, hx, nb[:, :2])
        self._Dyy = _fill_from_inside(Dyy, hy, nb[:, 2:])
        self._Dxy = twist_to_nodes @ Dxy
        self._zero = (np.bincount(e.ravel(), minlength=n) == 0) | level_transition_nodes(mesh)

    def factorise(self) -> None:
        """Build the factor that ``direct`` calls use (once; call it before
        using the estimator from several threads)."""
        if self._factor is None:
            self._factor = SPDSolver(self._smoother.A, "direct", 0.0).triangular()

    @property
    def matrix(self) -> sp.csc_matrix:
        """The smoother's SPD matrix (free nodes)."""
        return self._smoother.A

    def __call__(self, uh: np.ndarray, vh: np.ndarray, direct: bool = False,
                 solver=None) -> np.ndarray:
        """(N, 6) ``uxx, uxy, uyy, vxx, vxy, vyy`` in 1/px, (N, 6, K) for K fields (N, K);
        ``direct``: smoothed by a factor of the smoother's matrix (built once,
        :class:`~.linear_solvers.TriangularSolver`), not CG: for many columns (noise probes);
        ``solver``: an object whose ``solve(rhs, guess)`` solves with :attr:`matrix` instead."""
        if direct and solver is None:
            self.factorise()
        solve = (solver or (self._factor if direct else self._smoother)).solve
        uv = np.column_stack([uh, vh])  # the u columns, then the v columns
        sm = self.T @ solve(self._Wd @ uv, uv[self.free])
        out = np.stack([D @ s for s in np.split(sm, 2, axis=1)
                        for D in (self._Dxx, self._Dxy, self._Dyy)], axis=1)
        out[self._zero] = 0.0
        return out[:, :, 0] if np.ndim(uh) == 1 else out


class GlobalSolver:
    """Solves ``(β GᵀG + μ diag(w) + κ KᵀK) û = β Gᵀ(F - W) + μ w (u - v)`` per
    component (``KᵀK``: :func:`curvature_operator`, ``κ = curvature``).

    The matrix depends only on the mesh, β, μ and the node weights, so it is
    factorised once (SuperLU) and reused for every ADMM iteration and for
    every frame with the same mesh and weights. Meshes with more than
    ``DIRECT_MAX_UNKNOWNS`` free nodes use conjugate gradients preconditioned
    by algebraic multigrid (the hierarchy built once and reused the same
    way), warm-started from the previous solution: memory stays linear in the
    mesh size (the factor of a 500k-node mesh needs >1 GB). ``method``
    (``"auto"``, ``"direct"``, ``"amg"``, ``"jacobi"``) forces one; ``direct``
    is the former flag (True: ``"direct"``, False: ``"jacobi"``).
    ``curvature`` is ``κ``, or an (N,) array of per-node ``κ_i`` (adaptive
    smoothing, :func:`curvature_operator` weights).
    """

    def __init__(self, mesh: Q4Mesh, beta: float, mu: float, weights: np.ndarray,
                 direct: bool | None = None, curvature=0.0, method: str = "auto"):
        self.mesh = mesh
        self.beta = float(beta)
        self.mu = float(mu)
        kappa = np.asarray(curvature, float)
        self.curvature = float(kappa) if kappa.ndim == 0 else kappa
        self.Gx, self.Gy, self.covered = gradient_operator(mesh)
        self.T, self.free = mesh.prolongation()
        self.w = np.where(weights, 1.0, UNTRUSTED_WEIGHT).astype(float)
        # gradient rows of untrusted nodes are dropped (their gradient is unknown);
        # their displacement is still tied in through the neighbours' rows
        self.wg = np.asarray(weights, float)
        if direct is not None:
            method = "direct" if direct else "jacobi"
        self.system = SPDSolver(self._assemble(mesh, kappa), method, rtol=1e-7)
        self.A = self.system.A  # one copy (a 1.5 M-node matrix holds ~250 MB)
        self.method = self.system.method
        self.direct = self.method == "direct"
        self._curv = None  # (length, CurvatureEstimator) of second_gradients

    def _assemble(self, mesh: Q4Mesh, kappa: np.ndarray) -> sp.csc_matrix:
        """The system matrix on the free nodes, each temporary released as soon
        as it is summed (on large meshes they set the peak memory)."""
        Wg = sp.diags(self.wg)
        A = self.Gx.T @ Wg @ self.Gx
        A += self.Gy.T @ Wg @ self.Gy
        A *= self.beta
        A += self.mu * sp.diags(self.w)
        if kappa.ndim:
            A += curvature_operator(mesh, kappa)
        elif self.curvature > 0:
            A += self.curvature * curvature_operator(mesh)
        if self.free.size < mesh.n_nodes:  # hanging nodes: reduce to the free ones
            A = self.T.T @ A @ self.T
        return A.tocsc()

    def gradients(self, uh: np.ndarray, vh: np.ndarray) -> np.ndarray:
        """Nodal displacement gradients (N, 4): du/dx, du/dy, dv/dx, dv/dy."""
        return np.column_stack([self.Gx @ uh, self.Gy @ uh, self.Gx @ vh, self.Gy @ vh])

    def second_gradients(self, uh: np.ndarray, vh: np.ndarray, length: float,
                         data: np.ndarray | None = None) -> np.ndarray:
        """Nodal second derivatives (N, 6) of the field, from a
        :class:`CurvatureEstimator` of this mesh kept between calls (the same
        ``length`` and ``data`` mask are expected on every call)."""
        if self._curv is None or self._curv[0] != length:
            self._curv = (length, CurvatureEstimator(self.mesh, length, data, self.T, self.free))
        return self._curv[1](uh, vh)

    def rhs(self, F: np.ndarray, W: np.ndarray, u: np.ndarray, v: np.ndarray,
            vu: np.ndarray, vv: np.ndarray) -> np.ndarray:
        """Right-hand side ``Tᵀ [β Gᵀ(F - W) + μ w (u - v)]`` of the global step,
        reduced to the free nodes.

        Parameters
        ----------
        F, W : (N, 4) or (N, 4, K) nodal gradients and their scaled multipliers.
        u, v, vu, vv : (N,) or (N, K) local displacements and their scaled
            multipliers (K right-hand sides at once, one per column).

        Returns
        -------
        (n_free, 2) or (n_free, 2K): the ``u`` column(s), then the ``v`` column(s).
        """
        R = (F - W) * self.wg.reshape((-1,) + (1,) * (F.ndim - 1))
        mw = (self.mu * self.w).reshape((-1,) + (1,) * (u.ndim - 1))
        rhs_u = self.beta * (self.Gx.T @ R[:, 0] + self.Gy.T @ R[:, 1]) + mw * (u - vu)
        rhs_v = self.beta * (self.Gx.T @ R[:, 2] + self.Gy.T @ R[:, 3]) + mw * (v - vv)
        return self.T.T @ np.column_stack([rhs_u, rhs_v])

    def solve(self, F: np.ndarray, W: np.ndarray, u: np.ndarray, v: np.ndarray,
              vu: np.ndarray, vv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One global step.

        Parameters
        ----------
        F, W : (N, 4) nodal gradients and their scaled multipliers.
        u, v : (N,) local displacements; vu, vv : (N,) their scaled multipliers.
        """
        rhs = self.rhs(F, W, u, v, vu, vv)
        sol = self.system.solve(rhs, np.column_stack([u - vu, v - vv])[self.free])
        full = self.T @ sol
        return full[:, 0], full[:, 1]
