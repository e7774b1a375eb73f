"""One node of the local IC-GN solvers (:mod:`.icgn`, :mod:`.icgn_quadratic`).

The affine and the quadratic solver differ in their parameters, not in how
they run a node: the reference Gauss-Newton matrix is factorised once
(:func:`lu_factor`, in the work arrays of :func:`solve_buffers`) and solved
at every step (:func:`lu_solve`); a node starts the same way
(:func:`begin_node`: record the reference statistics, set aside a subset
without texture) and every step is judged by the same rule
(:func:`step_status`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import INLINE
from .gauss_newton import DIVERGED, NO_TEXTURE, NOT_CONVERGED, OK

__all__ = ["lu_factor", "lu_solve", "solve_buffers", "begin_node", "step_status"]


@nb.njit(**INLINE)
def lu_factor(M, LU, piv):
    """LU factor with partial pivoting of an ``n x n`` matrix.

    The instrumental-variable Gauss-Newton matrix ``M = sum J e^T``
    (steepest-descent images ``J`` against the exact linearisation ``e``) is
    not symmetric unless ``J = e``, so it is factorised by elimination, not
    Cholesky.

    Parameters
    ----------
    M : (n, n) float64
        Matrix (6 x 6 affine, 12 x 12 quadratic Gauss-Newton).
    LU : (n, n) float64
        Receives the factors: unit lower triangle below the diagonal, upper
        triangle on and above it.
    piv : (n,) int64
        Receives the row swapped with row ``c`` at column ``c``.

    Returns
    -------
    bool
        False if a pivot is not clearly non-zero against its column's
        diagonal entry (a subset without texture).
    """
    n = M.shape[0]
    for i in range(n):
        for j in range(n):
            LU[i, j] = M[i, j]
    for c in range(n):
        p = c
        big = abs(LU[c, c])
        for r in range(c + 1, n):
            if abs(LU[r, c]) > big:
                big = abs(LU[r, c])
                p = r
        piv[c] = p
        if big <= 1e-12 * (abs(M[c, c]) + 1e-300):
            return False
        if p != c:
            for j in range(n):
                LU[c, j], LU[p, j] = LU[p, j], LU[c, j]
        inv = 1.0 / LU[c, c]
        for r in range(c + 1, n):
            f = LU[r, c] * inv
            LU[r, c] = f
            for j in range(c + 1, n):
                LU[r, j] -= f * LU[c, j]
    return True


@nb.njit(**INLINE)
def lu_solve(LU, piv, b, x):
    """Solve ``M x = b`` with the factors of :func:`lu_factor`.

    Parameters
    ----------
    LU : (n, n) float64
        Factors from :func:`lu_factor`.
    piv : (n,) int64
        Its row swaps.
    b : (n,) float64
        Right-hand side (left unchanged).
    x : (n,) float64
        Receives the solution.
    """
    n = b.size
    for i in range(n):
        x[i] = b[i]
    for c in range(n):
        p = piv[c]
        if p != c:
            x[c], x[p] = x[p], x[c]
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= LU[i, k] * x[k]
        x[i] = s
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= LU[i, k] * x[k]
        x[i] = s / LU[i, i]


@nb.njit(**INLINE)
def solve_buffers(npar):
    """Per-task work arrays of the dense solve of a node.

    Parameters
    ----------
    npar : int
        Warp parameters (6 affine, 12 quadratic).

    Returns
    -------
    LU : (npar, npar) float64
        Receives the factors (:func:`lu_factor`).
    piv : (npar,) int64
        Receives their row swaps.
    b, dp : (npar,) float64
        Right-hand side and increment of a step.
    """
    return np.zeros((npar, npar)), np.zeros(npar, np.int64), np.empty(npar), np.empty(npar)


@nb.njit(**INLINE)
def begin_node(k, m, df2, hs, H, LU, piv, stats_out):
    """Record node ``k``'s reference statistics and factorise its matrix.

    Parameters
    ----------
    k : int
        Node index.
    m, df2 : int, float
        Subset pixels and ``sum (f - fm)^2``
        (:func:`~.subset.gather_subset`).
    hs : (float, float, float)
        ``sum gx^2, sum gx gy, sum gy^2`` of the exact gradients
        (:func:`~.subset.gather_gradients`).
    H : (npar, npar) float64
        Reference Gauss-Newton matrix ``sum J e^T``.
    LU, piv : (npar, npar) float64, (npar,) int64
        Receive the factors of ``H`` (:func:`lu_factor`).
    stats_out : (n, 5) float64
        Receives ``(m, var_f, hxx, hxy, hyy)`` in row ``k``, as
        :func:`~.subset.subset_stats` computes them.

    Returns
    -------
    status : int
        ``NOT_CONVERGED`` to start iterating, ``NO_TEXTURE`` for a flat
        subset or a singular matrix.
    zn, it : float, int
        ZNCC (NaN) and iterations (0) before the first step.
    dfn : float
        ``sqrt(df2)`` (:func:`~.gauss_newton.gn_step`).
    """
    stats_out[k, 0] = m
    stats_out[k, 1] = df2 / m
    stats_out[k, 2] = hs[0]
    stats_out[k, 3] = hs[1]
    stats_out[k, 4] = hs[2]
    if df2 <= 1e-6 * m or not lu_factor(H, LU, piv):
        return NO_TEXTURE, np.nan, 0, 0.0
    return NOT_CONVERGED, np.nan, 0, np.sqrt(df2)


@nb.njit(**INLINE)
def step_status(du, dv, span, nrm, tol):
    """Verdict on a node after one Gauss-Newton step.

    Parameters
    ----------
    du, dv : float
        Displacement moved since the node's start.
    span : int
        Subset width: a node that moved farther has diverged.
    nrm : float
        Squared norm of the step's increment (not finite: diverged).
    tol : float
        Convergence tolerance: converged when ``nrm < tol^2``.

    Returns
    -------
    int
        ``DIVERGED``, ``OK`` or ``NOT_CONVERGED`` (go on).
    """
    if abs(du) > span or abs(dv) > span or not np.isfinite(nrm):
        return DIVERGED
    if nrm < tol * tol:
        return OK
    return NOT_CONVERGED
