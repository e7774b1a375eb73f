"""Standard uncertainty of AL-DIC's smoothed field ``u``, ``v`` by linear
noise propagation through the ADMM iterations (random probing).

To first order the image noise ``n`` (reference minus warped deformed
image, white) moves every quantity of an AL-DIC run linearly:

* the Local DIC start of node i by ``δp_i = M_i⁻¹ Σ_subset J_i t n`` (the
  shape-function Gauss-Newton step with the noise as residual; ``M = Σ J ∇fᵀ``,
  ``t`` the shape monomials); neighbouring subsets share pixels, so their
  errors are correlated exactly as in the real run;
* each ADMM local step (translation, gradient ``F`` and warp curvature ``K``
  fixed, penalty ``pen_i``) by ``(C_i + pen_i I) δu_i = b_i + pen_i δt_i
  - B_i δF_i - Q_i δK_i`` with ``C_i`` the translation block of ``M_i``,
  ``b_i = Σ J_i n``, ``δt`` the perturbed penalty target, ``B_i``, ``Q_i``
  the first and second moments of ``Σ J ∇fᵀ`` over the subset (how bending
  the subset moves its translation) and ``δK`` the curvature the run's
  smoother and shrinkage make of ``δû`` (linearised at the run's field);
* each global step and dual update exactly as the solver does them (they
  are linear; the solver's matrix, weights and smoothing are frozen at the
  run's values), for the same number of ADMM iterations.

Drawing ``K`` unit-variance noise images (Rademacher: ±1 per pixel, which
estimate the variances with less sampling error than Gaussian ones,
:func:`rademacher_bits`) and pushing each through these maps
gives per node the std of the smoothed field and of the Local DIC
start under the same noise; their ratio (the smoothing gain, noise level
free) scales the Local model's standard uncertainty (``dic.quality``),
which already carries the node's own noise level, the interpolation and the
gradient-noise corrections.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from ..kernels.moments import centre_moments, moment_terms
from ..kernels.noise_sums import MAX_NOISE_ORDER, noise_window_sums
from .threads import side_by_side

__all__ = ["ADMMLinearisation", "CurvatureFeedback", "linearise_admm", "aldic_gain", "BatchSolver",
           "ProbeMaps", "probe_maps", "noise_projector", "rademacher_bits"]


@dataclass
class ADMMLinearisation:
    """What the propagation needs of a finished AL-DIC run.

    Attributes
    ----------
    solver : GlobalSolver
        The run's global solver (matrix, weights and smoothing frozen).
    iterations : int
        ADMM iterations run.
    mu : float
        Dimensionless local penalty.
    active : (n,) bool
        Nodes whose local step took part.
    probes : int
        Noise images drawn (the relative sampling error of a node's gain is
        about ``1/sqrt(2 probes)``).
    seed : int
    """

    solver: object
    iterations: int
    mu: float
    active: np.ndarray
    probes: int = 16
    seed: int = 0
    curvature: CurvatureFeedback | None = None


@dataclass
class CurvatureFeedback:
    """The second-order warp's feedback, linearised at the run's field.

    Attributes
    ----------
    estimator : CurvatureEstimator
        The smoothed second derivatives the local step bends subsets by (all
        probe columns at once: ``estimator(uh, vh, direct=True)``).
    factor : (n, 6) float
        Derivative of the curvature shrinkage at the run's curvature (0 where
        the warp is off: subsets cut by the ROI edge).
    """

    estimator: object
    factor: np.ndarray


def _shrink_gains(smooth, length: float, step: float, subset: int):
    """Curvature noise gains ``(g_xx, g_xy)`` of the run's shrinkage, per node
    when the smoothing length is."""
    from .regularise import curvature_noise_gains

    lengths, inverse = np.unique(np.atleast_1d(np.asarray(smooth, float)), return_inverse=True)
    g = np.array([curvature_noise_gains(float(ell), length, step, subset) for ell in lengths])
    return g[inverse.ravel(), 0], g[inverse.ravel(), 1]


def linearise_admm(solver, iterations: int, mu: float, active, *, second_order: bool = False,
                   uh=None, vh=None, length: float = 0.0, data=None, noise_var=None,
                   smooth=0.0, step: float = 1.0, subset: int = 0) -> ADMMLinearisation:
    """:class:`ADMMLinearisation` of a finished run; with ``second_order`` the
    curvature feedback (``length``: the curvature smoother's, ``data``: nodes
    it fits, ``noise_var`` (n, 2) local variances and ``smooth``, ``step``,
    ``subset`` as the run's shrinkage used them) linearised at ``uh``, ``vh``."""
    if not second_order:
        return ADMMLinearisation(solver, iterations, mu, active)
    from .global_solve import CurvatureEstimator

    gains = None if noise_var is None else _shrink_gains(smooth, length, step, subset)
    est = CurvatureEstimator(solver.mesh, length, data, solver.T, solver.free)
    c0 = est(uh, vh)
    factor = np.ones_like(c0)
    if noise_var is not None and gains is not None:
        var = np.array(noise_var, dtype=float)
        for c in range(2):
            bad = ~np.isfinite(var[:, c])
            var[bad, c] = np.nanmedian(var[:, c]) if (~bad).any() else 0.0
        g = np.column_stack(np.broadcast_arrays(*(np.asarray(x, float) for x in gains)))
        g = np.broadcast_to(g, (c0.shape[0], 2))
        vc = np.concatenate([var[:, c:c + 1] * g[:, [0, 1, 0]] for c in range(2)], axis=1)
        # d/dc [c³ / (c² + v)]: the shrinkage is smooth, its slope 0 at c = 0
        c2 = c0**2
        den = (c2 + vc) ** 2
        factor = np.divide(c2 * (c2 + 3 * vc), den, out=np.ones_like(c2), where=den > 0)
    if data is not None:  # subsets cut by the ROI edge keep the affine warp
        factor[~np.asarray(data, bool)] = 0.0
    return ADMMLinearisation(solver, iterations, mu, active,
                             curvature=CurvatureFeedback(est, factor))


def _local_maps(q, k: int):
    """Per node the matrices of the Local DIC step (``M``, (n, 2k, 2k)) and
    of the penalised translation step (``C``, (n, 2, 2)), and the penalty
    stiffness ``pen / mu`` = ``tr(Σ J Jᵀ) / 2`` of the translation block."""
    m = q.hessian if q.cross is None else q.cross
    idx = [0, k]
    c = m[:, idx][:, :, idx]
    h = q.hessian
    pen = 0.5 * (h[:, 0, 0] + h[:, k, k])
    ok = np.isfinite(m).all(axis=(1, 2)) & (q.m > 2 * k)
    ok &= np.linalg.det(np.where(ok[:, None, None], m, np.eye(2 * k))) > 0
    return m, c, pen, ok


class BatchSolver:
    """:meth:`GlobalSolver.solve` and ``gradients`` for many right-hand sides
    at once (columns: noise images) with the run's factorised matrix; the
    right-hand side is the solver's own (:meth:`GlobalSolver.rhs`). Only
    factorised systems are propagated: past the direct solver's size every
    probe would need its own conjugate-gradient solves, and AL-DIC reports
    the Local model instead (:func:`~.aldic.aldic_stage`)."""

    def __init__(self, solver, threads: int | None = None):
        if solver.system.method != "direct":
            raise ValueError("the AL-DIC noise propagation needs the factorised global "
                             f"system, not {solver.system.method!r} (meshes up to "
                             "DIRECT_MAX_UNKNOWNS free nodes)")
        # all probe columns in one compiled pass over the factor (TriangularSolver)
        self.s, self.system = solver, solver.system.triangular()
        self.threads = threads  # of each solve (TriangularSolver.solve)

    def gradients(self, uh, vh):
        s = self.s
        return np.stack([s.Gx @ uh, s.Gy @ uh, s.Gx @ vh, s.Gy @ vh], axis=1)

    def solve(self, F, W, u, v, vu, vv):
        s = self.s
        k = u.shape[1]
        rhs = s.rhs(F, W, u, v, vu, vv)
        full = s.T @ self.system.solve(rhs, threads=self.threads)
        return full[:, :k], full[:, k:]


def _curvature_coupling(m: np.ndarray, k: int) -> np.ndarray:
    """(n, 2, 6) ``Σ J ∇fᵀ q`` per unit curvature ``(uxx, uxy, uyy, vxx, vxy,
    vyy)``, ``q = dXᵀ (∇∇u) dX / 2``: from the second moments in the blocks of
    ``M`` (entries of the monomials dx, dy)."""
    out = np.empty((m.shape[0], 2, 6))
    for a in range(2):
        for b in range(2):
            blk = m[:, a * k:(a + 1) * k, b * k:(b + 1) * k]
            out[:, a, 3 * b:3 * b + 3] = np.stack(
                [0.5 * blk[:, 1, 1], blk[:, 1, 2], 0.5 * blk[:, 2, 2]], axis=1)
    return np.nan_to_num(out)


def _gradient_coupling(m: np.ndarray, k: int) -> np.ndarray:
    """(n, 2, 4) ``Σ J ∇fᵀ (δF dX)`` per unit gradient error ``(ux, uy, vx, vy)``:
    the first moments in the blocks of ``M`` (the subset is bent by ``F``)."""
    out = np.empty((m.shape[0], 2, 4))
    for a in range(2):
        for b in range(2):
            out[:, a, 2 * b:2 * b + 2] = m[:, a * k, b * k + 1:b * k + 3]
    return np.nan_to_num(out)


def _curvature_change(fb: CurvatureFeedback, uh, vh) -> np.ndarray:
    """(n, 6, K) linearised change of the warp curvature for field errors (n, K):
    all K columns smoothed by one solve with the smoother's factor."""
    return fb.factor[:, :, None] * fb.estimator(uh, vh, direct=True)


def _propagate(solver: BatchSolver, lin: ADMMLinearisation, dp0: np.ndarray, b_t: np.ndarray,
               cinv: np.ndarray, pen: np.ndarray, k: int, coupling: np.ndarray | None,
               fcoupling: np.ndarray):
    """The linearised ADMM run for a batch of noise images (last axis): start
    ``dp0`` (n, 2k, K), local data ``b_t`` (n, 2, K); returns the errors of
    the global ``û``, ``v̂`` (n, K) each."""
    u, v = dp0[:, 0].copy(), dp0[:, k].copy()
    g0 = dp0[:, [1, 2, k + 1, k + 2]]
    W = np.zeros_like(g0)
    vu, vv = np.zeros_like(u), np.zeros_like(u)
    uh, vh = solver.solve(g0, W, u, v, vu, vv)
    act = lin.active[:, None]
    out = ~lin.solver.covered
    for it in range(lin.iterations):
        F = solver.gradients(uh, vh)
        F[out] = g0[out]
        r = b_t + pen[:, None, None] * np.stack([uh + vu, vh + vv], axis=1)
        r -= fcoupling @ F  # the subset is warped by F (stacked products: matmul is 2-4x einsum)
        if lin.curvature is not None:
            # a curvature error bends the subset: the translation takes less
            r -= coupling @ _curvature_change(lin.curvature, uh, vh)
        uv = cinv @ r
        u = np.where(act, uv[:, 0], u)
        v = np.where(act, uv[:, 1], v)
        uh, vh = solver.solve(F, W, u, v, vu, vv)
        if it + 1 < lin.iterations:  # the multipliers of a next iteration
            W += solver.gradients(uh, vh) - F
            vu += uh - u
            vv += vh - v
    return uh, vh


@dataclass
class ProbeMaps:
    """What the propagation needs that does not depend on the ADMM run (only
    on the reference's speckle quality, the probes and ``mu``): computed by
    :func:`probe_maps`, ahead of the run where a core is free.

    Attributes
    ----------
    k : int
        Shape-function terms per component.
    m : (n, 2k, 2k)
        The Local DIC step's matrices; ``ok`` (n,) where usable.
    pen : (n,)
        The local penalty stiffness (``mu`` included; 0 where not ``ok``).
    cinv : (n, 2, 2)
        Inverse of the penalised translation step's matrix; ``good`` (n,)
        where it is positive definite.
    b : (n, 2k, K)
        The probes' subset sums; ``dp0`` (n, 2k, K) the Local start they make.
    """

    k: int
    m: np.ndarray
    ok: np.ndarray
    pen: np.ndarray
    cinv: np.ndarray
    good: np.ndarray
    b: np.ndarray
    dp0: np.ndarray


def probe_maps(q, b: np.ndarray, mu: float) -> ProbeMaps:
    """:class:`ProbeMaps` of the nodes of ``q`` (SpeckleQuality, with the
    run's steepest-descent images), the probes' subset sums ``b`` (n, 2k, K)
    (``project(rng, K)``, see :func:`aldic_gain`) and the penalty ``mu``."""
    k = q.hessian.shape[1] // 2
    m, c, pen, ok = _local_maps(q, k)
    minv = np.zeros_like(m)
    minv[ok] = np.linalg.inv(m[ok])
    pen = mu * np.where(ok, pen, 0.0)
    cp = c + pen[:, None, None] * np.eye(2)
    # 2 x 2: the closed forms (a tenth of LAPACK's batched det and inv)
    det = cp[:, 0, 0] * cp[:, 1, 1] - cp[:, 0, 1] * cp[:, 1, 0]
    good = ok & (det > 0)
    adj = np.stack([cp[:, 1, 1], -cp[:, 0, 1], -cp[:, 1, 0], cp[:, 0, 0]], axis=1)
    cinv = np.where(good[:, None], adj / np.where(good, det, 1.0)[:, None], 0.0).reshape(-1, 2, 2)
    b = np.where(ok[:, None, None], np.nan_to_num(b), 0.0)
    return ProbeMaps(k, m, ok, pen, cinv, good, b, minv @ b)


def aldic_gain(q, project, lin: ADMMLinearisation, maps: ProbeMaps | None = None) -> np.ndarray:
    """Per node the ratio (n, 2) of the std of AL-DIC's ``u``, ``v`` to that
    of the Local DIC subset estimate under the same white image noise.

    Parameters
    ----------
    q : SpeckleQuality
        Of the nodes, with the run's steepest-descent images.
    project : callable(rng, count) -> (n, 2k, count)
        ``Σ_subset J t n`` per node for ``count`` fresh unit white noise
        images ``n`` drawn from ``rng`` (:func:`noise_projector`).
    lin : ADMMLinearisation
    maps : the run-independent part, computed ahead (:func:`probe_maps` of
        ``q``, ``project(np.random.default_rng(lin.seed), lin.probes)`` and
        ``lin.mu``), or None.
    """
    if maps is None:
        maps = probe_maps(q, project(np.random.default_rng(lin.seed), lin.probes), lin.mu)
    k, m, ok, pen, cinv, dp0 = maps.k, maps.m, maps.ok, maps.pen, maps.cinv, maps.dp0
    active = lin.active & maps.good
    lin = ADMMLinearisation(lin.solver, lin.iterations, lin.mu, active, lin.probes, lin.seed,
                            lin.curvature)
    b = maps.b
    # only the nodes whose local result is data (trusted) carry noise into the
    # run: an untrusted node's value enters with a vanishing weight, but the
    # linearisation of its (nearly singular, e.g. textureless) subset is not
    # what the run did, and a huge sensitivity times a tiny weight would
    # still swamp the field
    data = active[:, None, None]
    start, b_t = np.where(data, dp0, 0.0), np.where(data, b[:, [0, k]], 0.0)
    # the probes are independent: in parts side by side, at least two (the
    # propagation's NumPy and SciPy steps release the GIL but run on one thread
    # each); a probe's arithmetic does not depend on the part it is in
    threads = max(2, numba.get_num_threads())
    count = min(threads, lin.probes)
    # each part solves its columns in one pass over the factor (the parts fill the threads)
    solver = BatchSolver(lin.solver, threads=max(1, threads // count))
    if lin.curvature is not None:
        lin.curvature.estimator.factorise()  # shared by all parts
    consts = (cinv, pen, k, None if lin.curvature is None else _curvature_coupling(m, k),
              _gradient_coupling(m, k))
    groups = [g for g in np.array_split(np.arange(lin.probes), count) if g.size]
    parts = side_by_side(lambda c: _propagate(solver, lin, start[..., c], b_t[..., c], *consts),
                         groups, count)
    uh = np.concatenate([p[0] for p in parts], axis=1)
    vh = np.concatenate([p[1] for p in parts], axis=1)
    s_loc = np.stack([np.sum(dp0[:, 0] ** 2, axis=1), np.sum(dp0[:, k] ** 2, axis=1)], axis=1)
    s_glob = np.stack([np.sum(uh**2, axis=1), np.sum(vh**2, axis=1)], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = np.sqrt(s_glob / s_loc)
    return np.where(ok[:, None] & np.isfinite(gain), gain, np.nan)


def noise_projector(jx, jy, x, y, subset: int, roi, terms):
    """A callable ``(rng, count) -> (n, 2k, count)``: for ``count`` fresh
    white noise images of unit variance drawn from ``rng`` (Rademacher: ±1
    at each pixel, see :func:`rademacher_bits`), ``Σ_subset J t n`` per
    node (the right-hand side of the subset's Gauss-Newton step with the
    noise as residual; ``J = (jx, jy)``, ``t`` the shape monomials
    ``terms``, ``dic.quality.SHAPE_TERMS``). Its ``apply(images)`` gives the
    same for given noise images (a list of (H, W) arrays)."""
    h, w = np.shape(jx)
    jx, jy = (np.ascontiguousarray(a, np.float32) for a in (jx, jy))
    mask = (np.zeros((0, 0), np.bool_) if roi is None or bool(np.all(roi))
            else np.ascontiguousarray(roi, np.bool_))
    deg = max(p + q for p, q in terms)
    if deg > MAX_NOISE_ORDER:
        raise ValueError(f"noise_projector: shape terms up to order {MAX_NOISE_ORDER}, "
                         f"got {deg}")
    order_terms = moment_terms(deg)
    col = [order_terms.index(t) for t in terms]
    keep, *lay = _window_layout(np.asarray(x), np.asarray(y), subset // 2, h, w)
    n = np.size(x)
    # the nodes about the image centre, where the kernel's moments are taken
    dx = np.asarray(x, np.float64).ravel()[keep] - 0.5 * (w - 1)
    dy = np.asarray(y, np.float64).ravel()[keep] - 0.5 * (h - 1)
    none8, none32 = np.zeros((0, 0), np.uint8), np.zeros((0, 0, 0), np.float32)
    moments = len(order_terms)
    pick = col + [moments + c for c in col]  # the shape terms of jx, then of jy

    def sums(bits, noise) -> np.ndarray:  # (n, 2k, K): one kernel call, one thread
        k = bits.shape[0] or noise.shape[0]
        raw = np.empty((keep.size, 2 * moments, k))
        noise_window_sums(jx, jy, mask, bits, noise, deg, *lay, raw)
        out = np.zeros((n, len(pick), k))
        out[keep] = _about_nodes(raw, dx, dy, deg)[:, pick]
        return out

    def run(bits=None, noise=None) -> np.ndarray:
        # the probes in groups side by side, one kernel call (one pass over J) each
        count = (bits if bits is not None else noise).shape[0]
        groups = [g for g in np.array_split(np.arange(count), numba.get_num_threads())
                  if g.size]
        parts = side_by_side(lambda g: sums(none8 if bits is None else bits[g],
                                            none32 if noise is None else noise[g]), groups)
        return np.concatenate(parts, axis=2)

    def apply(images) -> np.ndarray:
        return np.concatenate([run(noise=np.asarray(images[c0:c0 + APPLY_CHUNK], np.float32))
                               for c0 in range(0, len(images), APPLY_CHUNK)], axis=2)

    def project(rng, count: int = 1) -> np.ndarray:
        return run(bits=rademacher_bits(rng, (h, w), count))

    project.apply = apply
    return project


#: noise images per kernel call of a projector's ``apply`` (memory: K H W floats)
APPLY_CHUNK = 16


def _about_nodes(raw: np.ndarray, dx: np.ndarray, dy: np.ndarray, order: int) -> np.ndarray:
    """Moments ``Σ a (X - dx)^p (Y - dy)^q`` about each node from ``raw``
    (N, 2 M, K) about the image centre (both halves in ``moment_terms(order)``
    order; ``dx``, ``dy`` (N,): the nodes about the centre), by
    :func:`~..kernels.moments.centre_moments` (one row per node, half and probe)."""
    n, k = raw.shape[0], raw.shape[2]
    rows = np.ascontiguousarray(raw.reshape(n, 2, -1, k).transpose(0, 1, 3, 2))
    rows = rows.reshape(n * 2 * k, -1)
    c = centre_moments(rows, np.repeat(dx, 2 * k), np.repeat(dy, 2 * k), order)
    return c.reshape(n, 2, k, -1).transpose(0, 1, 3, 2).reshape(raw.shape)


def _window_layout(x, y, half: int, h: int, w: int) -> tuple:
    """The node windows of :func:`~..kernels.noise_sums.noise_window_sums`:
    ``keep`` (the nodes whose window holds pixels; the others' sums are 0),
    then its arguments ``edges, e0, e1, col_of, r0, r1, by0, by1`` for them."""
    xi, yi = np.asarray(x, np.int64).ravel(), np.asarray(y, np.int64).ravel()
    c0, c1 = np.clip(xi - half, 0, w), np.clip(xi + half + 1, 0, w)
    r0, r1 = np.clip(yi - half, 0, h), np.clip(yi + half + 1, 0, h)
    keep = np.flatnonzero((c0 < c1) & (r0 < r1))
    cols, col_of = np.unique(xi[keep], return_inverse=True)
    cc0, cc1 = np.clip(cols - half, 0, w), np.clip(cols + half + 1, 0, w)
    edges = np.unique(np.concatenate([cc0, cc1])).astype(np.int64)
    r0, r1 = r0[keep], r1[keep]
    return (keep, edges, np.searchsorted(edges, cc0).astype(np.int64),
            np.searchsorted(edges, cc1).astype(np.int64), col_of.ravel().astype(np.int64),
            r0, r1, np.argsort(r0, kind="stable").astype(np.int64),
            np.argsort(r1, kind="stable").astype(np.int64))


def rademacher_bits(rng, shape, count: int) -> np.ndarray:
    """``count`` images of independent ±1 pixels (equally likely), from
    ``rng``'s random bytes: (count, ceil(size / 8)) uint8, one bit a pixel
    (``np.unpackbits`` order; 1 is +1), the bytes of each image drawn in turn.

    As probes of a linear map ``A`` of white noise (mean 0, variance 1 per
    pixel), ``E[(A z)_i²] = Σ_j A_ij²`` for these as for Gaussian images, with
    a smaller sampling variance, ``2 (Σ_j A_ij²)² - 2 Σ_j A_ij⁴`` against
    ``2 (Σ_j A_ij²)²`` (Hutchinson's estimator); drawing them costs a few
    per cent of Gaussian ones (1 bit a pixel instead of a normal deviate)."""
    nbytes = (int(np.prod(shape)) + 7) // 8
    out = np.empty((count, nbytes), np.uint8)
    for c in range(count):
        out[c] = rng.integers(0, 256, nbytes, dtype=np.uint8)
    return out
