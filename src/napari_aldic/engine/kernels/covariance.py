"""Per-node Gauss-Newton matrices and standard uncertainty of subset matches.

The node-by-node steps of ``dic.quality``, each one parallel pass without
Python loops or stacked temporaries:

* :func:`gather_matrices` -- the ``(2k, 2k)`` matrices of each node (blocks
  ``Σ a t tᵀ`` of the shape-function monomials ``t``) from its window moments;
* :func:`mean_noise_factor` -- the variance that is left of unit white
  noise after B-spline interpolation at a match's sub-pixel position
  (linear interpolation in a tabulated curve, as ``np.interp``), averaged
  over a grid of offsets across the subset when the displacement gradient
  sweeps the subset across pixels;
* :func:`covariance_diag` -- ``diag(2 σ² M⁻¹ (A - t E_A / 2) M⁻ᵀ)`` at the
  ``u`` and ``v`` entries of the shape-function parameters, with
  ``M = C - t E_C`` (the model of ``dic.quality``). Only rows ``0`` and
  ``k`` of ``M⁻¹`` are needed: two solves with an LU factor of ``Mᵀ``
  (partial pivoting) instead of an inverse and two matrix products; its
  pivots also give the sign of ``det M``. Each node's four matrices are
  gathered from the moments as it is reached, so none is stored for all
  nodes (at 4096², quadratic, that would be 1.2 GB).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE, PARALLEL, SERIAL, SERIAL_CALLEE
from .icgn_node import lu_factor, lu_solve

__all__ = ["CHUNK", "MIN_SPECKLE_FRACTION", "gather_matrices", "mean_noise_factor",
           "covariance_diag"]

#: nodes per parallel task (work buffers are allocated once per task)
CHUNK = 256
#: the speckle part ``M`` keeps at least this fraction of each diagonal
#: entry of ``C`` (extreme noise would otherwise make it singular)
MIN_SPECKLE_FRACTION = 0.1


@nb.njit(**INLINE)
def _gather(m0, m1, src, col, scale, i, out):
    """``out[p, q]``: node ``i``'s moment ``col[p, q]`` of ``m{src[p, q]}``
    times ``scale`` (``src < 0``: zero)."""
    s = src.shape[0]
    for p in range(s):
        for q in range(s):
            k = src[p, q]
            if k == 0:
                v = m0[i, col[p, q]]
            elif k == 1:
                v = m1[i, col[p, q]]
            else:
                v = 0.0
            out[p, q] = v * scale


@nb.njit(**PARALLEL, fastmath=FASTMATH)
def gather_matrices(m0, m1, src, col, scale):
    """Per-node matrices whose entries are window moments.

    Parameters
    ----------
    m0, m1 : (N, F0), (N, F1) float64
        Moments per node (several products side by side).
    src, col : (S, S) int64
        Entry ``(p, q)`` is column ``col[p, q]`` of ``m{src[p, q]}``;
        ``src < 0``: zero.
    scale : float
        Factor on every entry.

    Returns
    -------
    (N, S, S) float64
    """
    n, s = m0.shape[0], src.shape[0]
    out = np.empty((n, s, s))
    for i in nb.prange(n):
        _gather(m0, m1, src, col, scale, i, out[i])
    return out


@nb.njit(**INLINE)
def _interp(x, t, rho):
    """``np.interp(x, t, rho)`` on a sorted table (NaN for NaN)."""
    n = t.size
    if not x == x:
        return np.nan
    if x <= t[0]:
        return rho[0]
    if x >= t[n - 1]:
        return rho[n - 1]
    # the table is evenly spaced: guess the interval, then settle it
    j = min(max(int((x - t[0]) / (t[n - 1] - t[0]) * (n - 1)), 0), n - 2)
    while j > 0 and x < t[j]:
        j -= 1
    while j < n - 2 and x >= t[j + 1]:
        j += 1
    if x == t[j]:
        return rho[j]
    slope = (rho[j + 1] - rho[j]) / (t[j + 1] - t[j])
    return slope * (x - t[j]) + rho[j]


# serial (issue 25): as fast as with threads (measured), compiles ~2x faster
@nb.njit(**SERIAL, fastmath=FASTMATH)
def mean_noise_factor(u, v, grad, half, offsets, t, rho):
    """Mean over a grid of subset offsets of the interpolated-noise factor.

    Parameters
    ----------
    u, v : (N,) float64
        Displacements (px).
    grad : (N, 4) float64
        Displacement gradient ``(du/dx, du/dy, dv/dx, dv/dy)`` (finite).
    half : (N,) float64
        Half-width of the offset grid per node (px).
    offsets : (K,) float64
        Offsets in units of ``half``; the grid is ``offsets x offsets``.
    t, rho : (T,) float64
        The 1-D factor ``rho(t)`` tabulated at fractional offsets ``t``.

    Returns
    -------
    (N,) float64
        ``mean_ij rho(frac(u_ij)) rho(frac(v_ij))``, ``u_ij = u + u_x o_i +
        u_y o_j`` (``o = offsets * half``), the same for ``v``.
    """
    n, k = u.size, offsets.size
    out = np.empty(n)
    for i in nb.prange(n):
        acc = 0.0
        for a in range(k):
            oa = offsets[a] * half[i]
            for b in range(k):
                ob = offsets[b] * half[i]
                ua = u[i] + grad[i, 0] * oa + grad[i, 1] * ob
                va = v[i] + grad[i, 2] * oa + grad[i, 3] * ob
                acc += _interp(ua % 1.0, t, rho) * _interp(va % 1.0, t, rho)
        out[i] = acc / (k * k)
    return out


@nb.njit(**INLINE)
def _noise_scale(c, ec):
    """The fraction (0-1) of the noise part ``ec`` taken out of ``c``: at
    most ``1 - MIN_SPECKLE_FRACTION`` of any diagonal entry of ``c``."""
    lim = np.inf
    for d in range(c.shape[0]):
        r = c[d, d] / ec[d, d]
        if np.isfinite(r) and r > 0 and r < lim:
            lim = r
    s = (1.0 - MIN_SPECKLE_FRACTION) * lim
    return min(s, 1.0)  # lim > 0 or inf: s is positive


@nb.njit(**INLINE)
def _lu_transposed(m, lu, piv, mt):
    """LU factor with partial pivoting of ``mᵀ`` into ``lu`` (row swaps in
    ``piv``; :func:`~.icgn_node.lu_factor`, ``mt`` a work array); True when
    the factor exists and ``det m > 0``."""
    s = m.shape[0]
    for i in range(s):
        for j in range(s):
            mt[i, j] = m[j, i]
    if not lu_factor(mt, lu, piv):
        return False
    sign = 1.0
    for c in range(s):
        if piv[c] != c:
            sign = -sign
        if lu[c, c] < 0:
            sign = -sign
    return sign > 0


@nb.njit(**INLINE)
def _row_quadratic_form(lu, piv, e, z, mid, w):
    """``zᵀ mid z`` with ``z`` row ``e`` of ``m⁻¹`` (``mᵀ z = e_e``, the
    factor of ``mᵀ`` in ``lu``, ``piv``; ``w`` a work array)."""
    w[:] = 0.0
    w[e] = 1.0
    lu_solve(lu, piv, w, z)
    s = z.size
    q = 0.0
    for i in range(s):
        row = 0.0
        for j in range(s):
            row += mid[i, j] * z[j]
        q += z[i] * row
    return q


@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
def _node_covariance(mats, var, lu, piv, z, w):
    """The u and v variances of one node from its matrices ``mats`` = ``A,
    E_A, C, E_C`` (overwritten; ``E_A`` ends as a work array; ``z, w`` work
    vectors); NaN where the speckle part is not finite
    or not positive definite."""
    a, ea, c, ec = mats[0], mats[1], mats[2], mats[3]
    s = a.shape[0]
    for p in range(s):
        for q in range(s):
            ec[p, q] *= var
            ea[p, q] *= var
    t = _noise_scale(c, ec)
    for p in range(s):
        for q in range(s):
            c[p, q] -= t * ec[p, q]  # the speckle part M
            if not np.isfinite(c[p, q]):
                return np.nan, np.nan
            # the reference's gradient noise is anti-correlated with its own
            # noise at the neighbouring pixels: it adds E_A / 2, not E_A
            a[p, q] -= 0.5 * t * ea[p, q]
    if not _lu_transposed(c, lu, piv, ea):  # E_A is no longer needed
        return np.nan, np.nan
    return (2.0 * var * _row_quadratic_form(lu, piv, 0, z, a, w),
            2.0 * var * _row_quadratic_form(lu, piv, s // 2, z, a, w))


# serial (issue 25): ~0.03 s more per 1024² run on 2 cores, 3.7 s less compiling
@nb.njit(**SERIAL, fastmath=FASTMATH)
def covariance_diag(m0, m1, src, col, scale, var_e, m):
    """Variances of the u and v parameters of each node's subset match.

    Per node, with ``t`` the largest fraction (<= 1) of ``var_e E_C`` that
    leaves every diagonal entry of ``C`` at least :data:`MIN_SPECKLE_FRACTION`
    of itself, ``M = C - t var_e E_C`` and ``B = A - t var_e E_A / 2``:
    ``2 var_e (M⁻¹ B M⁻ᵀ)`` at entries ``(0, 0)`` and ``(k, k)``.

    Parameters
    ----------
    m0, m1 : (N, F0), (N, F1) float64
        The moments the matrices are gathered from (:func:`gather_matrices`).
    src, col : (4, 2k, 2k) int64
        Gather tables of ``A`` (``Σ J Jᵀ``), ``E_A`` (its noise part per unit
        noise variance), ``C`` (``Σ J ∇fᵀ``; ``A`` again when ``J`` is the
        plain gradient) and ``E_C``.
    scale : (4,) float64
        Factor on each of the four.
    var_e : (N,) float64
        Noise variance of each image per node (NaN: no estimate).
    m : (N,) float64
        Pixels of each subset; nodes with ``m <= 2k`` are left out.

    Returns
    -------
    (N, 2) float64
        The variances (px²); NaN where a node is left out, ``M`` is not
        finite or ``det M <= 0``.
    """
    n, s = m0.shape[0], src.shape[1]
    out = np.empty((n, 2))  # (np.full would be a parallel launch of its own)
    for ch in nb.prange((n + CHUNK - 1) // CHUNK):
        mats, lu = np.empty((4, s, s)), np.empty((s, s))
        piv, z, w = np.empty(s, np.int64), np.empty(s), np.empty(s)
        for i in range(ch * CHUNK, min(n, ch * CHUNK + CHUNK)):
            var = var_e[i]
            out[i, 0] = out[i, 1] = np.nan
            if m[i] > s and np.isfinite(var):
                for j in range(4):
                    _gather(m0, m1, src[j], col[j], scale[j], i, mats[j])
                out[i, 0], out[i, 1] = _node_covariance(mats, var, lu, piv, z, w)
    return out
