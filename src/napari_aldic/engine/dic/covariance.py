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
  are never all held (at 4096², quadratic, that would be 1.2 GB), and laid
  out node-last: the elimination runs one step for all nodes at once over
  contiguous vectors (1024², 15k nodes: 30-50 ms against 85-105 ms with
  NumPy's batched LAPACK ``solve`` and ``slogdet``, a call per matrix);
* :func:`mean_noise_factor` -- the variance that is left of unit white noise
  after B-spline interpolation at a match's sub-pixel position, averaged over
  a grid of offsets across the subset.

These replaced compiled kernels of the same models (issue 25, the first run):
the kernels cost 2.45 s (covariance), 0.75 s (matrix gathering, AL-DIC) and
0.78 s (noise factor, now ~2 ms slower per 15k nodes) of compiling on every
first run.
"""

from __future__ import annotations

import numba
import numpy as np

from .threads import side_by_side

__all__ = ["MIN_SPECKLE_FRACTION", "CHUNK", "gather_matrices", "covariance_from_matrices",
           "covariance_diag", "mean_noise_factor"]

#: the speckle part ``M`` keeps at least this fraction of each diagonal
#: entry of ``C`` (extreme noise would otherwise make it singular)
MIN_SPECKLE_FRACTION = 0.1
#: nodes whose four matrices are gathered at once (quadratic: ~75 MB)
CHUNK = 16384
# from this many nodes on, the chunks run side by side, one per thread
PARALLEL_NODES = 2048


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
    # one gather: the node-last one, transposed
    return np.ascontiguousarray(_gather_node_last(arrays, src, col, scale, nodes)
                                .transpose(2, 0, 1))


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
    return _variances(*(np.asarray(x, np.float64).transpose(1, 2, 0) for x in (a, ea, c, ec)),
                      var, m)


def _variances(a, ea, c, ec, var, m) -> np.ndarray:
    """:func:`covariance_from_matrices` of node-last matrices (2k, 2k, n).

    Every step is a NumPy operation over contiguous vectors of the nodes
    (the matrices are small: a batched LAPACK call per matrix costs 3x as
    much at 15k nodes of 6 x 6); nodes left out are computed alongside and
    masked, which is cheaper than copying the others out."""
    s, n = a.shape[0], a.shape[2]
    var = np.asarray(var, np.float64)
    out = np.full((n, 2), np.nan)
    use = (np.asarray(m) > s) & np.isfinite(var)
    if not use.any():
        return out
    diag = np.arange(s)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = c[diag, diag] / ec[diag, diag] / var
        lim = np.where(np.isfinite(r) & (r > 0), r, np.inf).min(axis=0)
        # t var, the share of the noise parts taken out (t <= 1)
        tv = np.minimum((1.0 - MIN_SPECKLE_FRACTION) * lim, 1.0) * var
        spk = c - tv * ec  # the speckle part M
        # the reference's gradient noise is anti-correlated with its own noise
        # at the neighbouring pixels: it adds E_A / 2, not E_A
        mid = a - (0.5 * tv) * ea
    ok = use & np.isfinite(spk).all(axis=(0, 1))
    if not ok.all():
        spk[:, :, ~ok] = np.eye(s)[:, :, None]  # a stand-in, left out below
    k = s // 2
    e = np.zeros((s, 2, n))
    e[0, 0] = e[k, 1] = 1.0
    # rows 0 and k of M⁻¹ (Mᵀ z = e; det Mᵀ = det M)
    z, positive = _solve_batched(spk.transpose(1, 0, 2), e)
    ok &= positive
    q = np.einsum("ian,ian->an", z, np.einsum("ijn,jan->ian", mid, z))
    with np.errstate(invalid="ignore", over="ignore"):
        out[ok] = (2.0 * var * q).T[ok]
    return out


def _solve_batched(mats: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``M x = b`` for many small matrices at once, laid out node-last.

    Gaussian elimination with partial pivoting (LAPACK's pivots), a step at a
    time for all nodes over contiguous vectors: at 15k nodes of 6 x 6 it
    takes a third of the time of NumPy's batched ``solve`` and ``slogdet``,
    which pay a LAPACK call per matrix.

    Parameters
    ----------
    mats : (s, s, n) float64
        ``M`` of each node (last axis); not modified.
    rhs : (s, r, n) float64
        ``r`` right-hand sides per node; not modified.

    Returns
    -------
    x : (s, r, n) float64
        The solutions (not finite where ``M`` is singular or not finite).
    positive : (n,) bool
        ``det M > 0`` (False where a pivot is zero or not finite).
    """
    s, n = mats.shape[0], mats.shape[2]
    a = np.array(mats, np.float64)
    b = np.array(rhs, np.float64)
    sign = np.ones(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        for j in range(s):
            p = j + np.argmax(np.abs(a[j:, j]), axis=0)
            moved = np.flatnonzero(p != j)
            if moved.size:  # swap rows j and p of those nodes: the sign flips
                pj = p[moved]
                for x in (a, b):
                    keep = x[j, :, moved].copy()
                    x[j, :, moved] = x[pj, :, moved]
                    x[pj, :, moved] = keep
                sign[moved] *= -1.0
            piv = a[j, j]
            sign *= np.sign(piv)
            low = a[j + 1:, j] / piv
            a[j + 1:, j + 1:] -= low[:, None] * a[j, None, j + 1:]
            b[j + 1:] -= low[:, None] * b[j, None]
        for i in range(s - 1, -1, -1):
            for jj in range(i + 1, s):
                b[i] -= a[i, jj] * b[jj]
            b[i] /= a[i, i]
    return b, sign > 0


def _gather_node_last(arrays, src, col, scale: float, nodes: slice) -> np.ndarray:
    """:func:`gather_matrices` laid out node-last, (S, S, n): each entry a
    contiguous row of the transposed moment arrays."""
    s = src.shape[0]
    src, col = src.ravel(), col.ravel()
    out = np.zeros((s * s, np.asarray(arrays[0])[nodes].shape[0]))  # src < 0: zero
    for j, arr in enumerate(arrays):
        pick = np.flatnonzero(src == j)
        if pick.size:
            out[pick] = np.asarray(arr)[nodes][:, col[pick]].T
    out *= scale
    return out.reshape(s, s, -1)


def covariance_diag(arrays, src, col, scale, var, m, chunk: int = CHUNK) -> np.ndarray:
    """:func:`covariance_from_matrices` of the matrices that the tables
    ``src, col`` (4, 2k, 2k) and factors ``scale`` (4,) gather from the moment
    ``arrays`` (:func:`gather_matrices`; ``A, E_A, C, E_C`` in that order),
    ``chunk`` nodes at a time."""
    var = np.asarray(var, np.float64)
    n = var.size
    out = np.empty((n, 2))

    def one(nodes):
        mats = [_gather_node_last(arrays, src[j], col[j], float(scale[j]), nodes)
                for j in range(4)]
        out[nodes] = _variances(*mats, var[nodes], np.asarray(m)[nodes])
    side_by_side(one, _node_slices(n, chunk))
    return out


def _node_slices(n: int, chunk: int) -> list[slice]:
    """Slices of at most ``chunk`` of ``n`` nodes, at least one per thread
    (``numba.get_num_threads()``) once there are ``PARALLEL_NODES``: chunks
    of NumPy work that run side by side (``threads.side_by_side``; NumPy
    releases the GIL on arrays this long), each node's result the same."""
    parts = max(-(-n // chunk), min(numba.get_num_threads(), n // PARALLEL_NODES), 1)
    edges = np.linspace(0, n, parts + 1).astype(np.int64)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def mean_noise_factor(u, v, grad, half, offsets, t, rho, chunk: int = CHUNK) -> np.ndarray:
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
        The 1-D factor ``rho(t)`` tabulated at evenly spaced fractional
        offsets ``t`` from 0 to 1, interpolated linearly (as ``np.interp``).
    chunk : int
        Nodes evaluated at once (``chunk * K²`` values are held).

    Returns
    -------
    (N,) float64
        ``mean_ij rho(frac(u_ij)) rho(frac(v_ij))``, ``u_ij = u + u_x o_i +
        u_y o_j`` (``o = offsets * half``), the same for ``v``; NaN where a
        ``u_ij`` or ``v_ij`` is not finite.
    """
    u, v, half = (np.asarray(a, np.float64) for a in (u, v, half))
    grad = np.asarray(grad, np.float64)
    offsets = np.asarray(offsets, np.float64)
    t, rho = np.asarray(t, np.float64), np.asarray(rho, np.float64)
    # the table is evenly spaced: the interval is an index, not a search;
    # frac = 1 (rounding of a tiny negative) reads the last entry, slope 0
    scale = (t.size - 1) / (t[-1] - t[0])
    slope = np.append(np.diff(rho), 0.0)
    oa = np.repeat(offsets, offsets.size)  # the grid, flattened
    ob = np.tile(offsets, offsets.size)

    def factor(x):  # rho(frac(x)), in place of x; NaN rows read entry 0, marked after
        bad = ~np.isfinite(x).all(axis=1)
        x[bad] = 0.0
        x -= np.floor(x)
        x *= scale
        j = x.astype(np.intp)
        x -= j
        out = rho[j] + slope[j] * x
        out[bad] = np.nan
        return out

    out = np.empty(u.size)

    def one(s):
        a, b = oa * half[s, None], ob * half[s, None]
        g = grad[s]
        x = u[s, None] + g[:, 0:1] * a + g[:, 1:2] * b
        y = v[s, None] + g[:, 2:3] * a + g[:, 3:4] * b
        out[s] = np.einsum("ij,ij->i", factor(x), factor(y)) / oa.size
    side_by_side(one, _node_slices(u.size, chunk))
    return out
