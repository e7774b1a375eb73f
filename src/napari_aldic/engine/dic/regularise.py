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

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp

from ..core.params import ADAPTIVE_WINDOW, SMOOTH_CANDIDATES
from ..kernels.cg import jacobi_cg
from .global_solve import (
    UNTRUSTED_WEIGHT,
    CurvatureEstimator,
    Q4Mesh,
    SPDSolver,
    curvature_operator,
    level_transition_nodes,
    second_difference_operators,
    solver_method,
)
from .linear_solvers import cg_tolerances
from .reliability import displacement_variance, subset_statistics
from .threads import side_by_side

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
# trial smoothers factorised at once (the machines this targets have 2+ cores)
SMOOTHING_THREADS = 2
# trial lengths up to this many node spacings are solved by Jacobi CG (relative
# tolerance CG_RTOL on the smoother's correction; past CG_MAX_ITER iterations a
# factor instead); the off-data nodes start from the fields' window mean of
# FILL_SIGMA node spacings
CG_MAX_LENGTH = 1.0
CG_RTOL = 1e-6
CG_MAX_ITER = 200
FILL_SIGMA = 2.0


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
    with ThreadPoolExecutor(1) as aside:
        job = aside.submit(_residuals, mesh, np.column_stack([u, v]), keep, lengths, step,
                           late)
        try:
            lap, gain = _undermatching_bias(mesh, u, v, keep, noise_var, step, subset,
                                            bias_length)
        except BaseException as exc:
            late.set_exception(exc)
            raise
        late.set_result(np.nan_to_num(lap))
        both = job.result()
    diff = both[..., :2]
    resid = np.sum(diff**2, axis=2)
    qx, qy, r = _lattice_symbols(step, subset)
    D = _deconvolution_symbol(step, subset, bias_length, qx, qy)
    cross_noise = np.array([np.mean((_thin_plate_symbol(ell, step, qx, qy) - 1) * (1 - D) * r)
                            for ell in lengths])
    cross = 2 * (np.einsum("nkc,nc->nk", diff, np.nan_to_num(lap))
                 - np.where(np.isfinite(lap).all(axis=1), 1.0, 0.0)[:, None]
                 * cross_noise * nvar[:, None])
    plain = resid + cross + np.array([_lattice_noise_factor(ell, step, subset)
                                      for ell in lengths]) * nvar[:, None]
    if curv_length is None:
        return plain, None, gain
    deconv = np.sum((diff - both[..., 2:]) ** 2, axis=2)
    # nodes without a curvature estimate (edges) are not deconvolved
    has = np.isfinite(lap).all(axis=1)[:, None]
    deconv_noise = np.where(has, [np.mean((_thin_plate_symbol(ell, step, qx, qy) - 1) ** 2
                                          * D**2 * r) for ell in lengths],
                            [np.mean((_thin_plate_symbol(ell, step, qx, qy) - 1) ** 2 * r)
                             for ell in lengths])
    fixed_point = np.array([_lattice_noise_factor(ell, step, subset, curv_length)
                            + np.mean((_thin_plate_symbol(ell, step, qx, qy) - 1) ** 2 * r)
                            for ell in lengths])
    warp = deconv + (fixed_point - deconv_noise) * nvar[:, None]
    return plain, warp, gain


def _residuals(mesh: Q4Mesh, fields: np.ndarray, keep, lengths, step: float,
               late: Future | None = None) -> np.ndarray:
    """(N, K, M) ``S_ℓ f - f`` per node and length (NaN off ``keep``) of nodal
    ``fields`` (N, M): the thin-plate smoother fitted at the trusted nodes.
    ``late``: a future of more columns of ``fields``, waited for only once a
    smoother is ready for them (the caller computes them meanwhile).

    Lengths up to ``CG_MAX_LENGTH`` node spacings are solved by Jacobi CG for
    the correction ``S_ℓ f - f`` itself (:class:`_ShortSmoother`); longer ones
    (and short ones whose CG stalls) by a factor like the global matrix's, or
    on meshes too large for a factor by AMG-CG warm-started from the previous
    length (4 digits suffice)."""
    T, free = mesh.prolongation()
    KtK = (T.T @ curvature_operator(mesh) @ T).tocsr()
    Wd = (T.T @ sp.diags(np.where(keep, 1.0, UNTRUSTED_WEIGHT)) @ T).tocsr()
    diag = np.maximum(Wd.diagonal(), UNTRUSTED_WEIGHT)[:, None]
    trials = [k for k, ell in enumerate(lengths) if ell != 0]
    first = np.where(keep[:, None], fields, np.nan)

    def data():  # the fields, the late columns with them, 0 off keep
        more = () if late is None else (late.result(),)
        return np.where(keep[:, None], np.column_stack([fields, *more]), 0.0)

    def factor(k, start=None):
        solver = SPDSolver((Wd + lengths[k] ** 4 * KtK).tocsc(), "auto", rtol=1e-5)
        b = T.T @ data()
        return solver.solve(b, b / diag if start is None else start)

    if solver_method(Wd.shape[0]) == "direct":
        short = [k for k in trials if lengths[k] <= CG_MAX_LENGTH * step]
        long = [k for k in trials if k not in short]
        # CG starts from the fields, filled off the data by their window mean
        fill = np.nan_to_num(window_mean(mesh, first, step, FILL_SIGMA * step))

        def columns(late_ones: bool):  # (right-hand sides, starts) on the free nodes
            f = late.result() if late_ones else fields
            start = np.where(keep[:, None], f, 0.0 if late_ones else fill)[free]
            return T.T @ np.where(keep[:, None], f, 0.0), start
        cg = _ShortSmoother(Wd, KtK, lengths, columns, late is not None, factor,
                            short[0] if short else None)
        # the long lengths' factors are independent and SuperLU releases the GIL:
        # two at a time on the two cores (each freed once its solve is done);
        # the shortest length's CG goes first (it tells whether CG converges
        # here), the other short lengths' CG fills the cores after the factors,
        # their late columns last (no core waits for them while work is left)
        jobs = ([("cg", k) for k in short[:1]] + [("factor", k) for k in long]
                + [("cg", k) for k in short[:0:-1]] + [("late", k) for k in short[::-1]])
        run = {"cg": cg.first_columns, "factor": factor, "late": cg.late_columns}
        done = side_by_side(lambda job: run[job[0]](job[1]), jobs, SMOOTHING_THREADS)
        found = {k: x for (_, k), x in zip(jobs, done) if x is not None}
        sols = [found[k] for k in trials]
    else:
        sols = []
        for k in trials:
            sols.append(factor(k, sols[-1] if sols else None))
    full = data()
    out = np.full((mesh.n_nodes, len(lengths), full.shape[1]), np.nan)
    out[keep] = 0.0
    for k, sol in zip(trials, sols):
        out[keep, k] = ((T @ sol) - full)[keep]
    return out


class _ShortSmoother:
    """A short trial smoother by Jacobi CG on its correction.

    With ``x0`` the fields (filled off the data), ``(Wd + ℓ⁴ KᵀK) x = b`` is
    solved as ``x = x0 + e``, ``(Wd + ℓ⁴ KᵀK) e = b - (Wd + ℓ⁴ KᵀK) x0``: ``e`` is
    the smoother's correction, the risk's residual, so CG's relative tolerance
    applies to it, not to the field (a rigid shift of 50 px would otherwise
    need 1e-8). Short lengths are well conditioned (κ ≲ 1 + 64 (ℓ/step)⁴):
    10-70 iterations, a fraction of a factor's cost. Where CG stalls (many
    untrusted nodes make the system nearly singular there) ``factor(k)``
    solves the length instead. Whether CG converges on the ``first`` (the
    shortest) length decides for the others: past a stall there, they are
    factorised without trying (a decision that does not depend on timing).

    ``columns(late)``: ``(b, x0)`` of the first columns (``late=False``) or,
    with ``has_late``, of the late ones (waited for after the first)."""

    def __init__(self, Wd, KtK, lengths, columns, has_late: bool, factor, first):
        self.Wd, self.KtK, self.lengths, self.columns = Wd, KtK, lengths, columns
        self.has_late, self.factor, self.first = has_late, factor, first
        self._converges = Future()
        # length -> Future of its first columns by CG (None: solved whole)
        self._firsts: dict[int, Future] = {}

    def first_columns(self, k: int) -> np.ndarray | None:
        """Length ``k``'s solution in every column (by its factor if CG stalls,
        or stalled on the first length; by CG without late columns), or None
        when its late columns are left to :meth:`late_columns`."""
        done = self._firsts.setdefault(k, Future())
        try:
            x = self._cg_first(k)
        except BaseException as exc:
            done.set_exception(exc)
            raise
        partial = x is not None and self.has_late
        done.set_result(x if partial else None)
        if x is None:
            return self.factor(k)
        return None if partial else x

    def late_columns(self, k: int) -> np.ndarray | None:
        """Length ``k``'s solution in every column, its late columns by CG after
        the first ones (by its factor if CG stalls there); None if
        :meth:`first_columns` solved it whole. Run after ``first_columns(k)``
        has started."""
        first = self._firsts[k].result()
        if first is None:
            return None
        more = _cg_columns(self._matrix(k), *self.columns(True))
        return self.factor(k) if more is None else np.column_stack([first, more])

    def _cg_first(self, k: int) -> np.ndarray | None:
        """The first columns by CG, or None (stalled here or on the first length)."""
        if k != self.first and not self._converges.result():
            return None
        try:
            x = _cg_columns(self._matrix(k), *self.columns(False))
        except BaseException as exc:
            if k == self.first:
                self._converges.set_exception(exc)
            raise
        if k == self.first:
            self._converges.set_result(x is not None)
        return x

    def _matrix(self, k: int) -> sp.csr_matrix:
        return (self.Wd + self.lengths[k] ** 4 * self.KtK).tocsr()


class _CGFirst:
    """``solve(rhs, guess)`` with one SPD matrix, warm-started from the last
    solution (the first from ``start``): :func:`_cg_columns`, and once CG
    stalls a factor for this and every later solve."""

    def __init__(self, A, start: np.ndarray):
        self.A, self._last, self._factor = A.tocsr(), start, None

    def solve(self, rhs: np.ndarray, guess=None) -> np.ndarray:
        x = None if self._factor is not None else _cg_columns(self.A, rhs, self._last)
        if x is None:
            if self._factor is None:
                self._factor = SPDSolver(self.A.tocsc(), "direct", 0.0)
            x = self._factor.solve(rhs, None)
        self._last = x
        return x


def _cg_columns(A: sp.csr_matrix, b: np.ndarray, x0: np.ndarray) -> np.ndarray | None:
    """``A⁻¹ b`` as ``x0`` plus a correction solved by Jacobi CG to ``CG_RTOL`` of
    its right-hand side, all columns at once; None if a column needs more than
    ``CG_MAX_ITER`` iterations."""
    rhs = np.ascontiguousarray(b - A @ x0)
    atol, _ = cg_tolerances(rhs, CG_RTOL)
    e = np.zeros(rhs.shape)
    its = np.zeros(rhs.shape[1], np.int64)
    jacobi_cg(A.indptr, A.indices, A.data, 1.0 / A.diagonal(), rhs, e, atol, CG_MAX_ITER, its)
    return None if (its >= CG_MAX_ITER).any() else x0 + e


def _adaptive_choice(mesh: Q4Mesh, risk, step, sigma_px, i_global) -> np.ndarray:
    """Per-node candidate index minimising the windowed risk (N, K); nodes
    whose window holds no trusted node take the single best one."""
    risk = window_mean(mesh, risk, step, sigma_px)
    ok = np.isfinite(risk).all(axis=1)
    idx = np.full(mesh.n_nodes, i_global)
    idx[ok] = np.argmin(risk[ok], axis=1)
    return idx


def window_mean(mesh: Q4Mesh, values: np.ndarray, step: float, sigma_px: float) -> np.ndarray:
    """Gaussian-weighted mean (standard deviation ``sigma_px``) of nodal
    ``values`` (N, M) around each node, ignoring NaN; NaN where the window
    holds no value. Nodes are binned on their lattice of spacing ``step``
    (quadtree nodes fall in the nearest cell), so the cost is linear in N."""
    ix = np.rint((mesh.x - mesh.x.min()) / step).astype(np.int64)
    iy = np.rint((mesh.y - mesh.y.min()) / step).astype(np.int64)
    shape = (int(iy.max()) + 1, int(ix.max()) + 1)
    s = sigma_px / step
    out = np.full(values.shape, np.nan)
    for j in range(values.shape[1]):
        ok = np.isfinite(values[:, j])
        num = np.zeros(shape)
        den = np.zeros(shape)
        np.add.at(num, (iy[ok], ix[ok]), values[ok, j])
        np.add.at(den, (iy[ok], ix[ok]), 1.0)
        num = ndi.gaussian_filter(num, s, mode="constant", truncate=2.5)
        den = ndi.gaussian_filter(den, s, mode="constant", truncate=2.5)
        d = den[iy, ix]
        out[:, j] = np.where(d > 1e-3, num[iy, ix] / np.maximum(d, 1e-3), np.nan)
    return out


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
    solver = None
    if solver_method(mesh.n_nodes) == "direct" and length <= CG_MAX_LENGTH * step:
        # as the short trial smoothers: CG on the correction, from the field
        # filled off the data, and a factor if CG stalls (with many untrusted
        # nodes, weight UNTRUSTED_WEIGHT, Jacobi CG needs thousands of
        # iterations: crack sample 2,000 per column, against ~40 when nearly
        # all nodes are data)
        fill = window_mean(mesh, np.where(keep[:, None], uv, np.nan), step, FILL_SIGMA * step)
        solver = _CGFirst(estimate.matrix, np.where(keep[:, None], uv, np.nan_to_num(fill))[free])
    d = uv
    for _ in range(DECONVOLUTION_STEPS):
        curv = estimate(d[:, 0], d[:, 1], solver=solver)
        d = uv - _subset_gamma(subset) * np.column_stack([curv[:, 0] + curv[:, 2],
                                                          curv[:, 3] + curv[:, 5]])
    bias[inner] = (uv - d)[inner]
    qx, qy, r = _lattice_symbols(step, subset)
    D = _deconvolution_symbol(step, subset, length, qx, qy)
    noise = float(np.mean((1 - D) ** 2 * r)) * noise_var[inner].sum(axis=1)
    gain[inner] = np.sum(bias[inner] ** 2, axis=1) - noise
    return bias, gain


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
