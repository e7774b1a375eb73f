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
    """``out = A x`` for CSR arrays, row by row."""
    for i in range(out.size):
        s = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            s += data[p] * x[indices[p]]
        out[i] = s


@nb.njit(**CALLEE)
def _dot(a, b):
    """``a · b``, summed in order."""
    s = 0.0
    for i in range(a.size):
        s += a[i] * b[i]
    return s


@nb.njit(**CACHED)
def jacobi_cg(indptr, indices, data, dinv, b, x, atol, maxiter):
    """Solve ``A x = b`` by conjugate gradients preconditioned with ``dinv``.

    From the start ``x`` (updated in place): residual ``r = b - A x`` (``b``
    itself when ``x`` is zero); then per iteration, until ``|r| < atol``:
    ``z = dinv r``, ``rho = r·z``, ``p = z`` (first) or ``p = beta p + z``
    with ``beta = rho / rho_prev``; ``q = A p``, ``alpha = rho / p·q``,
    ``x += alpha p``, ``r -= alpha q`` (SciPy's ``cg``, step for step).

    Parameters
    ----------
    indptr, indices, data : CSR arrays of the SPD matrix ``A`` (n x n).
    dinv : (n,) float64
        Inverse diagonal of ``A`` (the preconditioner).
    b : (n,) float64
        Right-hand side.
    x : (n,) float64
        Start; the solution on return.
    atol : float
        Residual norm at which to stop.
    maxiter : int
        Most iterations.

    Returns
    -------
    int
        Iterations run.
    """
    n = b.size
    r = np.empty(n)
    if np.any(x != 0.0):
        _matvec(indptr, indices, data, x, r)
        for i in range(n):
            r[i] = b[i] - r[i]
    else:  # element by element: an array copy's shape check compiles for 1.7 s
        for i in range(n):
            r[i] = b[i]
    z = np.empty(n)
    p = np.empty(n)
    q = np.empty(n)
    rho_prev = 1.0
    for it in range(maxiter):
        if np.sqrt(_dot(r, r)) < atol:
            return it
        for i in range(n):
            z[i] = dinv[i] * r[i]
        rho = _dot(r, z)
        if it > 0:
            beta = rho / rho_prev
            for i in range(n):
                p[i] = p[i] * beta + z[i]
        else:
            for i in range(n):
                p[i] = z[i]
        _matvec(indptr, indices, data, p, q)
        alpha = rho / _dot(p, q)
        for i in range(n):
            x[i] += alpha * p[i]
            r[i] -= alpha * q[i]
        rho_prev = rho
    return maxiter


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
