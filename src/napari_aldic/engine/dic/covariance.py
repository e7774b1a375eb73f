"""Per-node Gauss-Newton matrices and the standard uncertainty of subset
matches, batched in NumPy (the model of :mod:`.quality`).

* :func:`gather_matrices` -- the ``(2k, 2k)`` matrices of each node (blocks
  ``Σ a t tᵀ`` of the shape-function monomials ``t``) from its window
  moments, by table: entry ``(p, q)`` is column ``col[p, q]`` of moment array
  ``src[p, q]`` (``src < 0``: zero);
* :func:`covariance_diag` -- ``diag(2 σ² M⁻¹ (A - t E_A / 2) M⁻ᵀ)`` at the
  ``u`` and ``v`` entries of the shape-function parameters, with
  ``M = C - t E_C``. Only rows ``0`` and ``k`` of ``M⁻¹`` are needed: two
  solves with ``Mᵀ`` instead of an inverse and two matrix products. The
  nodes' four matrices are gathered :data:`CHUNK` nodes at a time, so they
  are never all held (at 4096², quadratic, that would be 1.2 GB).

This replaced a compiled kernel of the same model (issue 25, the first run):
batched LAPACK solves are as fast as it was at 15k nodes, and it cost 2.45 s
of compiling on every first run.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_SPECKLE_FRACTION", "CHUNK", "gather_matrices", "covariance_from_matrices",
           "covariance_diag"]

#: the speckle part ``M`` keeps at least this fraction of each diagonal
#: entry of ``C`` (extreme noise would otherwise make it singular)
MIN_SPECKLE_FRACTION = 0.1
#: nodes whose four matrices are gathered at once (quadratic: ~75 MB)
CHUNK = 16384


def gather_matrices(arrays, src, col, scale: float, nodes=slice(None)) -> np.ndarray:
    """Per-node matrices whose entries are window moments.

    Parameters
    ----------
    arrays : sequence of (N, F) float64
        Moments per node (several products side by side).
    src, col : (S, S) int64
        Entry ``(p, q)`` is column ``col[p, q]`` of ``arrays[src[p, q]]``;
        ``src < 0``: zero.
    scale : float
        Factor on every entry.
    nodes : slice
        The nodes wanted (default: all).

    Returns
    -------
    (n, S, S) float64
    """
    s = src.shape[0]
    rows = [np.asarray(a)[nodes] for a in arrays]
    src, col = src.ravel(), col.ravel()
    if np.all(src == 0):  # one array holds every entry: one fancy index
        out = rows[0][:, col]
    else:
        out = np.zeros((rows[0].shape[0], s * s))
        for j, a in enumerate(rows):
            pick = np.flatnonzero(src == j)
            if pick.size:
                out[:, pick] = a[:, col[pick]]
    out *= scale
    return out.reshape(-1, s, s)


def covariance_from_matrices(a, ea, c, ec, var, m) -> np.ndarray:
    """Variances of the u and v parameters of each node's subset match.

    Per node, with ``t`` the largest fraction (<= 1) of ``var E_C`` that
    leaves every diagonal entry of ``C`` at least :data:`MIN_SPECKLE_FRACTION`
    of itself, ``M = C - t var E_C`` and ``B = A - t var E_A / 2``:
    ``2 var (M⁻¹ B M⁻ᵀ)`` at entries ``(0, 0)`` and ``(k, k)``.

    Parameters
    ----------
    a, ea, c, ec : (n, 2k, 2k) float64
        ``A`` (``Σ J Jᵀ``), ``E_A`` (its noise part per unit noise variance),
        ``C`` (``Σ J ∇fᵀ``; ``A`` again when ``J`` is the plain gradient) and
        ``E_C``.
    var : (n,) float64
        Noise variance of each image per node (NaN: no estimate).
    m : (n,) float64
        Pixels of each subset; nodes with ``m <= 2k`` are left out.

    Returns
    -------
    (n, 2) float64
        The variances (px²); NaN where a node is left out, ``M`` is not
        finite or ``det M <= 0``.
    """
    n, s = a.shape[0], a.shape[1]
    var = np.asarray(var, np.float64)
    out = np.full((n, 2), np.nan)
    use = (np.asarray(m) > s) & np.isfinite(var)
    if not use.any():
        return out
    v = var
    if not use.all():  # (boolean indexing copies: only when needed)
        a, ea, c, ec, v = a[use], ea[use], c[use], ec[use], var[use]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.diagonal(c, axis1=1, axis2=2) / np.diagonal(ec, axis1=1, axis2=2) / v[:, None]
    lim = np.where(np.isfinite(r) & (r > 0), r, np.inf).min(axis=1)
    # t var, the share of the noise parts taken out (t <= 1)
    tv = (np.minimum((1.0 - MIN_SPECKLE_FRACTION) * lim, 1.0) * v)[:, None, None]
    spk = c - tv * ec  # the speckle part M
    # the reference's gradient noise is anti-correlated with its own noise at
    # the neighbouring pixels: it adds E_A / 2, not E_A
    mid = a - (0.5 * tv) * ea
    ok = np.isfinite(spk).all(axis=(1, 2))
    if not ok.all():
        spk[~ok] = np.eye(s)  # a stand-in, left out below
    spk_t = np.ascontiguousarray(np.swapaxes(spk, 1, 2))  # Mᵀ: its LU gives det M too
    sign, _ = np.linalg.slogdet(spk_t)
    ok &= sign > 0
    k = s // 2
    e = np.zeros((spk.shape[0], s, 2))
    e[:, 0, 0] = e[:, k, 1] = 1.0
    if not ok.all():
        spk_t[~ok] = np.eye(s)
    z = np.linalg.solve(spk_t, e)  # rows 0 and k of M⁻¹
    q = np.einsum("nia,nij,nja->na", z, mid, z, optimize=True)
    done = np.where(ok[:, None], 2.0 * v[:, None] * q, np.nan)
    out[use] = done
    return out


def covariance_diag(arrays, src, col, scale, var, m, chunk: int = CHUNK) -> np.ndarray:
    """:func:`covariance_from_matrices` of the matrices that the tables
    ``src, col`` (4, 2k, 2k) and factors ``scale`` (4,) gather from the moment
    ``arrays`` (:func:`gather_matrices`; ``A, E_A, C, E_C`` in that order),
    ``chunk`` nodes at a time."""
    var = np.asarray(var, np.float64)
    n = var.size
    out = np.empty((n, 2))
    for i0 in range(0, n, chunk):
        nodes = slice(i0, min(n, i0 + chunk))
        mats = [gather_matrices(arrays, src[j], col[j], float(scale[j]), nodes)
                for j in range(4)]
        out[nodes] = covariance_from_matrices(*mats, var[nodes], np.asarray(m)[nodes])
    return out
