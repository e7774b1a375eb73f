"""Sparse SPD linear solvers of the AL-DIC global step and of its smoothers:
a SuperLU factor (optionally in float32 with refined solves), or CG
preconditioned by algebraic multigrid or by the diagonal
(:class:`SPDSolver`, :func:`solver_method`)."""

from __future__ import annotations

import threading
from concurrent.futures import Future

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..kernels.cg import jacobi_cg, triangular_solve
from .threads import side_by_side

__all__ = ["SPDSolver", "TriangularSolver", "solver_method", "cg_tolerances",
           "DIRECT_MAX_UNKNOWNS", "SOLVER_METHODS"]

# up to this many unknowns the SuperLU factor is used: measured (RESULTS.md,
# benchmarks/bench_smoothing.py solver) it beats AMG-CG in time up to at least
# 200k unknowns, but its memory grows like n log n (~130 n log2(n) bytes:
# 250 MB at 113k, 480 MB at 200k); this bound keeps it near 600 MB
DIRECT_MAX_UNKNOWNS = 250_000
SOLVER_METHODS = ("auto", "direct", "amg", "jacobi")


def solver_method(n_unknowns: int, method: str = "auto") -> str:
    """The linear solver of an SPD system of ``n_unknowns``: ``method`` itself,
    or for ``"auto"`` a SuperLU factor up to ``DIRECT_MAX_UNKNOWNS`` and
    algebraic-multigrid-preconditioned CG above."""
    if method not in SOLVER_METHODS:
        raise ValueError(f"solver method {method!r} is not one of {', '.join(SOLVER_METHODS)}")
    if method != "auto":
        return method
    return "direct" if n_unknowns <= DIRECT_MAX_UNKNOWNS else "amg"


def _splu(A: sp.csc_matrix):
    """SuperLU factor of an SPD matrix, without pivoting (see SPDSolver)."""
    return spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options={"SymmetricMode": True})


class SPDSolver:
    """Repeated solves with one sparse SPD matrix: a SuperLU factor; or
    conjugate gradients warm-started from the previous solution (or from a
    given guess on the first call), preconditioned by a root-node AMG
    hierarchy (pyamg; built once, reused by every solve with this matrix) or
    by the diagonal (Jacobi). CG keeps memory linear in the mesh size."""

    def __init__(self, A: sp.csc_matrix, method: str, rtol: float):
        self.method = solver_method(A.shape[0], method)
        self.A = A
        self.rtol = rtol
        self._last = None
        self._lu = self._M = None
        self._triangular: Future | None = None  # TriangularSolver started ahead
        self.iterations: list[int] = []  # CG iterations of each solve (per column)
        if self.method == "direct":
            # SPD: no pivoting. The minimum-degree order of A + Aᵀ is then kept and
            # the factor stays as sparse as a Cholesky factor's pattern; partial
            # pivoting let per-node smoothing weights grow it (measured on a
            # 15k-node system with random per-node lengths: 41 M non-zeros and
            # 19 s against 2.2 M and 0.2 s)
            # (float64 only: a float32 factor of the smoothing choice's
            # well-conditioned trial smoothers fills with subnormal numbers, and
            # took 0.20 s against float64's 0.086 s at 15k nodes on an Intel Xeon)
            self._lu = _splu(A)
        elif self.method == "amg":
            import pyamg

            self.A = A = A.tocsr()  # CG and the hierarchy use rows; the CSC copy goes
            # root-node aggregation: on these thin-plate-dominated systems it
            # needs half the CG iterations of plain smoothed aggregation and a
            # fifth of its setup (benchmarks/RESULTS.md, "AL-DIC global solve")
            self._M = pyamg.rootnode_solver(self.A, symmetry="symmetric",
                                            max_coarse=500).aspreconditioner()
        else:  # Jacobi: the compiled CG of kernels/cg.py, on the rows of A
            self._csr = A.tocsr()
            self._dinv = 1.0 / A.diagonal()

    @property
    def factor_nnz(self) -> int:
        """Non-zeros of the SuperLU factor (0 for CG): its memory is ~12 bytes each."""
        return 0 if self._lu is None else int(self._lu.L.nnz + self._lu.U.nnz)

    def solve(self, rhs: np.ndarray, guess: np.ndarray) -> np.ndarray:
        if self._lu is not None:
            # all columns at once: on a quiet machine 2.5x faster than column by
            # column (32 columns of a 15k-node system: 0.04 s against 0.09 s); its
            # dense kernels are OpenBLAS's, so on a loaded one the threads' hand-over
            # can make it slower (0.55 s measured at load 4 on 2 cores)
            return self._lu.solve(np.asfortranarray(rhs))
        start = guess if self._last is None else self._last
        if self.method == "jacobi":
            self._last = self._jacobi_cg(rhs, start)
            return self._last
        sol = np.empty_like(rhs)
        for c in range(rhs.shape[1]):
            count = [0]

            def tick(_x, count=count):
                count[0] += 1

            sol[:, c], _ = spla.cg(self.A, rhs[:, c], x0=start[:, c], M=self._M,
                                   rtol=self.rtol, maxiter=5000, callback=tick)
            self.iterations.append(count[0])
        self._last = sol
        return sol

    def triangular(self) -> TriangularSolver:
        """The factor as a :class:`TriangularSolver` (a copy: the one
        :meth:`triangular_ahead` started, when it was, which this solver then
        lets go: the caller holds it only as long as it needs it)."""
        ahead, self._triangular = self._triangular, None
        if ahead is not None:
            return ahead.result()
        return TriangularSolver(self._lu)

    def triangular_ahead(self) -> None:
        """Start copying the factor out for :meth:`triangular` on a thread of
        its own (0.02-0.04 s at 15k nodes, serial): AL-DIC starts it once the
        global system is factorised, and the ADMM local step's idle tail
        absorbs it before the u_std propagation asks. The copy only reads
        the factor, as the solves do."""
        if self._lu is None or self._triangular is not None:
            return
        self._triangular = Future()
        done = self._triangular

        def copy() -> None:
            try:
                done.set_result(TriangularSolver(self._lu))
            except BaseException as exc:  # handed to triangular()'s caller
                done.set_exception(exc)
        threading.Thread(target=copy, name="factor copy", daemon=True).start()

    def _jacobi_cg(self, rhs: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Jacobi-preconditioned CG for every column (``scipy.sparse.linalg.cg``'s
        iteration with ``M = diag(A)⁻¹``, compiled and single-threaded, the
        columns sharing each pass over ``A``)."""
        A = self._csr
        b = np.ascontiguousarray(rhs, np.float64).reshape(rhs.shape[0], -1)
        x = np.array(start, np.float64, order="C").reshape(b.shape)
        # not np.linalg.norm: a 1-D norm is a BLAS dot product, which on
        # vectors this long OpenBLAS splits between threads (18 ms a call
        # measured at load 7 on 2 cores, 6 calls in a smoothing choice)
        atol, zero = cg_tolerances(b, self.rtol)
        x[:, zero] = 0.0
        its = np.zeros(b.shape[1], np.int64)
        jacobi_cg(A.indptr, A.indices, A.data, self._dinv, b, x, atol, 5000, its)
        self.iterations.extend(int(i) for i in its)
        return x.reshape(rhs.shape)


def cg_tolerances(b: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(atol, zero)`` of :func:`~..kernels.cg.jacobi_cg` for the columns of
    ``b``: ``rtol`` times each column's norm, and the columns that are zero
    (their solution is 0; an infinite tolerance stops them at once)."""
    norm = np.sqrt(np.einsum("ij,ij->j", b, b))
    zero = norm == 0
    return np.where(zero, np.inf, rtol * norm), zero


class TriangularSolver:
    """Solves with a SuperLU factor ``Pr A Pc = L U`` by the compiled
    single-threaded triangular solves of ``kernels.cg``, all columns in one
    pass. SuperLU's own multi-column solve hands its small dense blocks to
    threaded OpenBLAS; on 2 busy cores 32 columns of a 4.8k-node system took
    0.2-0.4 s there and 3 ms here (equal to rounding)."""

    def __init__(self, lu):
        self.L = _diagonal_at(lu.L.tocsc(), first=True)
        self.U = _diagonal_at(lu.U.tocsc(), first=False)
        self.perm_r, self.perm_c = lu.perm_r, lu.perm_c

    def solve(self, rhs: np.ndarray, guess: np.ndarray | None = None,
              threads: int | None = None) -> np.ndarray:
        """``A⁻¹ rhs`` for (n,) or (n, K) ``rhs`` (``guess`` unused: the
        signature of :meth:`~..dic.global_solve.SPDSolver.solve`). With 4 or
        more columns, blocks of columns are solved side by side, one per
        thread (``threads``, default Numba's; the kernel releases the GIL; each
        column's arithmetic is the same, so is the result: 0.028 -> 0.018 s
        for the 32 probe columns of a 15k-node AL-DIC system on 2 cores). A
        pass streams the whole factor, and up to ~16 columns cost about as
        much as one: callers already running side by side pass 1."""
        x = np.empty((rhs.shape[0], int(np.prod(rhs.shape[1:]))))
        x[self.perm_r] = rhs.reshape(x.shape)
        blocks = min(threads or numba.get_num_threads(), x.shape[1] // 2)
        if blocks < 2:
            self._solve(x)
        else:
            parts = [np.ascontiguousarray(p) for p in np.array_split(x, blocks, axis=1)]
            side_by_side(self._solve, parts, blocks)
            x = np.concatenate(parts, axis=1)
        return x[self.perm_c].reshape(rhs.shape)

    def _solve(self, x: np.ndarray) -> None:
        for f, lower in ((self.L, True), (self.U, False)):
            triangular_solve(f.indptr, f.indices, f.data, x, lower)


def _diagonal_at(M: sp.csc_matrix, first: bool) -> sp.csc_matrix:
    """``M`` (a square triangular factor in CSC, every diagonal entry stored)
    with each column's diagonal entry swapped into its first (``first``) or
    last slot, in place, as :func:`~..kernels.cg.triangular_solve` expects
    (SuperLU's factors come so already). Within a column every entry updates
    another row, so their order does not change the solution."""
    n = M.shape[1]
    slot = M.indptr[:-1] if first else M.indptr[1:] - 1
    if M.nnz and np.array_equal(M.indices[np.minimum(slot, M.nnz - 1)], np.arange(n)):
        return M  # already there (the cheap test: 0.02 ms against 6 ms at 15k nodes)
    cols = np.repeat(np.arange(n), np.diff(M.indptr))
    at = np.flatnonzero(M.indices == cols)
    if at.size != n:
        raise ValueError("triangular factor without a stored diagonal entry in every column")
    move = at != slot
    if move.any():
        a, b = at[move], slot[move]
        for arr in (M.indices, M.data):
            arr[a], arr[b] = arr[b], arr[a].copy()
    return M
