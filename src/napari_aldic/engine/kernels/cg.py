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

from .flags import CACHED, CALLEE

__all__ = ["jacobi_cg", "triangular_solve"]


@nb.njit(**CALLEE)
def _matvec(indptr, indices, data, x, out):
    """``out = A x`` for CSR arrays and the columns of ``x`` (n, K), row by
    row. Each column's sum runs in order in its own scalar accumulator, four
    (or two) columns per pass over the row: one column's sum is a chain of
    dependent additions, several interleave."""
    k = x.shape[1]
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
            c += 4
        if c + 2 <= k:
            a0 = a1 = 0.0
            for p in range(lo, hi):
                v = data[p]
                j = indices[p]
                a0 += v * x[j, c]
                a1 += v * x[j, c + 1]
            out[i, c], out[i, c + 1] = a0, a1
            c += 2
        if c < k:
            a0 = 0.0
            for p in range(lo, hi):
                a0 += data[p] * x[indices[p], c]
            out[i, c] = a0


@nb.njit(**CALLEE)
def _dot(a, b, c):
    """``a[:, c] · b[:, c]``, summed in order."""
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i, c] * b[i, c]
    return s


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
    _matvec(indptr, indices, data, x, r)
    for i in range(n):
        for c in range(k):
            r[i, c] = b[i, c] - r[i, c]
    z = np.empty((n, k))
    p = np.empty((n, k))
    q = np.empty((n, k))
    rho = np.empty(k)
    rho_prev = np.ones(k)
    beta = np.empty(k)
    alpha = np.empty(k)
    active = np.ones(k, np.bool_)
    for c in range(k):
        iters[c] = maxiter
    for it in range(maxiter):
        left = 0
        for c in range(k):
            if active[c] and np.sqrt(_dot(r, r, c)) < atol[c]:
                active[c] = False
                iters[c] = it
            left += active[c]
        if left == 0:
            return
        # a finished column takes no more steps (its p, q stay as they were)
        for i in range(n):
            for c in range(k):
                z[i, c] = dinv[i] * r[i, c]
        for c in range(k):
            rho[c] = _dot(r, z, c)
            beta[c] = rho[c] / rho_prev[c]  # once per column, not per element
        for i in range(n):
            for c in range(k):
                if not active[c]:
                    continue
                if it > 0:
                    p[i, c] = p[i, c] * beta[c] + z[i, c]
                else:
                    p[i, c] = z[i, c]
        _matvec(indptr, indices, data, p, q)
        for c in range(k):
            if active[c]:
                alpha[c] = rho[c] / _dot(p, q, c)
                rho_prev[c] = rho[c]
        for i in range(n):
            for c in range(k):
                if active[c]:
                    x[i, c] += alpha[c] * p[i, c]
                    r[i, c] -= alpha[c] * q[i, c]


@nb.njit(**CACHED)
def triangular_solve(indptr, indices, data, x, lower):
    """Solve ``L y = x`` (``lower``) or ``U y = x`` in place for the columns
    of ``x`` (n, K) with a sparse triangular factor in CSC arrays (a SuperLU
    factor's ``L`` or ``U``), column-oriented and in order on one thread:
    the K right-hand sides of one row sit side by side, so each factor
    entry is read once for all of them.
    """
    n, k = x.shape
    for step in range(n):
        j = step if lower else n - 1 - step
        d = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            if indices[p] == j:
                d = data[p]
        for c in range(k):
            x[j, c] /= d
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            if i != j:
                a = data[p]
                for c in range(k):
                    x[i, c] -= a * x[j, c]
