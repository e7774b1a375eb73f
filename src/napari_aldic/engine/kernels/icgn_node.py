"""One node of the local IC-GN solvers (:mod:`.icgn`, :mod:`.icgn_quadratic`).

The affine and the quadratic solver differ in their parameters, not in how
they run a node: the reference Hessian is factorised once
(:func:`cholesky`, in the work arrays of :func:`solve_buffers`) and solved at
every step (:func:`chol_solve`); a node starts the same way
(:func:`begin_node`: record the reference statistics, set aside a subset
without texture) and every step is judged by the same rule
(:func:`step_status`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import INLINE
from .gauss_newton import DIVERGED, NO_TEXTURE, NOT_CONVERGED, OK

__all__ = ["cholesky", "chol_solve", "solve_buffers", "begin_node", "step_status"]


@nb.njit(**INLINE)
def cholesky(H, L):
    """In-place lower Cholesky factor of a symmetric ``n x n`` matrix.

    Parameters
    ----------
    H : (n, n) float64
        Symmetric matrix (6 x 6 affine, 12 x 12 quadratic Gauss-Newton).
    L : (n, n) float64
        Receives the factor (lower triangle).

    Returns
    -------
    bool
        False if a pivot is not clearly positive (``H`` not positive
        definite to working precision: a subset without texture).
    """
    for i in range(H.shape[0]):
        for j in range(i + 1):
            s = H[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 1e-12 * (abs(H[i, i]) + 1e-300):
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@nb.njit(**INLINE)
def chol_solve(L, b, x):
    """Solve ``L L^T x = b`` by forward and back substitution.

    Parameters
    ----------
    L : (n, n) float64
        Factor from :func:`cholesky`.
    b : (n,) float64
        Right-hand side.
    x : (n,) float64
        Receives the solution.
    """
    n = b.size
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@nb.njit(**INLINE)
def solve_buffers(npar):
    """Per-task work arrays of the dense solve of a node.

    Parameters
    ----------
    npar : int
        Warp parameters (6 affine, 12 quadratic).

    Returns
    -------
    L : (npar, npar) float64
        Zeros; receives the Cholesky factor (its upper triangle stays zero).
    b, dp : (npar,) float64
        Right-hand side and increment of a step.
    """
    return np.zeros((npar, npar)), np.empty(npar), np.empty(npar)


@nb.njit(**INLINE)
def begin_node(k, m, df2, H, L, stats_out):
    """Record node ``k``'s reference statistics and factorise its Hessian.

    Parameters
    ----------
    k : int
        Node index.
    m, df2 : int, float
        Subset pixels and ``sum (f - fm)^2``
        (:func:`~.subset.gather_subset`).
    H : (npar, npar) float64
        Reference Hessian; parameters 0 and 3 are ``u`` and ``v``, so
        ``H[0, 0], H[3, 0], H[3, 3]`` are ``sum gx^2, sum gx gy, sum gy^2``.
    L : (npar, npar) float64
        Receives the Cholesky factor of ``H``.
    stats_out : (n, 5) float64
        Receives ``(m, var_f, hxx, hxy, hyy)`` in row ``k``, as
        :func:`~.subset.subset_stats` computes them.

    Returns
    -------
    status : int
        ``NOT_CONVERGED`` to start iterating, ``NO_TEXTURE`` for a flat
        subset or a Hessian that is not positive definite.
    zn, it : float, int
        ZNCC (NaN) and iterations (0) before the first step.
    dfn : float
        ``sqrt(df2)`` (:func:`~.gauss_newton.gn_step`).
    """
    stats_out[k, 0] = m
    stats_out[k, 1] = df2 / m
    stats_out[k, 2] = H[0, 0]
    stats_out[k, 3] = H[3, 0]
    stats_out[k, 4] = H[3, 3]
    if df2 <= 1e-6 * m or not cholesky(H, L):
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
