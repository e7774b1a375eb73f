"""The linear solves of the smoothing choice (:mod:`.regularise`): each trial
smoother ``S_ℓ = (Wd + ℓ⁴ KᵀK)⁻¹ Wd`` applied to the Local DIC fields, and the
undermatching bias's smoother.

Short lengths (up to ``CG_MAX_LENGTH`` node spacings) are well conditioned,
``κ ≲ 1 + 64 (ℓ/step)⁴``: Jacobi CG solves them for the correction
``S_ℓ f - f`` itself in 30-75 iterations, a fraction of a factor's cost
(``docs/method.md`` section 7.4). On a mesh that is one node lattice, lengths
from ``LATTICE_MIN_LENGTH`` node spacings are solved by CG preconditioned with
the smoother's cosine-transform symbol instead (:mod:`.lattice_pcg`, ~13
iterations at any length). Other long lengths are factorised (SuperLU, as the
global matrix). The lengths are solved side by side. Where many untrusted nodes
(weight ``UNTRUSTED_WEIGHT``: a hole, a crack) make CG stall, factors take
over; which path a length takes depends on the data only, never on thread
timing.
"""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp

from ..kernels.cg import jacobi_cg
from .global_solve import UNTRUSTED_WEIGHT, Q4Mesh, SPDSolver, curvature_operator, solver_method
from .lattice_pcg import LatticePreconditioner, lattice_of, pcg_columns
from .linear_solvers import cg_tolerances
from .threads import side_by_side

__all__ = ["trial_residuals", "CGFirst", "window_mean", "use_cg", "lattice_preconditioner",
           "SMOOTHING_THREADS",
           "CG_MAX_LENGTH", "CG_RTOL", "CG_MAX_ITER", "FILL_SIGMA", "CG_MIN_NODES",
           "LATTICE_MIN_LENGTH", "LATTICE_MAX_ITER"]

# trial smoothers solved at once, at least (more with more of the run's threads:
# the jobs are independent and each computes the same whatever runs beside it)
SMOOTHING_THREADS = 2
# trial lengths up to this many node spacings are solved by Jacobi CG (relative
# tolerance CG_RTOL on the smoother's correction; past CG_MAX_ITER iterations a
# factor instead); the off-data nodes start from the fields' window mean of
# FILL_SIGMA node spacings. CG_RTOL: on the 1024² benchmark pair 1e-5 moves a
# node's risk by at most 5e-8 px² (0.13 % of the median risk, 0.4 % of the
# node's spread between lengths; no node's length changes) and saves a fifth of
# the choice (0.37 -> 0.30 s); 1e-4 moved risks by 3 % and changed 6 nodes' lengths
CG_MAX_LENGTH = 1.0
CG_RTOL = 1e-5
CG_MAX_ITER = 200
FILL_SIGMA = 2.0
# below this many free nodes factors are cheap (their cost grows like n^1.5, CG's
# like n): measured, CG lost at 4,900 nodes (0.27 s against 0.21 s for the whole
# choice on the open-hole coupon) and won at 15,000 (0.65 s against 0.81 s)
CG_MIN_NODES = 10_000
# on a lattice mesh, lengths from this many node spacings take the cosine-
# transform preconditioner (measured at 15k nodes, two columns: 0.039 against
# Jacobi's 0.061 s at 0.97 spacing, 0.042 against 0.21 s and a factor's 0.19 s
# at 1.9; Jacobi wins below ~0.7); past LATTICE_MAX_ITER iterations, a factor
LATTICE_MIN_LENGTH = 0.9
LATTICE_MAX_ITER = 100
# the shortest lengths solved by CG in two halves: the fields at once, while the
# caller computes the late columns, then those; the others all columns at once
SPLIT_LENGTHS = 2


def use_cg(n_free: int, length: float, step: float) -> bool:
    """Whether a smoother of ``length`` (pixels) on ``n_free`` nodes spaced
    ``step`` is solved by CG (else by a factor, or AMG-CG past its size)."""
    return (solver_method(n_free) == "direct" and n_free >= CG_MIN_NODES
            and length <= CG_MAX_LENGTH * step)


def lattice_preconditioner(mesh: Q4Mesh, free: np.ndarray, length: float, step: float,
                           lattice=None) -> LatticePreconditioner | None:
    """The cosine-transform preconditioner of a smoother of ``length``
    (pixels) when it is used (:mod:`.lattice_pcg`): on a mesh of one node
    lattice (``lattice``, found when not given) of at least ``CG_MIN_NODES``
    free nodes, from ``LATTICE_MIN_LENGTH`` node spacings; else None."""
    if length < LATTICE_MIN_LENGTH * step or not use_cg(free.size, 0.0, step):
        return None
    lattice = lattice_of(mesh, free, step) if lattice is None else lattice
    return None if lattice is None else LatticePreconditioner(lattice, length, step)


def trial_residuals(mesh: Q4Mesh, fields: np.ndarray, keep, lengths, step: float,
                    late: Future | None = None, workers: int = SMOOTHING_THREADS) -> np.ndarray:
    """(N, K, M) ``S_ℓ f - f`` per node and length (NaN off ``keep``) of nodal
    ``fields`` (N, M): the thin-plate smoother fitted at the trusted nodes.
    ``late``: a future of more columns of ``fields``, waited for only once a
    smoother is ready for them (the caller computes them meanwhile);
    ``workers``: threads solving lengths side by side.

    Lengths up to ``CG_MAX_LENGTH`` node spacings (on meshes of at least
    ``CG_MIN_NODES`` free nodes, :func:`use_cg`) are solved by Jacobi CG for
    the correction ``S_ℓ f - f`` itself (:class:`_CGSmoother`), and on a
    lattice mesh the lengths from ``LATTICE_MIN_LENGTH`` spacings by CG with
    :mod:`.lattice_pcg`'s preconditioner; the others (and those whose CG
    stalls) by a factor like the global matrix's, or on meshes too large for
    a factor by AMG-CG warm-started from the previous length (4 digits
    suffice)."""
    T, free = mesh.prolongation()
    KtK = mesh.reduced(curvature_operator(mesh))
    Wd = mesh.reduced(sp.diags(np.where(keep, 1.0, UNTRUSTED_WEIGHT)))
    diag = np.maximum(Wd.diagonal(), UNTRUSTED_WEIGHT)[:, None]
    trials = [k for k, ell in enumerate(lengths) if ell != 0]
    first = np.where(keep[:, None], fields, np.nan)

    def data():  # the fields, the late columns with them, 0 off keep
        more = () if late is None else (late.result(),)
        return np.where(keep[:, None], np.column_stack([fields, *more]), 0.0)

    def factor(k, start=None):
        solver = SPDSolver((Wd + lengths[k] ** 4 * KtK).tocsc(), "auto", rtol=1e-5)
        b = T.T @ data()
        return solver.solve(b, b / diag if start is None else start)

    if solver_method(Wd.shape[0]) == "direct":
        lattice = lattice_of(mesh, free, step)
        pre = {k: lattice_preconditioner(mesh, free, lengths[k], step, lattice)
               for k in trials} if lattice is not None else {}
        spectral = [k for k in trials if pre.get(k) is not None]
        short = [k for k in trials if k not in spectral and use_cg(free.size, lengths[k], step)]
        long = [k for k in trials if k not in short + spectral]
        # CG starts from the fields, filled off the data by their window mean
        fill = np.nan_to_num(window_mean(mesh, first, step, FILL_SIGMA * step))

        def columns(which: str):  # (right-hand sides, starts) on the free nodes
            # "first": the fields, "late": the late columns, "all": both
            sets = [] if which == "late" else [(fields, fill)]
            if which != "first" and late is not None:
                sets.append((late.result(), 0.0))
            f = np.column_stack([c for c, _ in sets])
            start = np.column_stack([np.where(keep[:, None], c, off) for c, off in sets])
            return T.T @ np.where(keep[:, None], f, 0.0), start[free]

        def solve(k, A, b, x0):  # CG of length k, or None where it stalls
            return _cg_columns(A, b, x0, pre.get(k))
        by_cg = sorted(short + spectral)
        cg = _CGSmoother(Wd, KtK, lengths, columns, late is not None, factor, solve,
                         by_cg[0] if by_cg else None)
        sols = _side_by_side(cg, factor, by_cg, long, trials, workers)
    else:
        sols = []
        for k in trials:
            sols.append(factor(k, sols[-1] if sols else None))
    full = data()
    out = np.full((mesh.n_nodes, len(lengths), full.shape[1]), np.nan)
    out[keep] = 0.0
    for k, sol in zip(trials, sols):
        out[keep, k] = ((T @ sol) - full)[keep]
    return out


def _side_by_side(cg: _CGSmoother, factor, by_cg: list, long: list, trials: list,
                  workers: int) -> list:
    """The solutions of the ``trials`` lengths, ``by_cg`` by CG (``cg``) and
    ``long`` by their factors, as jobs on ``workers`` threads.

    The long lengths' factors are independent and SuperLU releases the GIL:
    side by side (each freed once its solve is done). The shortest length's
    CG goes first, on the fields alone (it tells whether CG converges here),
    with the second shortest beside it while the caller computes the late
    columns; the other lengths' CG fills the cores after the factors, longest
    first, on all columns at once (a CG pass costs about as much with four
    columns as with two: 36 against 86 ms for the 1024² pair's 0.7-spacing
    length in two halves); the late columns of the two shortest go last."""
    split = by_cg[:SPLIT_LENGTHS]
    jobs = ([("cg", k) for k in split] + [("factor", k) for k in long]
            + [("whole", k) for k in by_cg[:len(split) - 1:-1]]
            + [("late", k) for k in split])
    run = {"cg": cg.first_columns, "factor": factor, "whole": cg.whole,
           "late": cg.late_columns}
    # a job waits only on jobs listed before it: any number of workers is safe
    done = side_by_side(lambda job: run[job[0]](job[1]), jobs, workers)
    found = {k: x for (_, k), x in zip(jobs, done) if x is not None}
    return [found[k] for k in trials]


class _CGSmoother:
    """A trial smoother by CG on its correction.

    With ``x0`` the fields (filled off the data), ``(Wd + ℓ⁴ KᵀK) x = b`` is
    solved as ``x = x0 + e``, ``(Wd + ℓ⁴ KᵀK) e = b - (Wd + ℓ⁴ KᵀK) x0``: ``e`` is
    the smoother's correction, the risk's residual, so CG's relative tolerance
    applies to it, not to the field (a rigid shift of 50 px would otherwise
    need 1e-8). Short lengths are well conditioned (κ ≲ 1 + 64 (ℓ/step)⁴):
    10-70 iterations of Jacobi CG, a fraction of a factor's cost; longer ones
    on a lattice ~13 of :mod:`.lattice_pcg`'s (``solve(k, A, b, x0)`` picks
    the method of length ``k``, None where it stalls). Where CG stalls (many
    untrusted nodes make the system nearly singular there) ``factor(k)``
    solves the length instead. Whether CG converges on the ``first`` (the
    shortest) length decides for the others: past a stall there, they are
    factorised without trying (a decision that does not depend on timing).

    The first length solves its first columns (:meth:`first_columns`) and
    then its late ones (:meth:`late_columns`), the others all columns at once
    (:meth:`whole`). ``columns(which)``: ``(b, x0)`` of the first columns
    (``"first"``), with ``has_late`` of the late ones (``"late"``, waited
    for), or of all (``"all"``)."""

    def __init__(self, Wd, KtK, lengths, columns, has_late: bool, factor, solve, first):
        self.Wd, self.KtK, self.lengths, self.columns = Wd, KtK, lengths, columns
        self.has_late, self.factor, self.solve, self.first = has_late, factor, solve, first
        self._converges = Future()
        # length -> Future of its first columns by CG (None: solved whole)
        self._firsts: dict[int, Future] = {}
        # length -> its matrix, built once for its first and late columns
        self._mats: dict[int, sp.csr_matrix] = {}

    def first_columns(self, k: int) -> np.ndarray | None:
        """Length ``k``'s solution in every column (by its factor if CG stalls,
        or stalled on the first length; by CG without late columns), or None
        when its late columns are left to :meth:`late_columns`."""
        done = self._firsts.setdefault(k, Future())
        try:
            x = self._cg_first(k)
        except BaseException as exc:
            done.set_exception(exc)
            raise
        partial = x is not None and self.has_late
        done.set_result(x if partial else None)
        if x is None:
            return self.factor(k)
        return None if partial else x

    def late_columns(self, k: int) -> np.ndarray | None:
        """Length ``k``'s solution in every column, its late columns by CG after
        the first ones (by its factor if CG stalls there); None if
        :meth:`first_columns` solved it whole. Run after ``first_columns(k)``
        has started."""
        first = self._firsts[k].result()
        if first is None:
            return None
        more = self.solve(k, self._matrix(k), *self.columns("late"))
        return self.factor(k) if more is None else np.column_stack([first, more])

    def whole(self, k: int) -> np.ndarray:
        """Length ``k``'s solution in every column (the late ones waited for)
        by one CG, or by its factor where CG stalls, here or on the first
        length."""
        if not self._converges.result():
            return self.factor(k)
        x = self.solve(k, self._matrix(k), *self.columns("all"))
        return self.factor(k) if x is None else x

    def _cg_first(self, k: int) -> np.ndarray | None:
        """The first columns by CG, or None (stalled here or on the first length)."""
        if k != self.first and not self._converges.result():
            return None
        try:
            x = self.solve(k, self._matrix(k), *self.columns("first"))
        except BaseException as exc:
            if k == self.first:
                self._converges.set_exception(exc)
            raise
        if k == self.first:
            self._converges.set_result(x is not None)
        return x

    def _matrix(self, k: int) -> sp.csr_matrix:
        # first_columns(k) builds it; late_columns(k) reads it after that has
        # set its future (no two threads build one length's matrix)
        if k not in self._mats:
            self._mats[k] = (self.Wd + self.lengths[k] ** 4 * self.KtK).tocsr()
        return self._mats[k]


class CGFirst:
    """``solve(rhs, guess)`` with one SPD matrix, warm-started from the last
    solution (the first from ``start``): :func:`_cg_columns` (``precond``: a
    :class:`~.lattice_pcg.LatticePreconditioner`, else Jacobi), and once CG
    stalls a factor for this and every later solve. Each solve is taken to
    the first one's absolute tolerance at least: a warm start's first residual
    is small (the right-hand side changed little), and ``CG_RTOL`` of it would
    ask for more than the first solve delivered (the undermatching bias's
    fixed-point steps: 14, 13, 13 -> 14, 9, 7 iterations on the 1024² pair,
    no node's smoothing length changed)."""

    def __init__(self, A, start: np.ndarray, precond=None):
        self.A, self._last, self._factor, self.precond = A.tocsr(), start, None, precond
        self._atol = None  # the first solve's, per column

    def solve(self, rhs: np.ndarray, guess=None) -> np.ndarray:
        if self._atol is None:
            self._atol = cg_tolerances(rhs - self.A @ self._last, CG_RTOL)[0]
        x = (None if self._factor is not None
             else _cg_columns(self.A, rhs, self._last, self.precond, self._atol))
        if x is None:
            if self._factor is None:
                self._factor = SPDSolver(self.A.tocsc(), "direct", 0.0)
            x = self._factor.solve(rhs, None)
        self._last = x
        return x


def _cg_columns(A: sp.csr_matrix, b: np.ndarray, x0: np.ndarray, precond=None,
                atol: np.ndarray | None = None) -> np.ndarray | None:
    """``A⁻¹ b`` as ``x0`` plus a correction solved by CG to ``CG_RTOL`` of its
    right-hand side (or ``atol`` per column, where given and larger), all
    columns at once; None if a column needs more than ``CG_MAX_ITER``
    iterations. Jacobi CG (compiled), or preconditioned by ``precond``
    (:func:`~.lattice_pcg.pcg_columns`, ``LATTICE_MAX_ITER``)."""
    if precond is not None:
        return pcg_columns(A, b, x0, precond, CG_RTOL, LATTICE_MAX_ITER, atol)
    rhs = np.ascontiguousarray(b - A @ x0)
    atol = np.maximum(cg_tolerances(rhs, CG_RTOL)[0], 0.0 if atol is None else atol)
    e = np.zeros(rhs.shape)
    its = np.zeros(rhs.shape[1], np.int64)
    jacobi_cg(A.indptr, A.indices, A.data, 1.0 / A.diagonal(), rhs, e, atol, CG_MAX_ITER, its)
    return None if (its >= CG_MAX_ITER).any() else x0 + e


def window_mean(mesh: Q4Mesh, values: np.ndarray, step: float, sigma_px: float) -> np.ndarray:
    """Gaussian-weighted mean (standard deviation ``sigma_px``) of nodal
    ``values`` (N, M) around each node, ignoring NaN; NaN where the window
    holds no value. Nodes are binned on their lattice of spacing ``step``
    (quadtree nodes fall in the nearest cell), so the cost is linear in N."""
    ix = np.rint((mesh.x - mesh.x.min()) / step).astype(np.int64)
    iy = np.rint((mesh.y - mesh.y.min()) / step).astype(np.int64)
    shape = (int(iy.max()) + 1, int(ix.max()) + 1)
    cell = iy * shape[1] + ix
    s = sigma_px / step
    ok = np.isfinite(values)
    m = values.shape[1]
    # the columns binned and filtered at once (a zero sigma leaves their axis
    # alone); one count of values when they share their NaN
    same = bool((ok == ok[:, :1]).all())
    num = np.empty((m, *shape))
    den = np.empty((1 if same else m, *shape))
    for j in range(m):
        num[j].flat = np.bincount(cell[ok[:, j]], values[ok[:, j], j], minlength=num[j].size)
        if j < den.shape[0]:
            den[j].flat = np.bincount(cell[ok[:, j]], minlength=num[j].size)
    num = ndi.gaussian_filter(num, (0, s, s), mode="constant", truncate=2.5)
    den = ndi.gaussian_filter(den, (0, s, s), mode="constant", truncate=2.5)
    d = den.reshape(den.shape[0], -1)[:, cell].T
    out = num.reshape(m, -1)[:, cell].T
    return np.where(d > 1e-3, out / np.maximum(d, 1e-3), np.nan)
