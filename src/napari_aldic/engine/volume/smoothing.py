"""Adaptive thin-plate smoothing of AL-DVC's global step, chosen by risk.

The 3-D form of :mod:`~..dic.regularise` (see its docstring and
``docs/method.md`` section 7.3): the global step may carry a thin-plate term
``Σ_r κ_r (K û)_r²``, zero for every affine field (rigid motion, uniform
strain), that attenuates a displacement wave of wavenumber ``k`` by about
``1 / (1 + (k ℓ)^4)``. The rows of ``K`` are the second differences along x,
y and z and the ``√2``-weighted twists on the cell faces, divided by
``step²``, so that ``KᵀK`` has the lattice symbol ``16 (q_x + q_y + q_z)² /
step⁴`` (``q = sin²(θ/2)``), and ``κ = ℓ⁴``.

The length is chosen per node by Stein's unbiased risk estimate of the
smoother ``S_ℓ = (W + ℓ⁴ KᵀK)⁻¹ W`` applied to the Local DVC field,

    R_i(ℓ) = |S_ℓ u_L - u_L|_i² + 2 <S_ℓ u_L - u_L, b>_i + (2 (S_ℓ R)_ii - 1) σ_i²,

against the true field: ``σ_i²`` is the node's predicted local variance
(its ``u_std² + v_std² + w_std²``), ``R`` the correlation of neighbouring
nodes' errors (the fraction of voxels their cubic subsets share, a product of
three 1-D overlaps) whose trace term is evaluated with Fourier symbols on the
lattice, and ``b ≈ γ ∇² u`` the undermatching bias of affine subsets (``γ =
h (h+1) / 6``, the subset mean of ``dx²/2`` along each axis), estimated from
the smoothed Local field, its noise share removed. The risk of each
candidate length is averaged over a Gaussian window of one subset width
around each node and the least one taken, so fine detail in one region and
smooth noisy motion in another each get their own smoothing. The candidate
lengths and the window are 2-D's (``core.params.SMOOTH_CANDIDATES``,
``ADAPTIVE_WINDOW``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi
from scipy import sparse

from ..core.params import ADAPTIVE_WINDOW, SMOOTH_CANDIDATES
from .grid import VolumeGrid

__all__ = ["UNTRUSTED_WEIGHT", "curvature_rows", "choose_volume_smoothing", "VolumeSmoothing",
           "spd_solver"]

#: data weight of an untrusted node in AL-DVC's global step and its smoothers
#: (small: its extrapolated motion only keeps the system well posed)
UNTRUSTED_WEIGHT = 1e-2
_DIRECT_MAX = 30_000  # nodes: a sparse factor below, AMG-preconditioned CG above
_BIAS_SMOOTHING = 0.5  # length of the bias estimate's smoother, in subset half-widths
_SYMBOL_N = 48  # wavenumbers per axis of the lattice symbols
# above this many nodes (seven CG smoothers of the whole lattice would cost more
# than the ADMM) one length is chosen, on a central box of about WINDOW_NODES
ADAPTIVE_MAX_NODES = 60_000
WINDOW_NODES = 20_000


def spd_solver(A: sparse.spmatrix, rtol: float = 1e-10):
    """``solve(b)`` for a symmetric positive definite sparse ``A``: a sparse
    LU factor on small lattices, AMG-preconditioned CG (pyamg) on large ones,
    whose 3-D factors fill in too much."""
    from scipy.sparse import linalg as spla
    A = sparse.csc_matrix(A)
    if A.shape[0] <= _DIRECT_MAX:
        return spla.splu(A).solve
    import pyamg
    A = A.tocsr()
    M = pyamg.smoothed_aggregation_solver(A).aspreconditioner()

    def solve(b):
        b = np.asarray(b, float)
        cols = b.reshape(b.shape[0], -1)
        out = np.column_stack([spla.cg(A, c, M=M, rtol=rtol, maxiter=500)[0] for c in cols.T])
        return out.reshape(b.shape)
    return solve


def curvature_rows(grid: VolumeGrid, step: float):
    """``(K, P)``: the thin-plate operator (m, n) and the (m, n) averaging
    matrix that gives each row's weight from nodal ``κ`` (the mean over the
    row's 3 or 4 nodes). Rows exist only where all their nodes do."""
    idx = grid.index_volume()
    rows, cols, vals = [], [], []
    m = 0

    def add(nodes, coef):
        nonlocal m
        ok = (np.stack(nodes) >= 0).all(0)
        k = int(ok.sum())
        for a, c in zip(nodes, coef):
            rows.append(m + np.arange(k))
            cols.append(a[ok])
            vals.append(np.full(k, c / step**2))
        m += k

    def shifted(offsets):
        s = tuple(slice(o, n - span + o) for n, (o, span) in zip(idx.shape, offsets))
        return idx[s].ravel()

    for ax in range(3):  # second differences along z, y, x
        add([shifted([(o if a == ax else 0, 2 if a == ax else 0) for a in range(3)])
             for o in range(3)], (1.0, -2.0, 1.0))
    r2 = np.sqrt(2.0)
    for a, b in ((0, 1), (0, 2), (1, 2)):  # twists on the cell faces
        add([shifted([(oa if ax == a else ob if ax == b else 0,
                       1 if ax in (a, b) else 0) for ax in range(3)])
             for oa, ob in ((0, 0), (1, 0), (0, 1), (1, 1))], (r2, -r2, -r2, r2))
    if m == 0:
        empty = sparse.csr_matrix((0, grid.n))
        return empty, empty
    r, c, v = (np.concatenate(x) for x in (rows, cols, vals))
    K = sparse.csr_matrix((v, (r, c)), shape=(m, grid.n))
    counts = np.bincount(r, minlength=m).astype(float)
    P = sparse.csr_matrix((1.0 / counts[r], (r, c)), shape=(m, grid.n))
    return K, P


def _symbols(step: float, subset: int, n: int = _SYMBOL_N):
    """``(Σq, R)`` on an n³ wavenumber grid: ``q = sin²(θ/2)`` summed over the
    axes and the symbol of the subset-overlap correlation (1 at zero lag)."""
    th = 2 * np.pi * np.arange(n) / n
    q = np.sin(th / 2) ** 2
    lags = np.arange(-(subset // step) - 1, subset // step + 2)
    tri = np.clip(1.0 - np.abs(lags) * step / subset, 0.0, None)
    r1 = np.real(np.exp(1j * np.outer(th, lags)) @ tri)
    qs = q[:, None, None] + q[None, :, None] + q[None, None, :]
    return qs, r1[:, None, None] * r1[None, :, None] * r1[None, None, :]


def _thin_plate(ell: float, step: float, qs):
    return 1.0 / (1.0 + (ell / step) ** 4 * 16 * qs**2)


@dataclass
class VolumeSmoothing:
    """Outcome of :func:`choose_volume_smoothing`."""

    smooth_px: float  # the single length of least mean risk (voxels)
    node_smooth_px: np.ndarray | None  # (n,) per-node lengths, None: use smooth_px
    table: list = field(default_factory=list)  # mean risk per candidate (voxel²)
    predicted_local_noise: float = float("nan")  # rms local error, voxels


def _smooth(A_data, KtK, ell: float, rhs, start=None):
    """``(W + ℓ⁴ KᵀK)⁻¹ rhs`` column by column: Jacobi-preconditioned CG,
    warm-started from ``start`` (measured at 2,744 nodes: 0.02 s a column
    against 0.24 s for one sparse factor, whose 3-D fill-in is large; the
    risk needs four digits)."""
    from scipy.sparse import linalg as spla
    A = (A_data + ell**4 * KtK).tocsr()
    M = sparse.diags(1.0 / A.diagonal())
    start = np.zeros_like(rhs) if start is None else start
    return np.column_stack([spla.cg(A, rhs[:, c], x0=start[:, c], rtol=1e-6, M=M,
                                    maxiter=2000)[0] for c in range(rhs.shape[1])])


def _laplacian(grid: VolumeGrid, values: np.ndarray, step: float) -> np.ndarray:
    """Nodal Laplacian (n, c) from the lattice's 1-D second differences; NaN
    where a node lacks a neighbour along an axis."""
    idx = grid.index_volume()
    out = np.zeros(values.shape)
    for ax in range(3):
        lo = np.roll(idx, 1, ax)
        hi = np.roll(idx, -1, ax)
        edge = [slice(None)] * 3
        edge[ax] = 0
        lo[tuple(edge)] = -1
        edge[ax] = -1
        hi[tuple(edge)] = -1
        a, b = lo[grid.iz, grid.iy, grid.ix], hi[grid.iz, grid.iy, grid.ix]
        ok = (a >= 0) & (b >= 0)
        d = np.full(values.shape, np.nan)
        d[ok] = (values[a[ok]] - 2 * values[ok] + values[b[ok]]) / step**2
        out += d
    return out


def _window_mean(grid: VolumeGrid, values: np.ndarray, sigma_nodes: float) -> np.ndarray:
    """Gaussian-weighted mean over the lattice of nodal ``values`` (n, k),
    ignoring NaN; NaN where the window holds no value."""
    out = np.full(values.shape, np.nan)
    at = (grid.iz, grid.iy, grid.ix)
    for j in range(values.shape[1]):
        ok = np.isfinite(values[:, j])
        num = np.zeros(grid.shape)
        den = np.zeros(grid.shape)
        num[grid.iz[ok], grid.iy[ok], grid.ix[ok]] = values[ok, j]
        den[grid.iz[ok], grid.iy[ok], grid.ix[ok]] = 1.0
        num = ndi.gaussian_filter(num, sigma_nodes, mode="constant", truncate=2.5)[at]
        den = ndi.gaussian_filter(den, sigma_nodes, mode="constant", truncate=2.5)[at]
        out[:, j] = np.where(den > 1e-3, num / np.maximum(den, 1e-3), np.nan)
    return out


def _central_box(grid: VolumeGrid, size: int):
    """``(rows, sub-grid)``: the nodes of a central box of about ``size``
    lattice sites (cubic where the lattice allows)."""
    dims = np.array(grid.shape)
    side = np.minimum(dims, max(int(round(size ** (1 / 3))), 3))
    for _ in range(3):  # flat lattices: widen the other axes
        side = np.minimum(dims, np.maximum(side, int(np.sqrt(size / side.min()))))
    lo = (dims - side) // 2
    at = np.stack([grid.iz, grid.iy, grid.ix], 1)
    rows = np.flatnonzero(((at >= lo) & (at < lo + side)).all(1))
    z0, y0, x0 = lo
    (sz, sy, sx) = side
    sub = VolumeGrid(grid.xs[x0:x0 + sx], grid.ys[y0:y0 + sy], grid.zs[z0:z0 + sz],
                     grid.ix[rows] - x0, grid.iy[rows] - y0, grid.iz[rows] - z0)
    return rows, sub


def choose_volume_smoothing(grid: VolumeGrid, u: np.ndarray, trusted: np.ndarray,
                            noise_var: np.ndarray, step: float, subset: int,
                            candidates=SMOOTH_CANDIDATES, window: float = ADAPTIVE_WINDOW
                            ) -> VolumeSmoothing:
    """Per-node smoothing lengths of least estimated risk.

    Parameters
    ----------
    grid : the node lattice.
    u : (n, 3) Local displacements; trusted : (n,) nodes whose result is reliable.
    noise_var : (n,) predicted variance of each node's local displacement
        (voxel², summed over the components).
    step, subset : node spacing and subset width (voxels).
    candidates : lengths to try, in units of ``subset``.
    window : standard deviation of the risk's averaging window, in subset widths.

    Above ``ADAPTIVE_MAX_NODES`` nodes one length (``node_smooth_px`` None) is
    chosen on a central box of about ``WINDOW_NODES`` nodes, as 2-D does.
    """
    if grid.n > ADAPTIVE_MAX_NODES:
        rows, sub = _central_box(grid, WINDOW_NODES)
        one = choose_volume_smoothing(sub, u[rows], trusted[rows], noise_var[rows], step,
                                      subset, candidates, window)
        return VolumeSmoothing(one.smooth_px, None, one.table, one.predicted_local_noise)
    keep = trusted & np.isfinite(noise_var) & np.isfinite(u).all(1)
    K, _ = curvature_rows(grid, step)
    if K.shape[0] == 0 or keep.sum() < 27:
        return VolumeSmoothing(0.0, None)
    lengths = [float(c) * subset for c in candidates]
    KtK = (K.T @ K).tocsc()
    Wd = sparse.diags(np.where(keep, 1.0, UNTRUSTED_WEIGHT)).tocsc()
    data = np.where(keep[:, None], u, 0.0)
    nvar = np.where(keep, noise_var, np.nan)
    h = subset // 2
    gamma = h * (h + 1) / 6
    qs, r = _symbols(step, subset)
    # the undermatching bias b = γ ∇² u, from the field smoothed over half a subset
    ell_b = _BIAS_SMOOTHING * h
    lap = gamma * _laplacian(grid, _smooth(Wd, KtK, ell_b, data), step)
    has = np.isfinite(lap).all(1) & keep
    g = gamma * 4 * qs / step**2 * _thin_plate(ell_b, step, qs)
    risk = np.full((grid.n, len(lengths)), np.nan)
    fit = data
    for k, ell in enumerate(lengths):
        s = _thin_plate(ell, step, qs)
        fit = _smooth(Wd, KtK, ell, data, fit) if ell > 0 else data
        diff = fit - data
        cross = 2 * np.where(has, (diff * np.nan_to_num(lap)).sum(1)
                             - float(np.mean((s - 1) * (-g) * r)) * nvar, 0.0)
        risk[:, k] = (diff**2).sum(1) + cross + (2 * float(np.mean(s * r)) - 1) * nvar
    risk[~keep] = np.nan
    mean = np.nanmean(risk, axis=0)
    best = int(np.argmin(mean))
    windowed = _window_mean(grid, risk, window * subset / step)
    ok = np.isfinite(windowed).all(1)
    choice = np.full(grid.n, best)
    choice[ok] = np.argmin(windowed[ok], axis=1)
    table = [{"smooth_px": lengths[k], "risk_px2": float(mean[k])} for k in range(len(lengths))]
    return VolumeSmoothing(lengths[best], np.asarray(lengths)[choice], table,
                           float(np.sqrt(np.nanmean(nvar))))
