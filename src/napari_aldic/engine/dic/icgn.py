"""Inverse-compositional Gauss-Newton (IC-GN) subset matching.

Affine (first-order) shape function with parameters
``p = (u, du/dx, du/dy, v, dv/dx, dv/dy)``: the subset pixel at offset
``(dx, dy)`` from the node maps to
``(x0 + dx + u + ux*dx + uy*dy, y0 + dy + v + vx*dx + vy*dy)``.
The matching criterion is the zero-normalised sum of squared differences
(ZNSSD), robust to affine grey-level changes. The inverse-compositional
update linearises the *reference* subset, so the Gauss-Newton Hessian is
built once per node and every iteration only samples the deformed image
(B-spline, precomputed coefficients) and accumulates nine sums in a single
pass.

References: S. Baker, I. Matthews, "Lucas-Kanade 20 years on", IJCV 56, 2004;
B. Pan, K. Li, W. Tong, "Fast, robust and accurate DIC calculation without
redundant computations", Exp. Mech. 53, 2013.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..core.reasons import Reason
from .interpolation import PAD

# fast-math without the no-NaN/no-inf assumptions, so NaN checks survive
_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}

__all__ = ["icgn_solve", "icgn_solve_translation"]

_OK = int(Reason.OK)
_NOT_CONVERGED = int(Reason.NOT_CONVERGED)
_OUT = int(Reason.OUT_OF_IMAGE)
_FLAT = int(Reason.NO_TEXTURE)
_DIVERGED = int(Reason.DIVERGED)

_CHUNK = 16  # nodes per parallel task


@nb.njit(inline="always")
def _cholesky6(H, L):
    """In-place lower Cholesky factor of 6x6 SPD ``H`` into ``L``; False if not SPD."""
    for i in range(6):
        for j in range(i + 1):
            s = H[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 1e-12 * (abs(H[i, i]) + 1e-300):
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@nb.njit(inline="always")
def _chol_solve6(L, b, x):
    y = np.empty(6)
    for i in range(6):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(5, -1, -1):
        s = y[i]
        for k in range(i + 1, 6):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@nb.njit(inline="always", fastmath=_FM)
def _sample_cubic_many(c1, stride, xw, yw, out, m):
    """Cubic B-spline samples at (xw, yw)[:m] (>= 0) from flat padded coefficients.

    Positions stay float64 (exact to 1e-12 px); the fractional parts, weights
    and the 16-tap sum use float32, which halves the cost of the hot loop.
    """
    one = np.float32(1.0)
    sixth = np.float32(1.0 / 6.0)
    two3 = np.float32(2.0 / 3.0)
    half = np.float32(0.5)
    for q in range(m):
        x = xw[q]
        y = yw[q]
        xi = np.int64(x)  # positions are >= 0, so truncation is floor
        yi = np.int64(y)
        tx = np.float32(x - xi)
        ty = np.float32(y - yi)
        b = (yi + PAD - 1) * stride + xi + PAD - 1
        s = one - tx
        t2 = tx * tx
        t3 = t2 * tx
        wx0 = s * s * s * sixth
        wx3 = t3 * sixth
        wx1 = two3 - t2 + half * t3
        wx2 = one - wx0 - wx1 - wx3
        s = one - ty
        t2 = ty * ty
        t3 = t2 * ty
        wy0 = s * s * s * sixth
        wy3 = t3 * sixth
        wy1 = two3 - t2 + half * t3
        wy2 = one - wy0 - wy1 - wy3
        r0 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        b += stride
        r1 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        b += stride
        r2 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        b += stride
        r3 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        out[q] = wy0 * r0 + wy1 * r1 + wy2 * r2 + wy3 * r3


@nb.njit(inline="always", fastmath=_FM)
def _quintic_weights(t):
    """Quintic B-spline weights for taps at offsets -2..3 (0 <= t < 1), float32."""
    one = np.float32(1.0)
    c = np.float32(1.0 / 120.0)
    s = one - t
    a1 = one + t
    b1 = np.float32(2.0) - t
    b2 = np.float32(3.0) - t
    s5 = s * s * s * s * s
    t5 = t * t * t * t * t
    w0 = s5 * c
    w1 = (b1 * b1 * b1 * b1 * b1 - np.float32(6.0) * s5) * c
    w2 = (b2 * b2 * b2 * b2 * b2 - np.float32(6.0) * b1 * b1 * b1 * b1 * b1
          + np.float32(15.0) * s5) * c
    w4 = (a1 * a1 * a1 * a1 * a1 - np.float32(6.0) * t5) * c
    w5 = t5 * c
    w3 = one - w0 - w1 - w2 - w4 - w5  # weights sum to one
    return w0, w1, w2, w3, w4, w5


@nb.njit(inline="always", fastmath=_FM)
def _sample_quintic_many(c1, stride, xw, yw, out, m):
    """Quintic B-spline samples at (xw, yw)[:m] (>= 0); see ``_sample_cubic_many``."""
    for q in range(m):
        x = xw[q]
        y = yw[q]
        xi = np.int64(x)
        yi = np.int64(y)
        wx0, wx1, wx2, wx3, wx4, wx5 = _quintic_weights(np.float32(x - xi))
        wy0, wy1, wy2, wy3, wy4, wy5 = _quintic_weights(np.float32(y - yi))
        b = (yi + PAD - 2) * stride + xi + PAD - 2
        acc = np.float32(0.0)
        for r in range(6):
            wy = wy0 if r == 0 else wy1 if r == 1 else wy2 if r == 2 else \
                wy3 if r == 3 else wy4 if r == 4 else wy5
            row = (wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
                   + wx4 * c1[b + 4] + wx5 * c1[b + 5])
            acc += wy * row
            b += stride
        out[q] = acc


@nb.njit(inline="always")
def _buffers(npx):
    """Per-task work arrays: subset offsets, reference gradients and values,
    warped positions and sampled grey values."""
    return (np.empty(npx), np.empty(npx), np.empty(npx), np.empty(npx), np.empty(npx),
            np.empty(npx), np.empty(npx), np.empty(npx, np.float32))


@nb.njit(inline="always")
def _gather(f, fgx, fgy, masks, sl, x0, y0, h, dxs, dys, gx, gy, fs):
    """Copy the node's subset pixels (its mask component only) into buffers.

    Returns ``(m, fm, df2)``: pixel count, mean and sum of squared deviations.
    """
    m = 0
    sf = 0.0
    sff = 0.0
    for a in range(-h, h + 1):
        for bb in range(-h, h + 1):
            if sl >= 0 and masks[sl, a + h, bb + h] == 0:
                continue
            fv = f[y0 + a, x0 + bb]
            dxs[m] = bb
            dys[m] = a
            gx[m] = fgx[y0 + a, x0 + bb]
            gy[m] = fgy[y0 + a, x0 + bb]
            fs[m] = fv
            sf += fv
            sff += fv * fv
            m += 1
    fm = sf / m
    return m, fm, sff - m * fm * fm


@nb.njit(inline="always", fastmath=_FM)
def _warp_sums(c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
               dxs, dys, gx, gy, fs, m, xw, yw, gv, xmax, ymax, quad, qx, qy):
    """Warp the subset, sample the deformed image and return the sums of one
    Gauss-Newton step: ``(inside, sg, sgg, sfg, sum gx g, sum gx g dx,
    sum gx g dy, sum gy g, sum gy g dx, sum gy g dy)``.

    With ``quad`` the fixed per-pixel offsets ``qx, qy`` (second-order terms
    of the warp) are added. The loops are split so that LLVM can vectorise
    the warp and the sums.
    """
    xlo = ylo = 1e300
    xhi = yhi = -1e300
    for q in range(m):
        dx = dxs[q]
        dy = dys[q]
        xv = x0 + dx + u + ux * dx + uy * dy
        yv = y0 + dy + v + vx * dx + vy * dy
        if quad:
            xv += qx[q]
            yv += qy[q]
        xw[q] = xv
        yw[q] = yv
        xlo = min(xlo, xv)
        xhi = max(xhi, xv)
        ylo = min(ylo, yv)
        yhi = max(yhi, yv)
    sg = sgg = sfg = 0.0
    t0 = t1 = t2 = t3 = t4 = t5 = 0.0
    if xlo < 0.0 or ylo < 0.0 or xhi > xmax or yhi > ymax or not (xhi - xlo < 1e9):
        return False, sg, sgg, sfg, t0, t1, t2, t3, t4, t5
    if order == 3:
        _sample_cubic_many(c1, stride, xw, yw, gv, m)
    else:
        _sample_quintic_many(c1, stride, xw, yw, gv, m)
    for q in range(m):
        g = np.float64(gv[q])
        dx = dxs[q]
        dy = dys[q]
        sg += g
        sgg += g * g
        sfg += fs[q] * g
        a1 = gx[q] * g
        a2 = gy[q] * g
        t0 += a1
        t1 += a1 * dx
        t2 += a1 * dy
        t3 += a2
        t4 += a2 * dx
        t5 += a2 * dy
    return True, sg, sgg, sfg, t0, t1, t2, t3, t4, t5


@nb.njit(inline="always", fastmath=_FM)
def _gn_step(c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
             dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, quad, qx, qy):
    """Sample the warped subset and return ``(status, zncc, df/dg, g mean,
    six gradient-weighted sums)``; status is OK, OUT_OF_IMAGE or NO_TEXTURE."""
    inside, sg, sgg, sfg, t0, t1, t2, t3, t4, t5 = _warp_sums(
        c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
        dxs, dys, gx, gy, fs, m, xw, yw, gv, xmax, ymax, quad, qx, qy)
    if not inside:
        return _OUT, np.nan, 0.0, 0.0, t0, t1, t2, t3, t4, t5
    gm = sg / m
    dg2 = sgg - m * gm * gm
    if dg2 <= 1e-6 * m:
        return _FLAT, np.nan, 0.0, gm, t0, t1, t2, t3, t4, t5
    dgn = np.sqrt(dg2)
    return _OK, (sfg - m * fm * gm) / (dfn * dgn), dfn / dgn, gm, t0, t1, t2, t3, t4, t5


@nb.njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def _icgn_kernel(f, fgx, fgy, coef, order, nx, ny, p_init, active, slot, masks,
                 h, max_iter, tol, p_out, zncc_out, iters_out, reason_out):
    n = nx.size
    rows, cols = f.shape
    stride = coef.shape[1]
    c1 = coef.ravel()
    S = 2 * h + 1
    npx_max = S * S
    nchunks = (n + _CHUNK - 1) // _CHUNK
    xmax = cols - 1.0  # deformed samples must stay inside the image
    ymax = rows - 1.0
    for c in nb.prange(nchunks):
        dxs, dys, gx, gy, fs, xw, yw, gv = _buffers(npx_max)
        H = np.empty((6, 6))
        L = np.zeros((6, 6))
        b = np.empty(6)
        dp = np.empty(6)
        for k in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            if not active[k]:
                continue
            x0 = nx[k]
            y0 = ny[k]
            m, fm, df2 = _gather(f, fgx, fgy, masks, slot[k], x0, y0, h, dxs, dys, gx, gy, fs)
            # --- Hessian, sum(J) and sum(J (f - fm)) of the reference subset
            for i in range(6):
                for j in range(6):
                    H[i, j] = 0.0
            sj0 = sj1 = sj2 = sj3 = sj4 = sj5 = 0.0
            b00 = b01 = b02 = b03 = b04 = b05 = 0.0
            for q in range(m):
                dx = dxs[q]
                dy = dys[q]
                ja = gx[q]
                jd = gy[q]
                J0 = ja
                J1 = ja * dx
                J2 = ja * dy
                J3 = jd
                J4 = jd * dx
                J5 = jd * dy
                fv = fs[q] - fm
                sj0 += J0
                sj1 += J1
                sj2 += J2
                sj3 += J3
                sj4 += J4
                sj5 += J5
                b00 += J0 * fv
                b01 += J1 * fv
                b02 += J2 * fv
                b03 += J3 * fv
                b04 += J4 * fv
                b05 += J5 * fv
                H[0, 0] += J0 * J0
                H[1, 0] += J1 * J0
                H[1, 1] += J1 * J1
                H[2, 0] += J2 * J0
                H[2, 1] += J2 * J1
                H[2, 2] += J2 * J2
                H[3, 0] += J3 * J0
                H[3, 1] += J3 * J1
                H[3, 2] += J3 * J2
                H[3, 3] += J3 * J3
                H[4, 0] += J4 * J0
                H[4, 1] += J4 * J1
                H[4, 2] += J4 * J2
                H[4, 3] += J4 * J3
                H[4, 4] += J4 * J4
                H[5, 0] += J5 * J0
                H[5, 1] += J5 * J1
                H[5, 2] += J5 * J2
                H[5, 3] += J5 * J3
                H[5, 4] += J5 * J4
                H[5, 5] += J5 * J5
            for i in range(6):
                for j in range(i + 1, 6):
                    H[i, j] = H[j, i]
            if df2 <= 1e-6 * m or not _cholesky6(H, L):
                reason_out[k] = _FLAT
                zncc_out[k] = np.nan
                iters_out[k] = 0
                for i in range(6):
                    p_out[k, i] = p_init[k, i]
                continue
            dfn = np.sqrt(df2)
            u = p_init[k, 0]
            ux = p_init[k, 1]
            uy = p_init[k, 2]
            v = p_init[k, 3]
            vx = p_init[k, 4]
            vy = p_init[k, 5]
            u_start = u
            v_start = v
            status = _NOT_CONVERGED
            zn = np.nan
            it = 0
            while it < max_iter:
                it += 1
                st, zn_k, r, gm, t0, t1, t2, t3, t4, t5 = _gn_step(
                    c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
                    dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, False, xw, yw)
                if st != _OK:
                    status = st
                    break
                zn = zn_k
                # b = sum J [(f - fm) - (df/dg)(g - gm)];  H dp = -b
                b[0] = b00 - r * (t0 - gm * sj0)
                b[1] = b01 - r * (t1 - gm * sj1)
                b[2] = b02 - r * (t2 - gm * sj2)
                b[3] = b03 - r * (t3 - gm * sj3)
                b[4] = b04 - r * (t4 - gm * sj4)
                b[5] = b05 - r * (t5 - gm * sj5)
                _chol_solve6(L, b, dp)
                du = -dp[0]
                dux = -dp[1]
                duy = -dp[2]
                dv = -dp[3]
                dvx = -dp[4]
                dvy = -dp[5]
                # --- inverse-compositional update: W(p) <- W(p) o W(dp)^-1
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
                u = m11 * it1 + m12 * it2 + u
                v = m21 * it1 + m22 * it2 + v
                ux = n11 - 1.0
                uy = n12
                vx = n21
                vy = n22 - 1.0
                nrm = du * du + dv * dv + h * h * (dux * dux + duy * duy + dvx * dvx + dvy * dvy)
                if abs(u - u_start) > S or abs(v - v_start) > S or not np.isfinite(nrm):
                    status = _DIVERGED
                    break
                if nrm < tol * tol:
                    status = _OK
                    break
            p_out[k, 0] = u
            p_out[k, 1] = ux
            p_out[k, 2] = uy
            p_out[k, 3] = v
            p_out[k, 4] = vx
            p_out[k, 5] = vy
            zncc_out[k] = zn
            iters_out[k] = it
            reason_out[k] = status


def icgn_solve(f, fgx, fgy, spline, nodes_x, nodes_y, p_init, active, slot, masks,
               half, max_iter=40, tol=1e-3, out=None):
    """Run IC-GN at the ``active`` nodes.

    Parameters
    ----------
    f, fgx, fgy : (H, W) float32
        Reference image and its spline gradients.
    spline : SplineImage
        Deformed-image B-spline coefficients.
    nodes_x, nodes_y : (n,) int64
        Node pixel coordinates.
    p_init : (n, 6) float64
        Initial parameters ``(u, ux, uy, v, vx, vy)``.
    active : (n,) bool
        Nodes to solve; the others are left untouched in ``out``.
    slot, masks : see :class:`~napari_aldic.engine.subsets.SubsetMasks`.
    half : int
        Subset half-width in pixels.
    out : tuple or None
        ``(p, zncc, iters, reason)`` arrays to update in place.

    Returns
    -------
    p, zncc, iters, reason
    """
    n = nodes_x.size
    if out is None:
        out = (np.array(p_init, dtype=np.float64, copy=True), np.full(n, np.nan),
               np.zeros(n, np.int32), np.full(n, _NOT_CONVERGED, np.int8))
    p, zn, it, rs = out
    _icgn_kernel(f, fgx, fgy, spline.coef, spline.order, nodes_x, nodes_y,
                 np.ascontiguousarray(p_init, dtype=np.float64), active, slot, masks,
                 int(half), int(max_iter), float(tol), p, zn, it, rs)
    return p, zn, it, rs


@nb.njit(cache=True, parallel=True, fastmath=_FM, nogil=True)
def _icgn2_kernel(f, fgx, fgy, coef, order, nx, ny, uv_init, grad, curv, target, mu, active,
                  slot, masks, h, max_iter, tol, uv_out, zncc_out, iters_out, reason_out):
    n = nx.size
    rows, cols = f.shape
    stride = coef.shape[1]
    c1 = coef.ravel()
    S = 2 * h + 1
    npx_max = S * S
    nchunks = (n + _CHUNK - 1) // _CHUNK
    xmax = cols - 1.0  # deformed samples must stay inside the image
    ymax = rows - 1.0
    quad = curv.shape[0] == n
    for c in nb.prange(nchunks):
        dxs, dys, gx, gy, fs, xw, yw, gv = _buffers(npx_max)
        qx = np.zeros(npx_max)
        qy = np.zeros(npx_max)
        for k in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            if not active[k]:
                continue
            x0 = nx[k]
            y0 = ny[k]
            m, fm, df2 = _gather(f, fgx, fgy, masks, slot[k], x0, y0, h, dxs, dys, gx, gy, fs)
            if quad:
                # fixed second-order part of the warp, from the global field
                for q in range(m):
                    dx = dxs[q]
                    dy = dys[q]
                    qx[q] = 0.5 * curv[k, 0] * dx * dx + curv[k, 1] * dx * dy \
                        + 0.5 * curv[k, 2] * dy * dy
                    qy[q] = 0.5 * curv[k, 3] * dx * dx + curv[k, 4] * dx * dy \
                        + 0.5 * curv[k, 5] * dy * dy
            h00 = h01 = h11 = sj0 = sj3 = b0 = b3 = 0.0
            for q in range(m):
                a1 = gx[q]
                a2 = gy[q]
                fv = fs[q] - fm
                h00 += a1 * a1
                h01 += a1 * a2
                h11 += a2 * a2
                sj0 += a1
                sj3 += a2
                b0 += a1 * fv
                b3 += a2 * fv
            if df2 <= 1e-6 * m or h00 * h11 - h01 * h01 <= 1e-12 * (h00 + h11) ** 2:
                reason_out[k] = _FLAT
                zncc_out[k] = np.nan
                iters_out[k] = 0
                uv_out[k, 0] = uv_init[k, 0]
                uv_out[k, 1] = uv_init[k, 1]
                continue
            dfn = np.sqrt(df2)
            ux = grad[k, 0]
            uy = grad[k, 1]
            vx = grad[k, 2]
            vy = grad[k, 3]
            # A = I + F maps a reference-frame shift to a deformed-frame shift
            a11 = 1.0 + ux
            a12 = uy
            a21 = vx
            a22 = 1.0 + vy
            pen = mu * 0.5 * (h00 + h11)  # penalty stiffness, scaled to the data term
            # normal matrix (H + pen A^T A), constant over the iterations
            m00 = h00 + pen * (a11 * a11 + a21 * a21)
            m01 = h01 + pen * (a11 * a12 + a21 * a22)
            m11 = h11 + pen * (a12 * a12 + a22 * a22)
            det = m00 * m11 - m01 * m01
            tu = target[k, 0]
            tv = target[k, 1]
            u = uv_init[k, 0]
            v = uv_init[k, 1]
            status = _NOT_CONVERGED
            zn = np.nan
            it = 0
            while it < max_iter:
                it += 1
                st, zn_k, r, gm, t0, t1, t2, t3, t4, t5 = _gn_step(
                    c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
                    dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, quad, qx, qy)
                if st != _OK:
                    status = st
                    break
                zn = zn_k
                g0 = b0 - r * (t0 - gm * sj0)
                g3 = b3 - r * (t3 - gm * sj3)
                # (H + pen A^T A) d = -g + pen A^T (u - t)
                eu = u - tu
                ev = v - tv
                r0 = -g0 + pen * (a11 * eu + a21 * ev)
                r1 = -g3 + pen * (a12 * eu + a22 * ev)
                d0 = (m11 * r0 - m01 * r1) / det
                d1 = (m00 * r1 - m01 * r0) / det
                du = a11 * d0 + a12 * d1
                dv = a21 * d0 + a22 * d1
                u -= du
                v -= dv
                if abs(u - uv_init[k, 0]) > S or abs(v - uv_init[k, 1]) > S or not np.isfinite(u + v):
                    status = _DIVERGED
                    break
                if du * du + dv * dv < tol * tol:
                    status = _OK
                    break
            uv_out[k, 0] = u
            uv_out[k, 1] = v
            zncc_out[k] = zn
            iters_out[k] = it
            reason_out[k] = status


def icgn_solve_translation(f, fgx, fgy, spline, nodes_x, nodes_y, uv_init, grad, target,
                           mu, active, slot, masks, half, max_iter=40, tol=1e-3,
                           curvature=None):
    """AL-DIC local step: IC-GN on the displacement only, with the gradient fixed.

    Minimises, per node, ``SSD(u; F fixed) + mu' / 2 |u - target|^2`` where
    ``mu' = mu * tr(H) / 2`` scales the dimensionless ``mu`` by the subset's
    Gauss-Newton stiffness (H: 2x2 Hessian of the data term), so one ``mu``
    suits every image contrast and subset size.

    Parameters
    ----------
    uv_init : (n, 2) starting displacements.
    grad : (n, 4) fixed gradients (du/dx, du/dy, dv/dx, dv/dy).
    target : (n, 2) penalty targets ``û + v`` (scaled multiplier included).
    mu : float, dimensionless penalty weight.
    curvature : (n, 6) or None
        Fixed second derivatives ``(uxx, uxy, uyy, vxx, vxy, vyy)`` (1/px)
        added to the warp as ``0.5 dXᵀ ∇∇u dX``; None keeps the warp affine.

    Returns
    -------
    uv, zncc, iters, reason
    """
    curv = (np.zeros((0, 6)) if curvature is None
            else np.ascontiguousarray(curvature, np.float64))
    n = nodes_x.size
    uv = np.array(uv_init, dtype=np.float64, copy=True)
    zn = np.full(n, np.nan)
    it = np.zeros(n, np.int32)
    rs = np.full(n, _NOT_CONVERGED, np.int8)
    _icgn2_kernel(f, fgx, fgy, spline.coef, spline.order, nodes_x, nodes_y,
                  np.ascontiguousarray(uv_init, np.float64), np.ascontiguousarray(grad, np.float64),
                  curv, np.ascontiguousarray(target, np.float64), float(mu), active, slot, masks,
                  int(half), int(max_iter), float(tol), uv, zn, it, rs)
    return uv, zn, it, rs
