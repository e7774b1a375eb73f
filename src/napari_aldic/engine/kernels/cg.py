"""Jacobi-preconditioned conjugate gradients, compiled and single-threaded.

The recurrences of ``scipy.sparse.linalg.cg`` with a diagonal
preconditioner, in one compiled loop. AL-DIC's curvature smoother solves
such systems (~75 iterations on 15k nodes) several times per run; SciPy's
loop takes a BLAS dot product three times per iteration, and on vectors of
this length OpenBLAS splits each between threads: on a busy machine the
hand-over to a descheduled thread costs more than the arithmetic. Here every
sum runs in order on one thread (the results agree with SciPy's to rounding).
The triangular solves of a SuperLU factor for many right-hand sides at once
(the AL-DIC noise propagation's probes) run the same way.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import CACHED, CALLEE, INLINE

__all__ = ["jacobi_cg", "triangular_solve"]


@nb.njit(**CALLEE)
def _matvec_dot(indptr, indices, data, x, out, xo):
    """``out = A x`` for CSR arrays and the columns of ``x`` (n, K), row by
    row, and ``xo[c] = x[:, c] · out[:, c]`` summed in row order as the rows
    are done (CG's ``p·q`` without another pass). Each column's sum runs in
    order in its own scalar accumulator, four (or two) columns per pass over
    the row: one column's sum is a chain of dependent additions, several
    interleave."""
    k = x.shape[1]
    for c in range(k):
        xo[c] = 0.0
    for i in range(out.shape[0]):
        lo, hi = indptr[i], indptr[i + 1]
        c = 0
        while c + 4 <= k:
            a0 = a1 = a2 = a3 = 0.0
            for p in range(lo, hi):
                v = data[p]
                j = indices[p]
                a0 += v * x[j, c]
                a1 += v * x[j, c + 1]
                a2 += v * x[j, c + 2]
                a3 += v * x[j, c + 3]
            out[i, c], out[i, c + 1], out[i, c + 2], out[i, c + 3] = a0, a1, a2, a3
            xo[c] += x[i, c] * a0
            xo[c + 1] += x[i, c + 1] * a1
            xo[c + 2] += x[i, c + 2] * a2
            xo[c + 3] += x[i, c + 3] * a3
            c += 4
        if c + 2 <= k:
            a0 = a1 = 0.0
            for p in range(lo, hi):
                v = data[p]
                j = indices[p]
                a0 += v * x[j, c]
                a1 += v * x[j, c + 1]
            out[i, c], out[i, c + 1] = a0, a1
            xo[c] += x[i, c] * a0
            xo[c + 1] += x[i, c + 1] * a1
            c += 2
        if c < k:
            a0 = 0.0
            for p in range(lo, hi):
                a0 += data[p] * x[indices[p], c]
            out[i, c] = a0
            xo[c] += x[i, c] * a0


@nb.njit(**INLINE)
def _advance(x, r, z, p, q, dinv, alpha, active, rr, rho):
    """One pass of CG over the vectors: ``x += alpha p``, ``r -= alpha q`` in
    the ``active`` columns, then in every column ``z = dinv r`` and the sums
    the next step needs, ``rr = r·r`` and ``rho = r·z`` (each in row order, so
    the iterates are SciPy's to rounding)."""
    n, k = r.shape
    for c in range(k):
        rr[c] = 0.0
        rho[c] = 0.0
    for i in range(n):
        for c in range(k):
            if active[c]:
                x[i, c] += alpha[c] * p[i, c]
                r[i, c] -= alpha[c] * q[i, c]
            ri = r[i, c]
            zi = dinv[i] * ri
            z[i, c] = zi
            rr[c] += ri * ri
            rho[c] += ri * zi


@nb.njit(**CACHED)
def jacobi_cg(indptr, indices, data, dinv, b, x, atol, maxiter, iters):
    """Solve ``A x = b`` by conjugate gradients preconditioned with ``dinv``,
    for each column of ``b`` independently; the columns share each pass
    over ``A`` (one matrix-vector product serves them all).

    Per column, from the start ``x`` (updated in place): residual ``r = b -
    A x``; then per iteration, until ``|r| < atol``: ``z = dinv r``, ``rho =
    r·z``, ``p = z`` (first) or ``p = beta p + z`` with ``beta = rho /
    rho_prev``; ``q = A p``, ``alpha = rho / p·q``, ``x += alpha p``, ``r -=
    alpha q`` (SciPy's ``cg``, step for step; a column's arithmetic does not
    depend on the others, so solving it alone gives the same result).

    Parameters
    ----------
    indptr, indices, data : CSR arrays of the SPD matrix ``A`` (n x n).
    dinv : (n,) float64
        Inverse diagonal of ``A`` (the preconditioner).
    b : (n, K) float64
        Right-hand sides.
    x : (n, K) float64
        Starts; the solutions on return.
    atol : (K,) float64
        Residual norm at which each column stops.
    maxiter : int
        Most iterations.
    iters : (K,) int64
        On return, the iterations each column ran (``maxiter``: not converged).
    """
    n, k = b.shape
    r = np.empty((n, k))
    pq = np.empty(k)
    _matvec_dot(indptr, indices, data, x, r, pq)  # r = A x (one kernel: compile time)
    z = np.empty((n, k))
    p = np.empty((n, k))
    q = np.empty((n, k))
    rr = np.zeros(k)  # r·r, the stopping test
    rho = np.zeros(k)  # r·z
    rho_prev = np.ones(k)
    beta = np.empty(k)
    alpha = np.empty(k)
    active = np.ones(k, np.bool_)
    for i in range(n):
        for c in range(k):
            r[i, c] = b[i, c] - r[i, c]
    _advance(x, r, z, p, q, dinv, alpha, np.zeros(k, np.bool_), rr, rho)
    for c in range(k):
        iters[c] = maxiter
    for it in range(maxiter):
        left = 0
        for c in range(k):
            if active[c] and np.sqrt(rr[c]) < atol[c]:
                active[c] = False
                iters[c] = it
            left += active[c]
        if left == 0:
            return
        for c in range(k):
            beta[c] = rho[c] / rho_prev[c]  # once per column, not per element
        # a finished column takes no more steps (its p, q stay as they were)
        for i in range(n):
            for c in range(k):
                if not active[c]:
                    continue
                if it > 0:
                    p[i, c] = p[i, c] * beta[c] + z[i, c]
                else:
                    p[i, c] = z[i, c]
        _matvec_dot(indptr, indices, data, p, q, pq)
        for c in range(k):
            if active[c]:
                alpha[c] = rho[c] / pq[c]
                rho_prev[c] = rho[c]
        _advance(x, r, z, p, q, dinv, alpha, active, rr, rho)


@nb.njit(**CACHED)
def triangular_solve(indptr, indices, data, x, lower):
    """Solve ``L y = x`` (``lower``) or ``U y = x`` in place for the columns
    of ``x`` (n, K) with a sparse triangular factor in CSC arrays whose
    diagonal entry is each column's first (``L``) or last (``U``) one (a
    SuperLU factor's, :class:`~..dic.linear_solvers.TriangularSolver` puts
    it there), column-oriented and in order on one thread: the K
    right-hand sides of one row sit side by side, so each factor entry is
    read once for all of them. The solved row is held apart while the
    column's entries update the rows below (above) it: ``x[i]`` and
    ``x[j]`` may alias as far as the compiler knows, which kept it
    re-reading ``x[j]`` after every update.
    """
    n, k = x.shape
    xj = np.empty(k)
    for step in range(n):
        j = step if lower else n - 1 - step
        if lower:
            diag, lo, hi = indptr[j], indptr[j] + 1, indptr[j + 1]
        else:
            diag, lo, hi = indptr[j + 1] - 1, indptr[j], indptr[j + 1] - 1
        d = data[diag]
        for c in range(k):
            xj[c] = x[j, c] / d
            x[j, c] = xj[c]
        for p in range(lo, hi):
            i = indices[p]
            a = data[p]
            for c in range(k):
                x[i, c] -= a * xj[c]
