"""Automatic strength of the AL-DIC regularisation.

Overlapping subsets make the errors of neighbouring Local DIC nodes strongly
correlated (31 px subsets every 8 px share ~75 % of their pixels), so the
compatibility constraints of Algorithm 1 alone cannot average noise away. The
global step therefore may carry a thin-plate term ``κ ‖K û‖²`` (squared second
differences and element twists of ``û``,
:func:`~napari_aldic.engine.global_solve.curvature_operator`). It is zero for
any affine field, so uniform strain and rigid motion are never biased; a
displacement wave of wavenumber ``k`` is attenuated by about
``1 / (1 + (k ℓ)^4)``, where ``ℓ`` (pixels) is the *smoothing length*.

``ℓ`` is chosen per image pair by minimising Stein's unbiased risk estimate
(SURE) of the linear smoother ``S_ℓ`` applied to the Local DIC field ``u_L``:

    R(ℓ) = ‖S_ℓ u_L - u_L‖² + 2 tr(S_ℓ Σ) - tr(Σ),

an unbiased estimate of ``E ‖S_ℓ u_L - E u_L‖²`` for any noise covariance
``Σ`` (C. M. Stein, Ann. Stat. 9, 1981). ``Σ`` is modelled from the images:

* variance per node: ``2 σ_e² S⁻¹ H S⁻¹`` (noise in both images; ``H`` the
  2x2 Gauss-Newton matrix of the subset, ``S`` its speckle part), with the
  image noise ``σ_e²`` estimated from the node's own ZNCC,
  ``σ_e² ≈ (1 - ZNCC) Σ(f - f̄)² / m``;
* correlation between two nodes: the fraction of pixels their subsets share
  (the product of the 1-D overlaps ``max(0, 1 - |Δ|/subset)``).

The trace is evaluated with the Fourier symbols of ``S_ℓ`` and of the overlap
correlation on the node lattice. When the second-order warp is allowed, each
length is also scored with the warp: its deconvolution of the subset average
removes the undermatching bias (estimated here) but amplifies noise (a
larger trace term); the cheaper risk wins. Noise-free images get ``ℓ ≈ 0``;
noisy images of smooth fields the smoothing that minimises the estimated
error; fields with fine detail (crack tips, holes) raise the residual term
and so get less smoothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .global_solve import (
    CurvatureEstimator,
    Q4Mesh,
    curvature_operator,
    level_transition_nodes,
    second_difference_operators,
)
from .reliability import displacement_variance, subset_statistics

__all__ = ["displacement_noise", "choose_smoothing", "SmoothingChoice", "curvature_noise_gains",
           "shrink_curvature", "SMOOTH_CANDIDATES"]

# candidate smoothing lengths, in units of the subset width (ratio ~sqrt 2):
# the local errors are correlated over about one subset width. At most half
# a subset: the field keeps (about) the spatial resolution of the subsets,
# and even a perfectly smooth field gains little beyond that.
SMOOTH_CANDIDATES = (0.0, 0.09, 0.125, 0.18, 0.25, 0.35, 0.5)
# larger meshes: the risk is estimated on a central window of this many nodes
# (a mean over thousands of nodes; keeps the trial factorisations cheap)
_SELECT_MAX_NODES = 3_000


def gradient_noise_gain(order: int) -> float:
    """Variance of the spline derivative of unit white noise at the pixel
    centres (:func:`~napari_aldic.engine.interpolation.reference_gradients`)."""
    w = np.linspace(0, np.pi, 4097)
    if order == 3:
        d = 6 * np.sin(w) / (4 + 2 * np.cos(w))
    else:
        d = (100 * np.sin(w) + 10 * np.sin(2 * w)) / (66 + 52 * np.cos(w) + 2 * np.cos(2 * w))
    return float(np.mean(d**2))


def displacement_noise(f, fgx, fgy, nodes_x, nodes_y, slot, masks, half: int,
                       zncc: np.ndarray, order: int = 3) -> np.ndarray:
    """Predicted noise variance (px²) of the local displacement at each node.

    Returns
    -------
    (n, 2) float64
        Variances of ``u`` and ``v``; NaN where the node has no usable subset
        or no ZNCC.
    """
    stats = subset_statistics(f, fgx, fgy, nodes_x, nodes_y, slot, masks, half)
    var_e = np.where(np.isfinite(zncc), (1.0 - zncc) * stats.var_f, np.nan)
    return displacement_variance(stats, var_e, gradient_noise_gain(order))


def _lattice_trace_factor(ell: float, step: float, subset: int, n: int = 256) -> float:
    """``(S_ℓ R)_ii`` on an infinite lattice: the mean over wavenumbers of the
    smoother's symbol times the subset-overlap correlation's symbol."""
    qx, qy, r = _lattice_symbols(step, subset, n)
    return float(np.mean(_thin_plate_symbol(ell, step, qx, qy) * r))


def _thin_plate_symbol(ell, step, qx, qy):
    # K^T K has the symbol 16 (sin²(θx/2) + sin²(θy/2))² / step⁴
    return 1.0 / (1.0 + (ell / step) ** 4 * 16 * (qx + qy) ** 2)


def _lattice_noise_factor(ell: float, step: float, subset: int,
                          curv_length: float | None = None, n: int = 256) -> float:
    """Noise part of the risk per unit local variance, so that
    ``risk = (‖S_ℓ u_L - u_L‖² + factor · tr Σ) / n``.

    Without the second-order warp the estimator is ``S = S_ℓ`` and the factor
    is SURE's ``2 (S R)_ii - 1``. With it (``curv_length`` given) the fixed
    point is ``H u_L`` with ``H = S / (1 - S g)``: the curvature correction
    feeds ``g = γ (-∇²) S_c`` of the global field back into the local
    displacements (``γ = h(h+1)/6``, the subset mean of ``dx²/2``). That
    deconvolves the subset average (restoring the signal, so the signal error
    stays that of ``S``, estimated by ``‖S u_L - u_L‖² - tr((S-1)Σ(S-1))``)
    but amplifies noise: ``tr(H Σ H)``. Factor ``(H² R)_ii - ((S-1)² R)_ii``;
    both reduce to SURE when ``g = 0``."""
    qx, qy, r = _lattice_symbols(step, subset, n)
    s = _thin_plate_symbol(ell, step, qx, qy)
    H = s
    if curv_length is not None:
        H = s / (1 - s * _feedback_symbol(step, subset, curv_length, qx, qy))
    return float(np.mean(H * H * r) - np.mean((s - 1) ** 2 * r))


def _subset_gamma(subset: int) -> float:
    """``γ = h(h+1)/6``: the subset mean of ``dx²/2`` (pixel offsets -h..h), the
    centre shift a curvature of 1/px causes in an affine subset fit."""
    h = subset // 2
    return h * (h + 1) / 6


def _feedback_symbol(step, subset, curv_length, qx, qy):
    """Symbol of ``g = γ (-∇²) S_c``: the second-order warp's correction of the
    local displacement per unit global field (curvature smoothed over
    ``curv_length``)."""
    return (_subset_gamma(subset) * 4 * (qx + qy) / step**2
            * _thin_plate_symbol(curv_length, step, qx, qy))


def _lattice_symbols(step: float, subset: int, n: int = 256):
    """``(q_x, q_y, R)`` on an n x n wavenumber grid: ``q = sin²(θ/2)`` and the
    symbol of the subset-overlap correlation (1 at zero lag)."""
    th = 2 * np.pi * np.arange(n) / n
    q = np.sin(th / 2) ** 2
    qx, qy = np.meshgrid(q, q, indexing="ij")
    lags = np.arange(-(subset // step) - 1, subset // step + 2)
    tri = np.clip(1.0 - np.abs(lags) * step / subset, 0.0, None)
    r1 = np.real(np.exp(1j * np.outer(th, lags)) @ tri)
    return qx, qy, np.outer(r1, r1)


def curvature_noise_gains(smooth: float, curv_length: float, step: float,
                          subset: int) -> tuple[float, float]:
    """Noise variance of the second-order warp's curvature estimate, per unit
    variance of the local displacement: ``(g_xx, g_xy)`` (1/px⁴) for the
    second differences and the node-averaged twists of the field smoothed by
    the global step (length ``smooth``) and by the curvature smoother
    (``curv_length``), with subset-overlap-correlated local noise."""
    qx, qy, r = _lattice_symbols(step, subset)
    filt = (_thin_plate_symbol(smooth, step, qx, qy)
            * _thin_plate_symbol(curv_length, step, qx, qy))
    dxx2 = (4 * qx / step**2) ** 2
    dxy2 = 16 * qx * qy * (1 - qx) * (1 - qy) / step**4
    return float(np.mean(dxx2 * filt**2 * r)), float(np.mean(dxy2 * filt**2 * r))


def shrink_curvature(curv: np.ndarray, noise_var: np.ndarray, gains) -> np.ndarray:
    """Scale each curvature component by ``c² / (c² + var_c)`` (a Wiener-type
    shrinkage): the second-order warp is applied where the curvature stands
    out of its own noise, and fades where it does not (uniform-strain regions
    of noisy images), so it corrects bias without feeding noise back.

    ``curv`` (N, 6) ``uxx, uxy, uyy, vxx, vxy, vyy``; ``noise_var`` (N, 2)
    local displacement variances (NaN: the median is used)."""
    var = np.array(noise_var, dtype=float)
    for c in range(2):
        bad = ~np.isfinite(var[:, c])
        var[bad, c] = np.nanmedian(var[:, c]) if (~bad).any() else 0.0
    g_xx, g_xy = gains
    vc = np.empty_like(curv)
    for c in range(2):
        vc[:, 3 * c] = var[:, c] * g_xx
        vc[:, 3 * c + 1] = var[:, c] * g_xy
        vc[:, 3 * c + 2] = var[:, c] * g_xx
    c2 = curv**2
    return curv * np.divide(c2, c2 + vc, out=np.ones_like(c2), where=(c2 + vc) > 0)


def _central_window(mesh: Q4Mesh, keep: np.ndarray, max_nodes: int) -> np.ndarray:
    """Nodes of a square window around the mesh centre holding about
    ``max_nodes`` nodes (risk estimation on very large meshes)."""
    cx, cy = np.median(mesh.x), np.median(mesh.y)
    r = np.maximum(np.abs(mesh.x - cx), np.abs(mesh.y - cy))
    lim = np.sort(r)[max_nodes - 1]
    return keep & (r <= lim)


@dataclass
class SmoothingChoice:
    """Outcome of :func:`choose_smoothing`."""

    smooth_px: float  # thin-plate smoothing length, pixels
    second_order: bool  # whether the second-order warp pays off
    table: list = field(default_factory=list)  # risk per candidate (px²)
    deconvolution_gain_px2: float = 0.0  # estimated bias² the warp removes, per node


def choose_smoothing(mesh: Q4Mesh, u: np.ndarray, v: np.ndarray, trusted: np.ndarray,
                     noise_var: np.ndarray, step: float, subset: int,
                     candidates=SMOOTH_CANDIDATES,
                     curv_length: float | None = None) -> SmoothingChoice:
    """Smoothing length (and use of the second-order warp) of least estimated risk.

    Parameters
    ----------
    mesh : the Q4 mesh of the nodes.
    u, v : local displacements; trusted : nodes whose local result is reliable.
    noise_var : (n, 2) from :func:`displacement_noise`.
    step, subset : node spacing and subset width (pixels).
    candidates : lengths to try, in units of ``subset``.
    curv_length : if the second-order warp may be used, the smoothing length
        (pixels) of its curvature estimate. Each length is then scored twice:
        with the warp (noise term of the whole fixed point, see
        :func:`_lattice_noise_factor`) and without it (plain SURE plus the
        undermatching bias the warp would remove, ``‖γ ∇² u‖²``, estimated
        from the smoothed local field minus its noise share).

    Returns
    -------
    SmoothingChoice
    """
    keep = trusted & np.isfinite(noise_var).all(axis=1)
    if mesh.n_elements == 0 or keep.sum() < 16:
        return SmoothingChoice(0.0, curv_length is not None)
    if mesh.n_nodes > _SELECT_MAX_NODES:
        sub_nodes = _central_window(mesh, np.ones(mesh.n_nodes, bool), _SELECT_MAX_NODES)
        mesh, u, v, keep, noise_var = _restrict(mesh, sub_nodes, u, v, keep, noise_var)
    T, free = mesh.prolongation()
    KtK = T.T @ curvature_operator(mesh) @ T
    w = keep.astype(float)
    Wd = T.T @ sp.diags(np.where(keep, 1.0, 1e-6)) @ T
    rhs = T.T @ np.column_stack([w * u, w * v])
    total_var = float(noise_var[keep].sum())
    data = np.column_stack([u, v])[keep]
    n_keep = int(keep.sum())
    gain = 0.0
    if curv_length is not None:
        gain = _deconvolution_gain(mesh, T, free, u, v, keep, noise_var, step, subset,
                                   curv_length)

    def risks(c: float) -> tuple[float, float]:
        ell = float(c) * subset
        if ell == 0:
            smooth = data
        else:
            A = (Wd + ell**4 * KtK).tocsc()
            sol = spla.splu(A, permc_spec="MMD_AT_PLUS_A").solve(np.asfortranarray(rhs))
            smooth = (T @ sol)[keep]
        resid = float(np.sum((smooth - data) ** 2)) / n_keep
        plain = resid + _lattice_noise_factor(ell, step, subset) * total_var / n_keep
        if curv_length is None:
            return plain, np.inf
        warp = resid + _lattice_noise_factor(ell, step, subset, curv_length) * total_var / n_keep
        return plain + gain, warp

    i, cache = _walk_downhill(len(candidates), lambda k: risks(candidates[k]))
    table = [{"smooth_px": float(candidates[k]) * subset, "risk_px2": cache[k][0],
              **({"risk_second_order_px2": cache[k][1]} if curv_length is not None else {})}
             for k in sorted(cache)]
    plain, warp = cache[i]
    return SmoothingChoice(float(candidates[i]) * subset, bool(warp < plain), table, gain)


def _walk_downhill(n: int, risks) -> tuple[int, dict[int, tuple[float, float]]]:
    """Index of the least risk among ``n`` candidates, and the risks computed.

    The risk is unimodal in log(ell) in practice: walk downhill from the
    middle candidate, evaluating (factorising) only the candidates visited.
    ``risks(k)`` returns ``(plain, second_order)``; a candidate scores the
    lower of the two.
    """
    cache: dict[int, tuple[float, float]] = {}

    def at(i: int) -> float:
        if i not in cache:
            cache[i] = risks(i)
        return min(cache[i])

    i = n // 2
    while True:
        here = at(i)
        if i > 0 and at(i - 1) < here:
            i -= 1
        elif i + 1 < n and at(i + 1) < here:
            i += 1
        else:
            break
    return i, cache


def _deconvolution_gain(mesh, T, free, u, v, keep, noise_var, step, subset, curv_length):
    """Mean per node of ``‖γ ∇² u‖²``: the squared undermatching bias of an
    affine subset, from the local field's curvature estimated exactly as the
    second-order warp estimates it, minus the noise share of that estimate."""
    _, _, _, hx, hy = second_difference_operators(mesh)
    inner = keep & hx & hy & ~level_transition_nodes(mesh)
    if not inner.any():
        return 0.0
    curv = CurvatureEstimator(mesh, curv_length, keep, T, free)(u, v)
    lap = _subset_gamma(subset) * np.column_stack([curv[:, 0] + curv[:, 2],
                                                   curv[:, 3] + curv[:, 5]])
    raw = float(np.mean(np.sum(lap[inner] ** 2, axis=1)))
    qx, qy, r = _lattice_symbols(step, subset)
    g = _feedback_symbol(step, subset, curv_length, qx, qy)
    noise = float(np.mean(g * g * r)) * float(np.mean(noise_var[inner].sum(axis=1)))
    return max(raw - noise, 0.0)


def _restrict(mesh: Q4Mesh, nodes: np.ndarray, u, v, keep, noise_var):
    """The sub-mesh of elements whose corners are all in ``nodes``."""
    e = mesh.elements
    e = e[nodes[e].all(axis=1)]
    used = np.unique(e)
    new = -np.ones(mesh.n_nodes, np.int64)
    new[used] = np.arange(used.size)
    h = mesh.hanging
    h = h[np.isin(h, used).all(axis=1)] if h.size else h
    sub = Q4Mesh(mesh.x[used], mesh.y[used], new[e], new[h] if h.size else h)
    return sub, u[used], v[used], keep[used], noise_var[used]
