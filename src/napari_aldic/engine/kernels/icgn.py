"""Inverse-compositional Gauss-Newton (IC-GN) kernels.

Two solvers share one skeleton (:mod:`.gauss_newton`; the affine solver
starts, solves and judges a node with :mod:`.icgn_node`, as the quadratic one
does): per chunk of ``CHUNK``
nodes (one parallel task) the work buffers are allocated once; per node the
subset is gathered (:func:`~.subset.gather_subset`), its reference sums are built once
(inverse composition linearises the *reference* subset), and the node runs
Gauss-Newton steps until the update is below ``tol``, the subset leaves the
image or has no texture, the solution wanders off by more than a subset
width, or ``max_iter`` is reached. Each step samples the warped subset in the
deformed image (:func:`~.gauss_newton.gn_step`, one pass of nine sums).

* :func:`icgn_affine`: the six affine parameters ``(u, ux, uy, v, vx, vy)`` (Local DIC);
* :func:`icgn_translation`: the displacement only, gradient held fixed, with
  the AL-DIC penalty towards a target (the local step of ADMM; its per-node
  pieces are in :mod:`.translation`).

References: S. Baker, I. Matthews, "Lucas-Kanade 20 years on", IJCV 56, 2004;
B. Pan, K. Li, W. Tong, "Fast, robust and accurate DIC calculation without
redundant computations", Exp. Mech. 53, 2013.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE, SERIAL, SERIAL_CALLEE
from .gauss_newton import (
    CHUNK,
    NO_TEXTURE,
    NOT_CONVERGED,
    OK,
    chunk_layout,
    gn_step,
    store_node,
)
from .icgn_node import begin_node, lu_solve, solve_buffers, step_status
from .static import zero_motion_evidence
from .subset import gather_gradients, gather_subset, subset_buffers
from .translation import (
    predict_node,
    translation_node,
    translation_step,
)

__all__ = ["icgn_affine", "icgn_translation", "affine_reference_sums", "inverse_compose",
           "affine_step"]


# ------------------------------------------------------------- affine IC-GN
@nb.njit(**INLINE)
def _moment_block(H, r0, c0, m0, mx, my, mxx, mxy, myy):
    """Write the 3 x 3 block ``sum c w w^T`` (``w = (1, dx, dy)``) of ``H`` at
    ``(r0, c0)`` from the six moments of ``c``."""
    H[r0, c0] = m0
    H[r0, c0 + 1] = H[r0 + 1, c0] = mx
    H[r0, c0 + 2] = H[r0 + 2, c0] = my
    H[r0 + 1, c0 + 1] = mxx
    H[r0 + 1, c0 + 2] = H[r0 + 2, c0 + 1] = mxy
    H[r0 + 2, c0 + 2] = myy


@nb.njit(**INLINE, fastmath=FASTMATH)
def _two_blocks(j, ex, ey, dxs, dys, m):
    """The six moments of ``w = (1, dx, dy)`` (``1, dx, dy, dx², dx dy, dy²``)
    weighed by ``j ex``, then those weighed by ``j ey``, over the subset."""
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    c0 = c1 = c2 = c3 = c4 = c5 = 0.0
    for q in range(m):
        dx = dxs[q]
        dy = dys[q]
        xx, xy, yy = dx * dx, dx * dy, dy * dy
        w = j[q] * ex[q]
        a0, a1, a2 = a0 + w, a1 + w * dx, a2 + w * dy
        a3, a4, a5 = a3 + w * xx, a4 + w * xy, a5 + w * yy
        w = j[q] * ey[q]
        c0, c1, c2 = c0 + w, c1 + w * dx, c2 + w * dy
        c3, c4, c5 = c3 + w * xx, c4 + w * xy, c5 + w * yy
    return a0, a1, a2, a3, a4, a5, c0, c1, c2, c3, c4, c5


# called once per node: compiled once as a function (shared by the IC-GN kernels,
# ~2 s less compiling), not inlined; the call costs nothing measurable
@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
def affine_reference_sums(dxs, dys, gx, gy, ex, ey, fs, m, fm, H):
    """Gauss-Newton matrix and sums of the reference subset (affine warp).

    With the steepest-descent images ``J = (gx, gx dx, gx dy, gy, gy dx,
    gy dy)`` and the exact linearisation ``e`` (the same with ``ex, ey``)
    three passes accumulate ``sum J`` and ``sum J (f - fm)``, then the
    instrumental-variable matrix ``H = sum J e^T`` (:func:`_two_blocks`).
    With ``J = e`` it is the symmetric Gauss-Newton Hessian; with smoothed
    ``J`` the step ``H^-1 sum J r`` is still Newton's (the warp is linearised
    with the true gradient), so the iteration converges as fast while it
    solves ``sum J r = 0``.

    Parameters
    ----------
    dxs, dys, gx, gy, fs : 1-D float64
        The gathered subset (``gx, gy``: the steepest-descent gradients).
    ex, ey : 1-D float64
        The exact reference gradients of the same pixels.
    m : int
        Subset pixels.
    fm : float
        Mean of the reference subset.
    H : (6, 6) float64
        Receives the matrix.

    Returns
    -------
    sj0, sj1, sj2, sj3, sj4, sj5 : float
        ``sum J``.
    b00, b01, b02, b03, b04, b05 : float
        ``sum J (f - fm)``.
    """
    sj0 = sj1 = sj2 = sj3 = sj4 = sj5 = 0.0
    b00 = b01 = b02 = b03 = b04 = b05 = 0.0
    for q in range(m):
        dx = dxs[q]
        dy = dys[q]
        ja = gx[q]
        jd = gy[q]
        fv = fs[q] - fm
        jax, jay, jdx, jdy = ja * dx, ja * dy, jd * dx, jd * dy
        sj0 += ja
        sj1 += jax
        sj2 += jay
        sj3 += jd
        sj4 += jdx
        sj5 += jdy
        b00 += ja * fv
        b01 += jax * fv
        b02 += jay * fv
        b03 += jd * fv
        b04 += jdx * fv
        b05 += jdy * fv
    # H is four 3 x 3 blocks sum (jx|jy)(ex|ey) w w^T with w = (1, dx, dy): six
    # moments of w per gradient product, 24 sums per pixel instead of 36, in
    # scalars, two blocks per pass: 12 sums a loop keep LLVM's vectorised
    # reductions in registers (one pass of all 36 sums spilled them: 4.0
    # against 2.9 us a node, one thread, 961 pixels)
    a0, a1, a2, a3, a4, a5, c0, c1, c2, c3, c4, c5 = _two_blocks(gx, ex, ey, dxs, dys, m)
    d0, d1, d2, d3, d4, d5, e0, e1, e2, e3, e4, e5 = _two_blocks(gy, ex, ey, dxs, dys, m)
    _moment_block(H, 0, 0, a0, a1, a2, a3, a4, a5)
    _moment_block(H, 0, 3, c0, c1, c2, c3, c4, c5)
    _moment_block(H, 3, 0, d0, d1, d2, d3, d4, d5)
    _moment_block(H, 3, 3, e0, e1, e2, e3, e4, e5)
    return sj0, sj1, sj2, sj3, sj4, sj5, b00, b01, b02, b03, b04, b05


@nb.njit(**INLINE, fastmath=FASTMATH)
def inverse_compose(p, du, dux, duy, dv, dvx, dvy):
    """Inverse-compositional update ``W(p) <- W(p) o W(dp)^-1``.

    Parameters
    ----------
    p : 6-tuple of float
        Current ``(u, ux, uy, v, vx, vy)``.
    du, dux, duy, dv, dvx, dvy : float
        The Gauss-Newton increment ``dp`` (already negated: ``-H^-1 b``).

    Returns
    -------
    6-tuple of float
        The composed parameters.
    """
    u, ux, uy, v, vx, vy = p
    a11 = 1.0 + dux
    a12 = duy
    a21 = dvx
    a22 = 1.0 + dvy
    det = a11 * a22 - a12 * a21
    i11 = a22 / det
    i12 = -a12 / det
    i21 = -a21 / det
    i22 = a11 / det
    it1 = -(i11 * du + i12 * dv)
    it2 = -(i21 * du + i22 * dv)
    m11 = 1.0 + ux
    m12 = uy
    m21 = vx
    m22 = 1.0 + vy
    n11 = m11 * i11 + m12 * i21
    n12 = m11 * i12 + m12 * i22
    n21 = m21 * i11 + m22 * i21
    n22 = m21 * i12 + m22 * i22
    return (m11 * it1 + m12 * it2 + u, n11 - 1.0, n12,
            m21 * it1 + m22 * it2 + v, n21, n22 - 1.0)


@nb.njit(**INLINE, fastmath=FASTMATH)
def affine_step(c1, stride, coef, order, x0, y0, p, dxs, dys, gx, gy, fs, m, fm, dfn,
                xw, yw, gv, xmax, ymax, sj, bf, fac, b, dp, h, span, start, tol, zn):
    """One affine IC-GN step of a node.

    Samples the warped subset (:func:`~.gauss_newton.gn_step`), forms
    ``b = sum J [(f - fm) - (df/dg)(g - gm)]``, solves ``H dp = -b`` with the
    factors ``fac`` and composes the inverse increment into ``p``.

    Parameters
    ----------
    c1, stride, coef, order, x0, y0, dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv
        As :func:`~.gauss_newton.gn_step`.
    xmax, ymax
        As :func:`~.gauss_newton.gn_step`.
    p : 6-tuple of float
        Current parameters.
    sj, bf : 6-tuples of float
        Reference sums from :func:`affine_reference_sums`.
    fac : ((6, 6) float64, (6,) int64)
        Factors of the reference matrix and their row swaps
        (:func:`~.icgn_node.lu_factor`).
    b, dp : (6,) float64
        Work arrays.
    h, span : int
        Subset half-width and width.
    start : (float, float)
        Starting ``(u, v)`` (divergence test).
    tol : float
        Convergence tolerance on the increment (pixels).
    zn : float
        ZNCC of the previous step.

    Returns
    -------
    status : int
        ``NOT_CONVERGED`` to go on, ``OK`` when the increment norm
        ``|du|^2 + |dv|^2 + h^2 |dF|^2`` is below ``tol^2``, else the failure.
    zn : float
        ZNCC of this step (unchanged if the step failed).
    p : 6-tuple of float
        Updated parameters (unchanged if the step failed).
    """
    u, ux, uy, v, vx, vy = p
    # np.bool_, not a literal False: gn_step would compile apart from the
    # translation solver's (a run-time flag there)
    st, zn_k, r, gm, t0, t1, t2, t3, t4, t5 = gn_step(
        c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
        dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, np.bool_(False), xw, yw)
    if st != OK:
        return st, zn, p
    # b = sum J [(f - fm) - (df/dg)(g - gm)];  H dp = -b
    b[0] = bf[0] - r * (t0 - gm * sj[0])
    b[1] = bf[1] - r * (t1 - gm * sj[1])
    b[2] = bf[2] - r * (t2 - gm * sj[2])
    b[3] = bf[3] - r * (t3 - gm * sj[3])
    b[4] = bf[4] - r * (t4 - gm * sj[4])
    b[5] = bf[5] - r * (t5 - gm * sj[5])
    lu_solve(fac[0], fac[1], b, dp)
    du = -dp[0]
    dux = -dp[1]
    duy = -dp[2]
    dv = -dp[3]
    dvx = -dp[4]
    dvy = -dp[5]
    p = inverse_compose(p, du, dux, duy, dv, dvx, dvy)
    nrm = du * du + dv * dv + h * h * (dux * dux + duy * duy + dvx * dvx + dvy * dvy)
    return step_status(p[0] - start[0], p[3] - start[1], span, nrm, tol), zn_k, p


@nb.njit(**SERIAL, fastmath=FASTMATH)
def icgn_affine(first, stop, f, fgx, fgy, egx, egy, coef, order, nx, ny, p_init, active, slot,
                masks, h, max_iter, tol, p_out, zncc_out, iters_out, reason_out, stats_out,
                g, static, static_out):
    """Affine IC-GN at the ``active`` nodes of chunks ``first`` to ``stop``
    (``CHUNK`` nodes each; ``dic.threads.in_threads`` runs ranges side by side).

    Per node: gather the subset, build the reference matrix and its LU
    factors (:func:`~.icgn_node.begin_node`; a node without texture is stored
    as ``NO_TEXTURE`` with its initial parameters), then iterate
    :func:`affine_step` while it reports ``NOT_CONVERGED`` and ``max_iter``
    allows.

    Parameters
    ----------
    first, stop : int
        The chunks to solve (nodes ``first * CHUNK`` to ``stop * CHUNK``).
    f, fgx, fgy : (H, W) float32
        Reference image and the gradients of its steepest-descent images
        (possibly smoothed).
    egx, egy : (H, W) float32
        The reference's exact spline gradients (the warp's linearisation;
        the same arrays as ``fgx, fgy`` for plain Gauss-Newton).
    coef : (H + 2 PAD, W + 2 PAD) float32
        Deformed-image B-spline coefficients; ``order`` 3 or 5.
    nx, ny : (n,) int64
        Node pixels.
    p_init : (n, 6) float64
        Initial ``(u, ux, uy, v, vx, vy)``.
    active : (n,) bool
        Nodes to solve; the others are left untouched.
    slot, masks
        Mask slot per node and the component masks of the cut nodes.
    h, max_iter, tol
        Subset half-width, iteration cap, convergence tolerance.
    p_out, zncc_out, iters_out, reason_out : (n, 6), (n,), (n,), (n,)
        Receive parameters, ZNCC, iterations and status.
    stats_out : (n, 5) float64
        Receives the reference subset's statistics (:func:`~.subset.subset_stats`).
    g, static, static_out : (H, W) float32, (float, float, float), (n or 0, 2) float64
        Deformed image; noise variance of one image, least motion (px) and
        the share ``S / D`` above which ``z`` is computed; receives
        :func:`~.static.zero_motion_evidence` of the converged nodes moved
        that far, from the last step's samples (else NaN; no rows: off).
    """
    n = nx.size
    c1, stride, span, npx, _, xmax, ymax = chunk_layout(f, coef, n, h)
    test_static = static_out.shape[0] == n
    for c in range(first, stop):
        dxs, dys, gx, gy, fs, xw, yw, gv = subset_buffers(npx)
        ex = np.empty(npx)
        ey = np.empty(npx)
        LU, piv, b, dp = solve_buffers(6)
        H = np.empty((6, 6))
        for k in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if not active[k]:
                continue
            x0, y0, m, fm, df2 = gather_subset(f, fgx, fgy, masks, slot, nx, ny, k, h,
                                               dxs, dys, gx, gy, fs)
            hs = gather_gradients(egx, egy, masks, slot, nx, ny, k, h, ex, ey)
            sj0, sj1, sj2, sj3, sj4, sj5, b00, b01, b02, b03, b04, b05 = affine_reference_sums(
                dxs, dys, gx, gy, ex, ey, fs, m, fm, H)
            sj = (sj0, sj1, sj2, sj3, sj4, sj5)
            bf = (b00, b01, b02, b03, b04, b05)
            p = (p_init[k, 0], p_init[k, 1], p_init[k, 2], p_init[k, 3], p_init[k, 4],
                 p_init[k, 5])
            status, zn, it, dfn = begin_node(k, m, df2, hs, H, LU, piv, stats_out)
            start = (p[0], p[3])
            while status == NOT_CONVERGED and it < max_iter:
                it += 1
                status, zn, p = affine_step(c1, stride, coef, order, x0, y0, p, dxs, dys, gx,
                                            gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, sj,
                                            bf, (LU, piv), b, dp, h, span, start, tol, zn)
            store_node(k, p, zn, it, status, p_out, zncc_out, iters_out, reason_out)
            if test_static:
                # the last step sampled the subset within tol of the final warp
                static_out[k, 0] = static_out[k, 1] = np.nan
                if status == OK and p[0] * p[0] + p[3] * p[3] >= static[1] * static[1]:
                    static_out[k, 0], static_out[k, 1] = zero_motion_evidence(
                        g, x0, y0, dxs, dys, fs, gv, m, static[0], xw, yw, static[2])


# ------------------------------------------------------------- translation IC-GN
@nb.njit(**SERIAL, fastmath=FASTMATH)
def icgn_translation(first, stop, f, fgx, fgy, egx, egy, coef, order, nx, ny, uv_init, grad, curv,
                     target, prior, settled, reach, mu, active, slot, masks, h, max_iter, tol,
                     uv_out, zncc_out, iters_out, reason_out):
    """Penalised IC-GN of the displacement at the ``active`` nodes of chunks
    ``first`` to ``stop`` (AL-DIC; chunks as :func:`icgn_affine`).

    Per node: with ``prior``, the linear prediction of the penalised optimum
    (:func:`predict_node`), which a ``settled`` node whose samples moved within
    ``reach`` takes with nothing gathered or sampled (0 iterations, ZNCC NaN:
    not measured again). Otherwise gather the subset (:func:`translation_node`;
    a node without texture is stored as ``NO_TEXTURE`` at its start) and
    iterate :func:`translation_step` from the prediction while it reports
    ``NOT_CONVERGED`` and ``max_iter`` allows (mostly once).

    Parameters
    ----------
    first, stop, f, fgx, fgy, egx, egy, coef, order, nx, ny, active, slot, masks, h,
    max_iter, tol
        As :func:`icgn_affine`.
    uv_init : (n, 2) float64
        Starting displacements.
    grad : (n, 4) float64
        Fixed gradients ``(ux, uy, vx, vy)``.
    curv : (n, 6) or (0, 6) float64
        Second derivatives of the warp, or no rows for an affine warp.
    target : (n, 2) float64
        Penalty targets.
    prior : (n, 12) or (0, 12) float64
        The targets, gradients and second derivatives the starts were
        optimal for (a Local DIC start: the start itself, no penalty, its own
        gradient and no curvature), or no rows: start where ``uv_init`` says
        (:func:`predicted_start`).
    settled : (n,) bool
        Nodes whose start is an optimum found by sampling (within ``tol``);
        only these may take the prediction unsampled.
    reach : (float, float)
        ``(px, misfit px)``: how far the samples may have moved for that
        (:func:`prediction_holds`); ``(0, 0)``: always sample.
    mu : float
        Dimensionless penalty weight.
    uv_out, zncc_out, iters_out, reason_out : (n, 2), (n,), (n,), (n,)
        Receive displacement, ZNCC, iterations and status.
    """
    n = nx.size
    c1, stride, span, npx, _, xmax, ymax = chunk_layout(f, coef, n, h)
    quad = curv.shape[0] == n
    for c in range(first, stop):
        dxs, dys, gx, gy, fs, xw, yw, gv = subset_buffers(npx)
        ex = np.empty(npx)
        ey = np.empty(npx)
        qx = np.zeros(npx)
        qy = np.zeros(npx)
        mom = np.empty((4, 6))
        for k in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if not active[k]:
                continue
            start = (uv_init[k, 0], uv_init[k, 1])
            u, v = start
            if prior.shape[0] == n:
                u, v, taken = predict_node(k, u, v, fgx, fgy, egx, egy, masks, slot, nx, ny,
                                           h, mom, prior, target, grad, curv, quad, mu,
                                           settled, reach, xmax, ymax)
                if taken:
                    store_node(k, (u, v), np.nan, 0, OK, uv_out, zncc_out, iters_out,
                               reason_out)
                    continue
            x0, y0, m, fm, dfn, node = translation_node(
                f, fgx, fgy, egx, egy, masks, slot, nx, ny, k, h, grad, curv, quad, target,
                start, mu, dxs, dys, gx, gy, fs, ex, ey, qx, qy)
            if dfn == 0.0:
                store_node(k, start, np.nan, 0, NO_TEXTURE, uv_out, zncc_out, iters_out,
                           reason_out)
                continue
            status, zn, it = NOT_CONVERGED, np.nan, 0
            while status == NOT_CONVERGED and it < max_iter:
                it += 1
                status, zn, u, v = translation_step(
                    c1, stride, coef, order, x0, y0, u, v, dxs, dys, gx, gy, fs, m, fm, dfn,
                    xw, yw, gv, xmax, ymax, quad, qx, qy, node, span, tol, zn)
            store_node(k, (u, v), zn, it, status, uv_out, zncc_out, iters_out, reason_out)
