"""The per-node pieces of AL-DIC's local step (:func:`~.icgn.icgn_translation`):
IC-GN of a subset's displacement with its gradient held fixed and a penalty
towards the global field. First the start is moved to the linear prediction
of the optimum (:func:`predict_node`: the subset's moments read from the
gradient images, :func:`prediction_moments`; the penalised 2 x 2 system,
:func:`penalty_system`; :func:`predicted_start`), which a node whose samples
barely moved takes as its solution (:func:`prediction_holds`). The others
gather their subset (:func:`translation_node`: the reference sums,
:func:`translation_reference_sums`; the second-order warp's fixed offsets,
:func:`curvature_offsets`) and go on with :func:`translation_step`, sampling
the deformed image until the update is below ``tol``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE
from .gauss_newton import DIVERGED, NOT_CONVERGED, OK, gn_step
from .subset import gather_gradients, gather_subset

__all__ = ["translation_reference_sums", "prediction_moments", "predicted_start",
           "prediction_holds", "predict_node", "translation_node",
           "curvature_offsets",
           "penalty_system", "translation_step"]


@nb.njit(**INLINE, fastmath=FASTMATH)
def translation_reference_sums(gx, gy, ex, ey, fs, m, fm):
    """Gauss-Newton sums of the reference subset for the displacement only.

    Parameters
    ----------
    gx, gy, fs : 1-D float64
        Steepest-descent gradients and values of the gathered subset.
    ex, ey : 1-D float64
        Its exact reference gradients (the linearisation).
    m : int
        Subset pixels.
    fm : float
        Mean of the reference subset.

    Returns
    -------
    h00, h01, h10, h11 : float
        The 2 x 2 matrix ``sum [gx gy]^T [ex ey]`` (instrumental variables,
        as :func:`affine_reference_sums`).
    sj0, sj3 : float
        ``sum gx``, ``sum gy``.
    b0, b3 : float
        ``sum gx (f - fm)``, ``sum gy (f - fm)``.
    """
    h00 = h01 = h10 = h11 = sj0 = sj3 = b0 = b3 = 0.0
    for q in range(m):
        a1 = gx[q]
        a2 = gy[q]
        fv = fs[q] - fm
        h00 += a1 * ex[q]
        h01 += a1 * ey[q]
        h10 += a2 * ex[q]
        h11 += a2 * ey[q]
        sj0 += a1
        sj3 += a2
        b0 += a1 * fv
        b3 += a2 * fv
    return h00, h01, h10, h11, sj0, sj3, b0, b3


@nb.njit(**INLINE, fastmath=FASTMATH)
def prediction_moments(fgx, fgy, egx, egy, masks, slot, nx, ny, k, h, mom):
    """The subset sums a prediction needs, read straight from the images.

    For the products ``gx ex, gx ey, gy ex, gy ey`` of the steepest-descent
    and the exact reference gradients (rows of ``mom``), their sums over node
    ``k``'s subset (its mask component) weighted by ``1, dx, dy, dx², dx dy,
    dy²`` (columns). Column 0 is :func:`translation_reference_sums`' 2 x 2
    matrix; the others give any affine or quadratic change of the warp's
    effect on the data term's gradient. One pass, without gathering the
    subset: a node that takes its prediction reads nothing else.

    Parameters
    ----------
    fgx, fgy, egx, egy : (H, W) float32
        Steepest-descent and exact reference gradients.
    masks, slot, nx, ny, k, h
        As :func:`~.subset.gather_subset`.
    mom : (4, 6) float64
        Receives the sums.
    """
    x0 = nx[k]
    y0 = ny[k]
    sl = slot[k]
    mom[:, :] = 0.0
    for a in range(-h, h + 1):
        # per row: the four products' sums weighted by 1, dx and dx²; dy is the row's
        zero = (0.0, 0.0, 0.0, 0.0)
        s0, s1, s2 = zero, zero, zero
        for bb in range(-h, h + 1):
            w = 1.0
            if sl >= 0 and masks[sl, a + h, bb + h] == 0:
                w = 0.0
            gxv = w * fgx[y0 + a, x0 + bb]
            gyv = w * fgy[y0 + a, x0 + bb]
            exv = np.float64(egx[y0 + a, x0 + bb])
            eyv = np.float64(egy[y0 + a, x0 + bb])
            d = np.float64(bb)
            p = (gxv * exv, gxv * eyv, gyv * exv, gyv * eyv)
            s0 = _weighted_add(s0, p, 1.0)
            s1 = _weighted_add(s1, p, d)
            s2 = _weighted_add(s2, p, d * d)
        for i in range(4):
            mom[i, 0] += s0[i]
            mom[i, 1] += s1[i]
            mom[i, 2] += a * s0[i]
            mom[i, 3] += s2[i]
            mom[i, 4] += a * s1[i]
            mom[i, 5] += a * a * s0[i]


@nb.njit(**INLINE, fastmath=FASTMATH)
def _weighted_add(acc, p, w):
    """``acc + w p`` for 4-tuples (sums held in registers)."""
    return (acc[0] + w * p[0], acc[1] + w * p[1], acc[2] + w * p[2], acc[3] + w * p[3])


@nb.njit(**INLINE, fastmath=FASTMATH)
def predicted_start(u, v, prior, k, tu, tv, system, mom, grad, curv, quad, h):
    """The start moved one linear step, to the predicted penalised optimum.

    ``(u, v)`` was optimal for the target ``prior[k, :2]`` with the gradient
    ``prior[k, 2:6]`` and the second derivatives ``prior[k, 6:]``: there the
    data term's gradient was ``pen Aᵀ (u - prior)``. Holding the subset at the
    new gradient ``grad[k]`` and curvature (``curv[k]`` when ``quad``) moves
    each warped sample by ``a = δF dx + ½ dxᵀ δ∇∇u dx``, which changes that
    gradient by about ``-Σ J ∇fᵀ a`` (the moments of
    :func:`prediction_moments`). :func:`translation_step`'s update with that
    gradient (``system``: :func:`penalty_system`'s, target ``tu, tv``),
    without sampling the deformed image.

    Returns
    -------
    u, v : float
        The predicted optimum.
    shift : float
        A bound on ``|a|`` over the subset (px, half-width ``h``): with
        ``|(u, v) - start|`` a bound on how far any sample moved from where
        it was optimal.
    """
    a11, a12, a21, a22, pen, m00, m01, m10, m11, det = system
    # the warp change, as coefficients of dx, dy, dx², dx dy, dy² (u, then v)
    u1 = grad[k, 0] - prior[k, 2]
    u2 = grad[k, 1] - prior[k, 3]
    v1 = grad[k, 2] - prior[k, 4]
    v2 = grad[k, 3] - prior[k, 5]
    u3, u4, u5 = -prior[k, 6], -prior[k, 7], -prior[k, 8]
    v3, v4, v5 = -prior[k, 9], -prior[k, 10], -prior[k, 11]
    if quad:
        u3 += curv[k, 0]
        u4 += curv[k, 1]
        u5 += curv[k, 2]
        v3 += curv[k, 3]
        v4 += curv[k, 4]
        v5 += curv[k, 5]
    u3 *= 0.5
    u5 *= 0.5
    v3 *= 0.5
    v5 *= 0.5
    c0 = (u1 * mom[0, 1] + u2 * mom[0, 2] + u3 * mom[0, 3] + u4 * mom[0, 4] + u5 * mom[0, 5]
          + v1 * mom[1, 1] + v2 * mom[1, 2] + v3 * mom[1, 3] + v4 * mom[1, 4] + v5 * mom[1, 5])
    c1 = (u1 * mom[2, 1] + u2 * mom[2, 2] + u3 * mom[2, 3] + u4 * mom[2, 4] + u5 * mom[2, 5]
          + v1 * mom[3, 1] + v2 * mom[3, 2] + v3 * mom[3, 3] + v4 * mom[3, 4] + v5 * mom[3, 5])
    pu = prior[k, 0] - tu
    pv = prior[k, 1] - tv
    r0 = pen * (a11 * pu + a21 * pv) + c0
    r1 = pen * (a12 * pu + a22 * pv) + c1
    d0 = (m11 * r0 - m01 * r1) / det
    d1 = (m00 * r1 - m10 * r0) / det
    # |a|: the affine part is largest at a corner of the square, the
    # quadratic part at most its coefficients' sum times h²
    corner = max((u1 + u2) ** 2 + (v1 + v2) ** 2, (u1 - u2) ** 2 + (v1 - v2) ** 2)
    bend = np.hypot(abs(u3) + abs(u4) + abs(u5), abs(v3) + abs(v4) + abs(v5))
    shift = h * np.sqrt(corner) + h * h * bend
    return u - (a11 * d0 + a12 * d1), v - (a21 * d0 + a22 * d1), shift


@nb.njit(**INLINE, fastmath=FASTMATH)
def translation_node(f, fgx, fgy, egx, egy, masks, slot, nx, ny, k, h, grad, curv, quad,
                     target, start, mu, dxs, dys, gx, gy, fs, ex, ey, qx, qy):
    """Node ``k``'s subset gathered for sampled steps: its pixels (into the
    buffers ``dxs ... ey``; ``qx, qy``: the second-order offsets when
    ``quad``), reference sums and penalised system.

    Returns
    -------
    x0, y0, m, fm : int, int, int, float
        As :func:`~.subset.gather_subset`.
    dfn : float
        ``sqrt(sum (f - fm)^2)``; 0 when the subset has no texture.
    node : tuple
        The constants of :func:`translation_step` (divergence measured from
        ``start``).
    """
    x0, y0, m, fm, df2 = gather_subset(f, fgx, fgy, masks, slot, nx, ny, k, h, dxs, dys, gx,
                                       gy, fs)
    gather_gradients(egx, egy, masks, slot, nx, ny, k, h, ex, ey)
    if quad:
        curvature_offsets(curv, k, dxs, dys, m, qx, qy)
    h00, h01, h10, h11, sj0, sj3, b0, b3 = translation_reference_sums(gx, gy, ex, ey, fs, m,
                                                                       fm)
    ux, uy, vx, vy = grad[k, 0], grad[k, 1], grad[k, 2], grad[k, 3]
    a11, a12, a21, a22, pen, m00, m01, m10, m11, det = penalty_system(
        h00, h01, h10, h11, ux, uy, vx, vy, mu)
    node = (ux, uy, vx, vy, sj0, sj3, b0, b3, a11, a12, a21, a22, pen, m00, m01, m10, m11, det,
            target[k, 0], target[k, 1], start[0], start[1])
    if df2 <= 1e-6 * m or not _invertible(h00, h01, h10, h11):
        return x0, y0, m, fm, 0.0, node
    return x0, y0, m, fm, np.sqrt(df2), node


@nb.njit(**INLINE, fastmath=FASTMATH)
def _invertible(h00, h01, h10, h11):
    """Whether the subset's 2 x 2 reference matrix is far from singular (a
    subset textured in both directions; NaN sums are not)."""
    return h00 * h11 - h01 * h10 > 1e-12 * (h00 + h11) ** 2


@nb.njit(**INLINE, fastmath=FASTMATH)
def predict_node(k, u, v, fgx, fgy, egx, egy, masks, slot, nx, ny, h, mom, prior, target,
                 grad, curv, quad, mu, settled, reach, xmax, ymax):
    """Node ``k``'s predicted optimum from its start ``u, v`` (the start
    itself when its subset has no texture) and whether it is taken without
    sampling: :func:`prediction_moments` (into ``mom``), :func:`penalty_system`,
    :func:`predicted_start` and, for a ``settled`` node, :func:`prediction_holds`
    with ``reach = (px, misfit px)``."""
    prediction_moments(fgx, fgy, egx, egy, masks, slot, nx, ny, k, h, mom)
    h00, h01, h10, h11 = mom[0, 0], mom[1, 0], mom[2, 0], mom[3, 0]
    if not _invertible(h00, h01, h10, h11):
        return u, v, False
    system = penalty_system(h00, h01, h10, h11, grad[k, 0], grad[k, 1], grad[k, 2],
                            grad[k, 3], mu)
    up, vp, shift = predicted_start(u, v, prior, k, target[k, 0], target[k, 1], system, mom,
                                    grad, curv, quad, h)
    moved = shift + np.sqrt((up - u) ** 2 + (vp - v) ** 2)
    return up, vp, settled[k] and prediction_holds(
        moved, h00, h01, h10, h11, reach[0], reach[1], nx[k], ny[k], up, vp, grad, curv, k,
        quad, h, xmax, ymax)


@nb.njit(**INLINE, fastmath=FASTMATH)
def prediction_holds(moved, h00, h01, h10, h11, reach, misfit, x0, y0, u, v, grad, curv, k,
                     quad, h, xmax, ymax):
    """Whether a settled node's predicted optimum is taken without sampling.

    Every sample moved by at most ``moved`` px from where the subset was
    optimal (and sampled). Below ``reach`` the prediction's error is second
    order in ``moved`` (well under ``tol``); below ``misfit`` as a misfit of
    the subset (``moved`` scaled by ``sqrt(tr H / λ_min H)``: an elongated
    texture loses more correlation along its weak direction) the lower ZNCC
    the sample would measure could not fail the global-mismatch test. The
    warped subset must also stay inside the image (a bound from the node's
    warp, without the samples).
    """
    if not moved <= reach:
        return False
    tr = h00 + h11
    hs = 0.5 * (h01 + h10)
    lam = 0.5 * (tr - np.sqrt((h00 - h11) ** 2 + 4.0 * hs * hs))
    if not (lam > 0.0 and moved * moved * tr <= misfit * misfit * lam):
        return False
    bend_x = bend_y = 0.0
    if quad:
        bend_x = 0.5 * h * h * (abs(curv[k, 0]) + 2.0 * abs(curv[k, 1]) + abs(curv[k, 2]))
        bend_y = 0.5 * h * h * (abs(curv[k, 3]) + 2.0 * abs(curv[k, 4]) + abs(curv[k, 5]))
    rx = h * (1.0 + abs(grad[k, 0]) + abs(grad[k, 1])) + bend_x
    ry = h * (1.0 + abs(grad[k, 2]) + abs(grad[k, 3])) + bend_y
    return (x0 + u - rx >= 0.0 and y0 + v - ry >= 0.0 and x0 + u + rx <= xmax
            and y0 + v + ry <= ymax)


@nb.njit(**INLINE, fastmath=FASTMATH)
def curvature_offsets(curv, k, dxs, dys, m, qx, qy):
    """Fixed second-order part of node ``k``'s warp, from the global field.

    Parameters
    ----------
    curv : (n, 6) float64
        ``(uxx, uxy, uyy, vxx, vxy, vyy)`` per node (1/px).
    k : int
        Node index.
    dxs, dys : 1-D float64
        Subset pixel offsets.
    m : int
        Subset pixels.
    qx, qy : 1-D float64
        Receive ``0.5 dX^T (grad grad u) dX`` and the same for ``v``.
    """
    for q in range(m):
        dx = dxs[q]
        dy = dys[q]
        qx[q] = 0.5 * curv[k, 0] * dx * dx + curv[k, 1] * dx * dy \
            + 0.5 * curv[k, 2] * dy * dy
        qy[q] = 0.5 * curv[k, 3] * dx * dx + curv[k, 4] * dx * dy \
            + 0.5 * curv[k, 5] * dy * dy


@nb.njit(**INLINE, fastmath=FASTMATH)
def penalty_system(h00, h01, h10, h11, ux, uy, vx, vy, mu):
    """Matrix of the penalised displacement step, constant per node.

    ``A = I + F`` maps a reference-frame shift to a deformed-frame shift; the
    penalty stiffness ``mu (h00 + h11) / 2`` scales ``mu`` to the data term.

    Parameters
    ----------
    h00, h01, h10, h11 : float
        Reference 2 x 2 matrix (:func:`translation_reference_sums`).
    ux, uy, vx, vy : float
        The fixed displacement gradient.
    mu : float
        Dimensionless penalty weight.

    Returns
    -------
    a11, a12, a21, a22 : float
        ``A``.
    pen : float
        Penalty stiffness.
    m00, m01, m10, m11 : float
        ``H + pen A^T A``.
    det : float
        Its determinant.
    """
    a11 = 1.0 + ux
    a12 = uy
    a21 = vx
    a22 = 1.0 + vy
    pen = mu * 0.5 * (h00 + h11)  # penalty stiffness, scaled to the data term
    # (H + pen A^T A), constant over the iterations
    c01 = pen * (a11 * a12 + a21 * a22)
    m00 = h00 + pen * (a11 * a11 + a21 * a21)
    m01 = h01 + c01
    m10 = h10 + c01
    m11 = h11 + pen * (a12 * a12 + a22 * a22)
    det = m00 * m11 - m01 * m10
    return a11, a12, a21, a22, pen, m00, m01, m10, m11, det


@nb.njit(**INLINE, fastmath=FASTMATH)
def translation_step(c1, stride, coef, order, x0, y0, u, v, dxs, dys, gx, gy, fs, m, fm,
                     dfn, xw, yw, gv, xmax, ymax, quad, qx, qy, node, span, tol, zn):
    """One penalised IC-GN step of a node's displacement (gradient fixed).

    Samples the warped subset (:func:`~.gauss_newton.gn_step`) and solves
    ``(H + pen A^T A) d = -g + pen A^T (u - t)`` for the reference-frame
    increment ``d``; the displacement moves by ``A d``.

    Parameters
    ----------
    c1, stride, coef, order, x0, y0, dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv
        As :func:`~.gauss_newton.gn_step`.
    xmax, ymax, quad, qx, qy
        As :func:`~.gauss_newton.gn_step`.
    u, v : float
        Current displacement.
    node : tuple of float
        The node's constants: fixed gradient ``(ux, uy, vx, vy)``, reference
        sums ``(sj0, sj3, b0, b3)`` (:func:`translation_reference_sums`), the
        penalised system (:func:`penalty_system`), the penalty target
        ``(tu, tv)`` and the starting displacement ``(u0, v0)`` (divergence test).
    span, tol : int, float
        Subset width; convergence tolerance (pixels).
    zn : float
        ZNCC of the previous step.

    Returns
    -------
    status : int
        ``NOT_CONVERGED`` to go on, ``OK`` when ``|A d| < tol``,
        else the failure.
    zn : float
        ZNCC of this step (unchanged if the step failed).
    u, v : float
        Updated displacement (unchanged if the step failed).
    """
    (ux, uy, vx, vy, sj0, sj3, b0, b3, a11, a12, a21, a22, pen, m00, m01, m10, m11, det,
     tu, tv, u0, v0) = node
    st, zn_k, r, gm, t0, t1, t2, t3, t4, t5 = gn_step(
        c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
        dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, quad, qx, qy)
    if st != OK:
        return st, zn, u, v
    g0 = b0 - r * (t0 - gm * sj0)
    g3 = b3 - r * (t3 - gm * sj3)
    # (H + pen A^T A) d = -g + pen A^T (u - t)
    eu = u - tu
    ev = v - tv
    r0 = -g0 + pen * (a11 * eu + a21 * ev)
    r1 = -g3 + pen * (a12 * eu + a22 * ev)
    d0 = (m11 * r0 - m01 * r1) / det
    d1 = (m00 * r1 - m10 * r0) / det
    du = a11 * d0 + a12 * d1
    dv = a21 * d0 + a22 * d1
    u -= du
    v -= dv
    if abs(u - u0) > span or abs(v - v0) > span or not np.isfinite(u + v):
        return DIVERGED, zn_k, u, v
    if du * du + dv * dv < tol * tol:
        return OK, zn_k, u, v
    return NOT_CONVERGED, zn_k, u, v
