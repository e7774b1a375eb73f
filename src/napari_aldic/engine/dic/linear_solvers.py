"""Sparse SPD linear solvers of the AL-DIC global step and of its smoothers:
a SuperLU factor (optionally in float32 with refined solves), or CG
preconditioned by algebraic multigrid or by the diagonal
(:class:`SPDSolver`, :func:`solver_method`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..kernels.cg import TriangularSolver, jacobi_cg

__all__ = ["SPDSolver", "solver_method", "DIRECT_MAX_UNKNOWNS", "SOLVER_METHODS"]

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


#: iterative refinement of solves with a float32 factor (SPDSolver ``single``)
REFINE_RTOL = 1e-10
REFINE_STEPS = 4


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

    def __init__(self, A: sp.csc_matrix, method: str, rtol: float, single: bool = False):
        self.method = solver_method(A.shape[0], method)
        self.A = A
        self.rtol = rtol
        self._last = None
        self._lu = self._M = None
        self.single = False  # a float32 factor whose solves are refined (see below)
        self.iterations: list[int] = []  # CG iterations of each solve (per column)
        if self.method == "direct":
            # SPD: no pivoting. The minimum-degree order of A + Aᵀ is then kept and
            # the factor stays as sparse as a Cholesky factor's pattern; partial
            # pivoting let per-node smoothing weights grow it (measured on a
            # 15k-node system with random per-node lengths: 41 M non-zeros and
            # 19 s against 2.2 M and 0.2 s)
            self._lu = _splu(A.astype(np.float32) if single else A)
            self.single = single
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
        if self.single:
            return self._refined(rhs)
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

    def _refined(self, rhs: np.ndarray) -> np.ndarray:
        """``A⁻¹ rhs`` with the float32 factor (``single``): iterative refinement,
        the residual of each column in float64, until it is below
        ``REFINE_RTOL`` of that column's right-hand side (each step gains the
        ~5 digits of a float32 factor; measured: 2e-6, then 4e-12 on the
        smoothing choice's 15k-node systems). A system float32 cannot
        resolve (no convergence in ``REFINE_STEPS``) gets a float64 factor."""
        rhs = np.asarray(rhs, float)
        x = np.zeros_like(rhs)
        r = rhs
        tol = REFINE_RTOL * np.linalg.norm(rhs, axis=0)
        for _ in range(REFINE_STEPS):
            x += self._lu.solve(np.asfortranarray(r, np.float32)).astype(float)
            r = rhs - self.A @ x
            if np.all(np.linalg.norm(r, axis=0) <= tol):
                return x
        self._lu, self.single = _splu(self.A), False
        return self._lu.solve(np.asfortranarray(rhs))

    def triangular(self) -> TriangularSolver:
        """The factor as a :class:`~..kernels.cg.TriangularSolver` (a copy)."""
        if self.single:  # the propagation's many columns want the float64 factor
            self._lu, self.single = _splu(self.A), False
        return TriangularSolver(self._lu)

    def _jacobi_cg(self, rhs: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Jacobi-preconditioned CG per column (``scipy.sparse.linalg.cg``'s
        iteration with ``M = diag(A)⁻¹``, compiled and single-threaded)."""
        A = self._csr
        sol = np.empty(rhs.shape)
        for c in range(rhs.shape[1]):
            b = np.ascontiguousarray(rhs[:, c], np.float64)
            # not np.linalg.norm: a 1-D norm is a BLAS dot product, which on
            # vectors this long OpenBLAS splits between threads (18 ms a call
            # measured at load 7 on 2 cores, 6 calls in a smoothing choice)
            bnorm = float(np.sqrt(np.sum(b * b)))
            x = np.array(start[:, c], np.float64)
            its = 0
            if bnorm == 0:
                x[:] = 0.0
            else:
                its = jacobi_cg(A.indptr, A.indices, A.data, self._dinv, b, x,
                                self.rtol * bnorm, 5000)
            self.iterations.append(int(its))
            sol[:, c] = x
        return sol
