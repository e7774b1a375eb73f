"""Automatic strength of the AL-DIC regularisation.

Overlapping subsets make the errors of neighbouring Local DIC nodes strongly
correlated (31 px subsets every 8 px share ~75 % of their pixels), so the
compatibility constraints of Algorithm 1 alone cannot average noise away. The
global step therefore may carry a thin-plate term ``κ ‖K û‖²`` (squared second
differences and element twists of ``û``,
:func:`~napari_aldic.engine.dic.global_solve.curvature_operator`). It is zero for
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

Two refinements (``docs/method.md`` section 7.3): the risk targets the true
field, not ``E u_L`` (a cross term with Local DIC's own undermatching bias,
estimated by deconvolving ``u_L`` as the second-order warp does), and the
length is chosen per node from the risk terms averaged over a window of
about one subset width, so detail in one region and smooth noise in another
each get their own smoothing (per-node weights of the thin-plate term).
"""

from __future__ import annotations

import functools
from concurrent.futures import Future
from dataclasses import dataclass, field

import numba
import numpy as np

from ..core.params import ADAPTIVE_WINDOW, SMOOTH_CANDIDATES
from .global_solve import (
    CurvatureEstimator,
    Q4Mesh,
    level_transition_nodes,
    second_difference_operators,
    solver_method,
)
from .reliability import displacement_variance, subset_statistics
from .threads import beside
from .trial_smoothers import (
    FILL_SIGMA,
    SMOOTHING_THREADS,
    CGFirst,
    lattice_preconditioner,
    trial_residuals,
    use_cg,
    window_mean,
)

__all__ = ["displacement_noise", "choose_smoothing", "SmoothingChoice", "curvature_noise_gains",
           "shrink_curvature", "SMOOTH_CANDIDATES", "ADAPTIVE_WINDOW", "window_mean"]

# above this many nodes (a direct factor per trial length gets too costly) one
# length is chosen, on a central window of WINDOW_NODES nodes
ADAPTIVE_MAX_NODES = 250_000
WINDOW_NODES = 20_000
# without the second-order warp, Local DIC's undermatching bias (the cross
# term of the risk) is estimated from the curvature smoothed over this
# fraction of the subset half-width (as the warp's, admm.CURVATURE_SMOOTHING)
BIAS_SMOOTHING = 0.5
# with the warp, a node's length is at most about the geometric mean of its
# warp-risk and affine-risk choices (see choose_smoothing)
WARP_LENGTH_CAP = True
# fixed-point steps of that deconvolution (the warp's ADMM iterations run a few)
DECONVOLUTION_STEPS = 3


def gradient_noise_gain(order: int) -> float:
    """Variance of the spline derivative of unit white noise at the pixel
    centres (:func:`~napari_aldic.engine.dic.interpolation.reference_gradients`)."""
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


@functools.lru_cache(maxsize=8)
def _lattice_symbols(step: float, subset: int, n: int = 256):
    """``(q_x, q_y, R)`` on an n x n wavenumber grid: ``q = sin²(θ/2)`` and the
    symbol of the subset-overlap correlation (1 at zero lag)."""
    th = 2 * np.pi * np.arange(n) / n
    q = np.sin(th / 2) ** 2
    qx, qy = np.meshgrid(q, q, indexing="ij")
    lags = np.arange(-(subset // step) - 1, subset // step + 2)
    tri = np.clip(1.0 - np.abs(lags) * step / subset, 0.0, None)
    r1 = np.real(np.exp(1j * np.outer(th, lags)) @ tri)
    return _frozen(qx), _frozen(qy), _frozen(np.outer(r1, r1))


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


@dataclass
class SmoothingChoice:
    """Outcome of :func:`choose_smoothing`."""

    smooth_px: float  # the best single smoothing length (pixels) for the whole mesh
    second_order: bool  # whether the second-order warp pays off
    table: list = field(default_factory=list)  # mean risk per candidate (px²)
    deconvolution_gain_px2: float = 0.0  # estimated bias² the warp removes, per node
    # (N,) per-node lengths (pixels) of the spatially adaptive choice; None: use smooth_px
    node_smooth_px: np.ndarray | None = None


def choose_smoothing(mesh: Q4Mesh, u: np.ndarray, v: np.ndarray, trusted: np.ndarray,
                     noise_var: np.ndarray, step: float, subset: int,
                     candidates=SMOOTH_CANDIDATES, curv_length: float | None = None,
                     adaptive: bool = True, window: float | None = None) -> SmoothingChoice:
    """Smoothing length(s) (and use of the second-order warp) of least estimated risk.

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
    adaptive : also choose a length per node (``node_smooth_px``), from the
        risk averaged over a Gaussian window of ``window`` subset widths
        (default ``ADAPTIVE_WINDOW``) around it: fine detail in one region no
        longer makes the whole field smoother, nor smooth regions the detail.

    Returns
    -------
    SmoothingChoice
    """
    keep = trusted & np.isfinite(noise_var).all(axis=1)
    if mesh.n_elements == 0 or keep.sum() < 16:
        return SmoothingChoice(0.0, curv_length is not None)
    if adaptive and mesh.n_nodes > ADAPTIVE_MAX_NODES:
        # six trial smoothers on the whole mesh would cost more than the ADMM
        # itself: one length, from a central window (the former behaviour)
        sub, u, v, trusted, noise_var = _central_window(mesh, u, v, trusted, noise_var)
        return choose_smoothing(sub, u, v, trusted, noise_var, step, subset, candidates,
                                curv_length, adaptive=False)
    window = ADAPTIVE_WINDOW if window is None else window
    lengths = [float(c) * subset for c in candidates]
    plain, warp, gain_nodes = _node_risks(mesh, u, v, keep, noise_var, step, subset, lengths,
                                          curv_length)
    gain = 0.0
    if curv_length is not None and np.isfinite(gain_nodes).any():
        gain = max(float(np.nanmean(gain_nodes)), 0.0)
    mean_plain = np.nanmean(plain, axis=0) + gain
    mean_warp = np.nanmean(warp, axis=0) if warp is not None else np.full(len(lengths), np.inf)
    best = np.minimum(mean_plain, mean_warp)
    i = int(np.argmin(best))
    table = [{"smooth_px": lengths[k], "risk_px2": float(mean_plain[k]),
              **({"risk_second_order_px2": float(mean_warp[k])} if warp is not None else {})}
             for k in range(len(lengths))]
    choice = SmoothingChoice(lengths[i], bool(mean_warp[i] < mean_plain[i]), table, gain)
    if adaptive:
        # the warp is used everywhere or nowhere (its mean risk decides); the
        # length varies: each node takes the least risk over its window
        idx = _adaptive_choice(mesh, plain, step, window * subset, i)
        if choice.second_order:
            k = _adaptive_choice(mesh, warp, step, window * subset, i)
            # the warp's risk assumes its deconvolution works; where noise makes
            # the curvature shrinkage fade it, it does not, and the affine-subset
            # risk (no deconvolution) smooths less: take the midpoint of the two
            # choices on the (geometric) candidate ladder
            idx = np.where(idx < k, (idx + k) // 2, k) if WARP_LENGTH_CAP else k
        choice.node_smooth_px = np.asarray(lengths, float)[idx]
    return choice


def _node_risks(mesh: Q4Mesh, u, v, keep, noise_var, step, subset, lengths, curv_length):
    """Per-node risk terms (N, K) of each length (NaN off ``keep``), against
    the true field: ``(plain, warp, gain)``.

    ``plain`` (affine subsets): SURE plus the cross term of the smoothing
    with Local DIC's own undermatching bias ``b = E u_L - u ≈ γ ∇² u``:
    ``2 <(S-1) E u_L, b>``, estimated by ``2 (S u_L - u_L)·γ∇²u_L`` minus its
    noise covariance. Smoothing an already attenuated fine structure
    attenuates it further: SURE alone (which targets ``E u_L``) misses
    that. ``warp`` (None without ``curv_length``): the risk with the
    second-order warp, whose fixed point deconvolves the subset average: its
    signal error is that of the smoother on the deconvolved field
    ``u_L - γ∇²u_L`` (SURE-corrected), its noise that of the whole fixed
    point (:func:`_lattice_noise_factor`); ``gain`` (N,): the bias² the warp
    removes, minus its noise share (NaN where not estimated).
    """
    nvar = np.where(keep, np.nan_to_num(noise_var).sum(axis=1), np.nan)
    bias_length = curv_length if curv_length is not None else BIAS_SMOOTHING * (subset // 2)
    # the trial smoothers factorise (they need only the mesh and the weights)
    # while this thread estimates the bias, their third field
    late = Future()
    workers = max(SMOOTHING_THREADS, numba.get_num_threads())

    def bias():  # hands its result (or failure) to the smoothers waiting for it
        try:
            out = _undermatching_bias(mesh, u, v, keep, noise_var, step, subset, bias_length)
        except BaseException as exc:
            late.set_exception(exc)
            raise
        late.set_result(np.nan_to_num(out[0]))
        return out
    both, (lap, gain) = beside(lambda: trial_residuals(mesh, np.column_stack([u, v]), keep,
                                                       lengths, step, late, workers), bias)
    # per component on (N, K) planes: sums and einsum over the last axis of
    # length 2 cost four times as much (the result is the same)
    d0, d1 = both[..., 0], both[..., 1]
    l0, l1 = (np.nan_to_num(lap[:, c])[:, None] for c in (0, 1))
    # nodes without a curvature estimate (edges) are not deconvolved
    has = np.isfinite(lap).all(axis=1)[:, None]
    c = _risk_constants(tuple(lengths), step, subset, bias_length, curv_length)
    cross = 2 * ((d0 * l0 + d1 * l1) - np.where(has, 1.0, 0.0) * c["cross_noise"] * nvar[:, None])
    plain = d0 * d0 + d1 * d1 + cross + c["plain"] * nvar[:, None]
    if curv_length is None:
        return plain, None, gain
    e0, e1 = d0 - both[..., 2], d1 - both[..., 3]
    deconv = e0 * e0 + e1 * e1
    deconv_noise = np.where(has, c["deconv_noise"], c["undeconvolved_noise"])
    warp = deconv + (c["fixed_point"] - deconv_noise) * nvar[:, None]
    return plain, warp, gain


@functools.lru_cache(maxsize=16)
def _risk_constants(lengths: tuple, step: float, subset: int, bias_length: float,
                    curv_length: float | None) -> dict:
    """The node risks' noise factors per length (:func:`_node_risks`): lattice
    means that depend on the parameters only, kept between runs (dozens of
    256² symbol evaluations, ~0.03 s a run)."""
    qx, qy, r = _lattice_symbols(step, subset)
    D = _deconvolution_symbol(step, subset, bias_length, qx, qy)
    out = {"cross_noise": [], "plain": [], "deconv_noise": [], "undeconvolved_noise": [],
           "fixed_point": []}
    for ell in lengths:
        s1 = _thin_plate_symbol(ell, step, qx, qy) - 1
        out["cross_noise"].append(np.mean(s1 * (1 - D) * r))
        out["plain"].append(_lattice_noise_factor(ell, step, subset))
        if curv_length is not None:
            out["deconv_noise"].append(np.mean(s1**2 * D**2 * r))
            out["undeconvolved_noise"].append(np.mean(s1**2 * r))
            out["fixed_point"].append(_lattice_noise_factor(ell, step, subset, curv_length)
                                      + np.mean(s1**2 * r))
    return {k: _frozen(np.array(v, float)) for k, v in out.items()}


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False  # shared between runs by the caches
    return a


def _adaptive_choice(mesh: Q4Mesh, risk, step, sigma_px, i_global) -> np.ndarray:
    """Per-node candidate index minimising the windowed risk (N, K); nodes
    whose window holds no trusted node take the single best one."""
    risk = window_mean(mesh, risk, step, sigma_px)
    ok = np.isfinite(risk).all(axis=1)
    idx = np.full(mesh.n_nodes, i_global)
    idx[ok] = np.argmin(risk[ok], axis=1)
    return idx


def _deconvolution_symbol(step, subset, length, qx, qy):
    """Symbol of the deconvolution ``d = u_L + g d`` (``DECONVOLUTION_STEPS``
    fixed-point steps from ``d = u_L``): ``1 + g + ... + g^m``."""
    g = _feedback_symbol(step, subset, length, qx, qy)
    return sum(g**j for j in range(DECONVOLUTION_STEPS + 1))


def _undermatching_bias(mesh, u, v, keep, noise_var, step, subset, length):
    """``(b, gain)``: per node (N, 2) the undermatching bias ``b = u_L - d`` of
    an affine subset, ``d`` the local field deconvolved by the fixed point
    ``d = u_L - γ ∇² d`` that the second-order warp solves (curvature
    smoothed over ``length``), and (N,) ``|b|²`` minus its noise share; NaN
    where not estimated."""
    _, _, _, hx, hy = second_difference_operators(mesh)
    inner = keep & hx & hy & ~level_transition_nodes(mesh)
    bias = np.full((mesh.n_nodes, 2), np.nan)
    gain = np.full(mesh.n_nodes, np.nan)
    if not inner.any():
        return bias, gain
    T, free = mesh.prolongation()
    estimate = CurvatureEstimator(mesh, length, keep, T, free)
    uv = np.column_stack([u, v])
    # a factor when the trial smoothers use them too: with many untrusted nodes
    # (weight UNTRUSTED_WEIGHT) Jacobi CG on the field needs thousands of
    # iterations (crack sample: 2,000 per column, 2.7 s, against ~40 when nearly
    # all are data); or, as the trial smoothers, CG on the correction from the
    # field filled off the data (lattice-preconditioned where they are), a
    # factor if CG stalls
    direct = solver_method(mesh.n_nodes) == "direct"
    solver = None
    pre = lattice_preconditioner(mesh, free, length, step)
    if pre is not None or use_cg(free.size, length, step):
        fill = window_mean(mesh, np.where(keep[:, None], uv, np.nan), step, FILL_SIGMA * step)
        solver = CGFirst(estimate.matrix, np.where(keep[:, None], uv, np.nan_to_num(fill))[free],
                         pre)
    d = uv
    for _ in range(DECONVOLUTION_STEPS):
        curv = estimate(d[:, 0], d[:, 1], direct=direct, solver=solver)
        d = uv - _subset_gamma(subset) * np.column_stack([curv[:, 0] + curv[:, 2],
                                                          curv[:, 3] + curv[:, 5]])
    bias[inner] = (uv - d)[inner]
    noise = _bias_noise_factor(step, subset, length) * noise_var[inner].sum(axis=1)
    gain[inner] = np.sum(bias[inner] ** 2, axis=1) - noise
    return bias, gain


@functools.lru_cache(maxsize=16)
def _bias_noise_factor(step: float, subset: int, length: float) -> float:
    """The share of the local noise variance in the bias estimate ``|b|²``."""
    qx, qy, r = _lattice_symbols(step, subset)
    return float(np.mean((1 - _deconvolution_symbol(step, subset, length, qx, qy)) ** 2 * r))


def _central_window(mesh: Q4Mesh, u, v, trusted, noise_var):
    """The sub-mesh of the elements whose corners all lie in a square window
    of about ``WINDOW_NODES`` nodes around the mesh centre, and its data."""
    r = np.maximum(np.abs(mesh.x - np.median(mesh.x)), np.abs(mesh.y - np.median(mesh.y)))
    inside = r <= np.sort(r)[min(WINDOW_NODES, r.size) - 1]
    e = mesh.elements[inside[mesh.elements].all(axis=1)]
    used = np.unique(e)
    new = -np.ones(mesh.n_nodes, np.int64)
    new[used] = np.arange(used.size)
    h = mesh.hanging
    h = h[np.isin(h, used).all(axis=1)] if h.size else h
    sub = Q4Mesh(mesh.x[used], mesh.y[used], new[e], new[h] if h.size else h)
    return sub, u[used], v[used], trusted[used], noise_var[used]
