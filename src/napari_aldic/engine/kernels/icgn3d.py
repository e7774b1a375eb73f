"""3-D inverse-compositional Gauss-Newton (IC-GN) over subset cubes (DVC).

One node is a cube of ``(2h+1)^3`` reference voxels (those inside the ROI
mask) matched in the deformed volume through the 12-parameter affine warp
``p = (u, ux, uy, uz, v, vx, vy, vz, w, wx, wy, wz)``: a voxel at offset
``d`` from the node goes to ``node + d + t + G d`` (``t = (u, v, w)``,
``G`` the displacement gradient). The criterion is the zero-normalised sum
of squared differences (ZNSSD), which ignores offset and scale of the grey
levels. Inverse compositional: the Gauss-Newton matrix ``H = sum J J^T``
uses the reference gradients only, so it is factorised once per node; each
step samples the deformed volume (tricubic B-spline) at the warped voxels
and composes ``W(p) <- W(p) o W(dp)^-1``.

Precision: voxel data and the 64-tap sums are float32 (memory bound, see
:mod:`.bspline3d`); positions, the matrix, the right-hand side and the warp
are float64 (they accumulate over ~10^4 voxels).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .bspline3d import tricubic
from .flags import CALLEE, FASTMATH, INLINE, PARALLEL
from .gauss_newton import DIVERGED, NO_TEXTURE, NOT_CONVERGED, OK, OUT_OF_IMAGE
from .icgn_node import lu_factor, lu_solve

__all__ = ["icgn3d", "SMALL_SUBSET", "NPAR3"]

NPAR3 = 12
EDGE3 = 3.0  # voxels kept clear of the deformed volume's faces (see _gather)
SMALL_SUBSET = 1  # fewer usable voxels than min_frac of the cube (Reason.SMALL_COMPONENT)


@nb.njit(**CALLEE)
def _compose(p, dp):
    """``p <- W(p) o W(dp)^-1`` for the affine warp: with ``W(p): d -> A d + t``
    (``A = I + G``), the new warp is ``A Di d + (A ti + t)``, ``Di = (I + G_dp)^-1``,
    ``ti = -Di t_dp``."""
    A = np.empty((3, 3))
    D = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            A[i, j] = p[4 * i + 1 + j] + (1.0 if i == j else 0.0)
            D[i, j] = dp[4 * i + 1 + j] + (1.0 if i == j else 0.0)
    Di = np.linalg.inv(D)
    ti = np.empty(3)
    for i in range(3):
        ti[i] = -(Di[i, 0] * dp[0] + Di[i, 1] * dp[4] + Di[i, 2] * dp[8])
    for i in range(3):
        t = p[4 * i]
        for k in range(3):
            t += A[i, k] * ti[k]
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += A[i, k] * Di[k, j]
            p[4 * i + 1 + j] = s - (1.0 if i == j else 0.0)
        p[4 * i] = t


@nb.njit(**INLINE, fastmath=FASTMATH)
def _warp_sample(gc, p, cx, cy, cz, d, m, g, lim):
    """Sample the deformed spline at the warped voxels. Returns 2 if one
    leaves the padded volume (``lim``: largest coordinate per axis + margin),
    1 if one comes over half a voxel closer to a face than the :data:`EDGE3`
    band of :func:`_gather`, else 0."""
    near = 0
    for q in range(m):
        dx = d[q, 0]
        dy = d[q, 1]
        dz = d[q, 2]
        x = cx + dx + p[0] + p[1] * dx + p[2] * dy + p[3] * dz
        y = cy + dy + p[4] + p[5] * dx + p[6] * dy + p[7] * dz
        z = cz + dz + p[8] + p[9] * dx + p[10] * dy + p[11] * dz
        if not (-3.0 < x < lim[0] and -3.0 < y < lim[1] and -3.0 < z < lim[2]):
            return 2
        # half a voxel beyond the band :func:`_gather` keeps (``lim - 3`` is the
        # last voxel): the voxels it chose never trigger a second pass by themselves
        if not (EDGE3 - 0.5 <= x <= lim[0] - 2.5 - EDGE3 and EDGE3 - 0.5 <= y <= lim[1] - 2.5
                - EDGE3 and EDGE3 - 0.5 <= z <= lim[2] - 2.5 - EDGE3):
            near = 1
        g[q] = tricubic(gc, x, y, z)
    return near


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _gather(f, fg, mask, p, cx, cy, cz, h, d, fv, gr):
    """Usable voxels of a cube: in the mask, and (warped by the initial
    ``p``) at least :data:`EDGE3` voxels inside the deformed volume, where
    the mirror boundary of the spline no longer biases the interpolant
    (its influence decays as ``(2 - sqrt 3)^k``: 2 % at 3 voxels).
    Returns their count."""
    nz, ny, nx = f.shape
    m = 0
    for dz in range(-h, h + 1):
        z = cz + dz
        if z < 0 or z >= nz:
            continue
        for dy in range(-h, h + 1):
            y = cy + dy
            if y < 0 or y >= ny:
                continue
            for dx in range(-h, h + 1):
                x = cx + dx
                if x < 0 or x >= nx or mask[z, y, x] == 0:
                    continue
                wx = x + p[0] + p[1] * dx + p[2] * dy + p[3] * dz
                wy = y + p[4] + p[5] * dx + p[6] * dy + p[7] * dz
                wz = z + p[8] + p[9] * dx + p[10] * dy + p[11] * dz
                if not (EDGE3 <= wx <= nx - 1 - EDGE3 and EDGE3 <= wy <= ny - 1 - EDGE3
                        and EDGE3 <= wz <= nz - 1 - EDGE3):
                    continue
                d[m, 0] = dx
                d[m, 1] = dy
                d[m, 2] = dz
                fv[m] = f[z, y, x]
                gr[m, 0] = fg[0, z, y, x]
                gr[m, 1] = fg[1, z, y, x]
                gr[m, 2] = fg[2, z, y, x]
                m += 1
    return m


# moment index of d_i d_j (d_0 = 1, d_1..3 = dx, dy, dz), i, j in 0..3
_MOM = np.array([[0, 1, 2, 3], [1, 4, 5, 6], [2, 5, 7, 8], [3, 6, 8, 9]], np.int64)


@nb.njit(**INLINE, fastmath=FASTMATH)
def _flush_row(R, M, dy, dz):
    """Add one row's sums ``R[0..2, k] = sum gg_k (1, dx, dx^2)`` (``k`` over
    the six gradient products) to the moments ``M[k, 0..9]`` of ``_MOM``."""
    for k in range(6):
        r0 = R[0, k]
        r1 = R[1, k]
        M[k, 0] += r0
        M[k, 1] += r1
        M[k, 2] += dy * r0
        M[k, 3] += dz * r0
        M[k, 4] += R[2, k]
        M[k, 5] += dy * r1
        M[k, 6] += dz * r1
        M[k, 7] += dy * dy * r0
        M[k, 8] += dy * dz * r0
        M[k, 9] += dz * dz * r0
        R[0, k] = 0.0
        R[1, k] = 0.0
        R[2, k] = 0.0


@nb.njit(**INLINE, fastmath=FASTMATH)
def _row_add(R, k, v, dx):
    R[0, k] += v
    R[1, k] += v * dx
    R[2, k] += v * dx * dx


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _hessian(gr, d, m, H):
    """``H = sum J J^T`` with ``J = g (x) (1, dx, dy, dz)``: every entry is a
    moment ``sum g_a g_b d_i d_j``. Along a row of the cube (``dy``, ``dz``
    fixed) only ``1, dx, dx^2`` vary, so a voxel adds 6 products and 18
    row sums, and each row end spreads them over the 10 moments (instead of
    78 products a voxel)."""
    R = np.zeros((3, 6))
    M = np.zeros((6, 10))
    if m == 0:
        for i in range(NPAR3):
            for j in range(NPAR3):
                H[i, j] = 0.0
        return
    ry = d[0, 1]
    rz = d[0, 2]
    for q in range(m):
        if d[q, 1] != ry or d[q, 2] != rz:
            _flush_row(R, M, float(ry), float(rz))
            ry = d[q, 1]
            rz = d[q, 2]
        gx = float(gr[q, 0])
        gy = float(gr[q, 1])
        gz = float(gr[q, 2])
        dx = float(d[q, 0])
        _row_add(R, 0, gx * gx, dx)
        _row_add(R, 1, gx * gy, dx)
        _row_add(R, 2, gx * gz, dx)
        _row_add(R, 3, gy * gy, dx)
        _row_add(R, 4, gy * gz, dx)
        _row_add(R, 5, gz * gz, dx)
    _flush_row(R, M, float(ry), float(rz))
    k = 0
    for a in range(3):
        for b in range(a, 3):
            for i in range(4):
                for j in range(4):
                    v = M[k, _MOM[i, j]]
                    H[4 * a + i, 4 * b + j] = v
                    H[4 * b + j, 4 * a + i] = v
            k += 1


@nb.njit(**INLINE, fastmath=FASTMATH)
def _stats(v, m):
    s = 0.0
    for q in range(m):
        s += v[q]
    mean = s / m
    ss = 0.0
    for q in range(m):
        ss += (v[q] - mean) ** 2
    return mean, ss


@nb.njit(**INLINE, fastmath=FASTMATH)
def _rhs(fv, g, gr, d, m, fm, gm, ratio, b):
    """``b = sum J e`` with ``e = (f - fm) - ratio (g - gm)``; returns sum e^2.
    Summed by rows of the cube, as :func:`_hessian`: ``sum e g_a (1, dx)``
    per row, times ``dy``, ``dz`` at its end."""
    for i in range(NPAR3):
        b[i] = 0.0
    s0 = np.zeros(3)
    s1 = np.zeros(3)
    e2 = 0.0
    if m == 0:
        return e2
    ry = d[0, 1]
    rz = d[0, 2]
    for q in range(m + 1):
        if q == m or d[q, 1] != ry or d[q, 2] != rz:
            for a in range(3):
                b[4 * a] += s0[a]
                b[4 * a + 1] += s1[a]
                b[4 * a + 2] += ry * s0[a]
                b[4 * a + 3] += rz * s0[a]
                s0[a] = 0.0
                s1[a] = 0.0
            if q == m:
                break
            ry = d[q, 1]
            rz = d[q, 2]
        e = (fv[q] - fm) - ratio * (g[q] - gm)
        e2 += e * e
        dx = d[q, 0]
        for a in range(3):
            v = e * gr[q, a]
            s0[a] += v
            s1[a] += v * dx
    return e2


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _iterate(gc, c, p, h, max_iter, tol, lim, d, fv, gr, g, m, fm, df2, LU, piv, b, dp, pen, q):
    """Gauss-Newton steps from ``p`` (updated in place). Returns ``(status,
    iterations, zncc, sum e^2, near)``; ``near``: the last sampling came
    closer than :data:`EDGE3` to a face of the volume.

    ``pen`` (12,) adds the AL-DVC penalty ``sum pen_i (p_i - q_i)^2`` on the
    displacements (the gradient rows of ``b`` zeroed: held fixed): with the
    composition linearised (``p o dp^-1 ~ p - dp``) the step solves
    ``(H + diag pen) dp = diag(pen) (p - q) - b``; ``LU`` factors ``H + diag pen``."""
    t0 = (p[0], p[4], p[8])
    status = NOT_CONVERGED
    zn = np.nan
    e2 = np.nan
    it = 0
    near = 0
    while it < max_iter:
        it += 1
        near = _warp_sample(gc, p, c[0], c[1], c[2], d, m, g, lim)
        if near == 2:
            status = OUT_OF_IMAGE
            break
        gm, dg2 = _stats(g, m)
        if dg2 <= 1e-6 * m:
            status = NO_TEXTURE
            break
        e2 = _rhs(fv, g, gr, d, m, fm, gm, np.sqrt(df2 / dg2), b)
        zn = 1.0 - 0.5 * e2 / df2
        if pen[0] > 0.0:  # AL-DVC: displacements only, pulled towards q
            for i in range(NPAR3):
                b[i] = b[i] - pen[i] * (p[i] - q[i]) if i % 4 == 0 else 0.0
        lu_solve(LU, piv, b, dp)
        for i in range(NPAR3):
            dp[i] = -dp[i]
        _compose(p, dp)
        nrm = dp[0] ** 2 + dp[4] ** 2 + dp[8] ** 2
        for a in range(3):
            for j in range(3):
                nrm += (h * dp[4 * a + 1 + j]) ** 2
        if (not np.isfinite(nrm) or abs(p[0] - t0[0]) > 2 * h or abs(p[4] - t0[1]) > 2 * h
                or abs(p[8] - t0[2]) > 2 * h):
            status = DIVERGED
            break
        if nrm < tol * tol:
            status = OK
            break
    return status, it, zn, e2, near == 1


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _translation_system(gr, m, mu, H, pen):
    """AL-DVC's local step, as 2-D AL-DIC: the subset's gradient is held at
    the global field's (Algorithm 1), so only the three displacements are
    solved: ``H`` gets the translation block ``sum g_a g_b`` (identity on
    the gradient rows, whose right-hand side :func:`_iterate` zeroes) and
    ``pen`` the displacement penalty, ``mu`` times the mean displacement
    stiffness ``(H_uu + H_vv + H_ww) / 3`` (``mu`` dimensionless)."""
    for i in range(NPAR3):
        pen[i] = 0.0
        for j in range(NPAR3):
            H[i, j] = 0.0
    s = np.zeros(6)
    for q in range(m):
        gx = gr[q, 0]
        gy = gr[q, 1]
        gz = gr[q, 2]
        s[0] += gx * gx
        s[1] += gx * gy
        s[2] += gx * gz
        s[3] += gy * gy
        s[4] += gy * gz
        s[5] += gz * gz
    k = 0
    for a in range(3):
        for b in range(a, 3):
            H[4 * a, 4 * b] = s[k]
            H[4 * b, 4 * a] = s[k]
            k += 1
    t = mu * (s[0] + s[3] + s[5]) / 3.0
    for i in range(NPAR3):
        if i % 4 == 0:
            pen[i] = t
        else:
            H[i, i] = 1.0


@nb.njit(**CALLEE, fastmath=FASTMATH)
def _solve_node(f, fg, gc, mask, c, p, h, max_iter, tol, min_frac, lim, out, mu, q, hr):
    """One node: returns ``(status, iterations, zncc, e2/(m - 12), m)``;
    ``p`` is updated in place; ``out`` (3,) receives diag(H^-1) at u, v, w,
    and (Local, ``mu == 0``) ``hr`` (3, 12) the rows of ``H`` at u, v, w.

    The usable voxels are chosen with the starting warp; if the converged
    warp takes some of them near a face of the volume, they are chosen
    again with it and the node solved once more. ``mu > 0`` is AL-DVC's
    local step (:func:`_translation_system`): the displacement is pulled
    towards ``q``, the gradient held at ``p``'s (the uncertainty is then
    that of the penalised match)."""
    n3 = (2 * h + 1) ** 3
    d = np.empty((n3, 3), np.float32)
    fv = np.empty(n3, np.float32)
    gr = np.empty((n3, 3), np.float32)
    g = np.empty(n3, np.float32)
    H = np.empty((NPAR3, NPAR3))
    LU = np.empty((NPAR3, NPAR3))
    piv = np.empty(NPAR3, np.int64)
    b = np.empty(NPAR3)
    dp = np.empty(NPAR3)
    pen = np.zeros(NPAR3)
    its = 0
    for _ in range(2):
        m = _gather(f, fg, mask, p, c[0], c[1], c[2], h, d, fv, gr)
        if m < min_frac * n3 or m <= 2 * NPAR3:
            return SMALL_SUBSET, its, np.nan, np.nan, m
        fm, df2 = _stats(fv, m)
        if df2 <= 1e-6 * m:
            return NO_TEXTURE, its, np.nan, np.nan, m
        if mu > 0.0:
            _translation_system(gr, m, mu, H, pen)
        else:
            _hessian(gr, d, m, H)
        for i in range(NPAR3):
            H[i, i] += pen[i]
        if not lu_factor(H, LU, piv):
            return NO_TEXTURE, its, np.nan, np.nan, m
        status, it, zn, e2, near = _iterate(gc, c, p, h, max_iter, tol, lim, d, fv, gr, g, m,
                                            fm, df2, LU, piv, b, dp, pen, q)
        its += it
        if status != OK or not near:
            break
    for a in range(3):  # diagonal of H^-1 at u, v, w
        for i in range(NPAR3):
            b[i] = 1.0 if i == 4 * a else 0.0
        lu_solve(LU, piv, b, dp)
        out[a] = dp[4 * a]
        if mu == 0.0:
            for i in range(NPAR3):
                hr[a, i] = H[4 * a, i]
    return status, its, zn, e2 / max(m - NPAR3, 1), m


@nb.njit(**PARALLEL, fastmath=FASTMATH)
def icgn3d(f, fg, gc, mask, nodes, p, todo, h, max_iter, tol, min_frac,
           status, iters, zncc, ustd, nvox, mu, target, hrow):
    """Solve the nodes ``todo`` (parallel over them).

    Parameters
    ----------
    f : (nz, ny, nx) float32
        Reference volume (grey levels at the voxels).
    fg : (3, nz, ny, nx) float32
        Gradient (d/dx, d/dy, d/dz) of the reference's spline at the voxels,
        computed once for the volume: a voxel lies in ~(subset/step)^3
        subsets, so per-subset gradients would repeat that work.
    gc : (nz + 2 PAD3, ny + 2 PAD3, nx + 2 PAD3) float32
        Padded tricubic coefficients of the deformed volume.
    mask : (nz, ny, nx) uint8
        ROI (1 = material); voxels outside are left out of every subset.
    nodes : (n, 3) int64
        Node voxels (x, y, z).
    p : (n, 12) float64
        Initial warp in, solution out (the nodes of ``todo`` only).
    todo : (t,) int64
        Indices of the nodes to solve (a contiguous batch of them is shared
        evenly by the threads).
    h, max_iter, tol, min_frac : int, int, float, float
        Half-width, iteration cap, tolerance (voxels at the subset edge)
        and the smallest usable fraction of the cube.
    mu : float
        AL-DVC penalty (dimensionless, 0 for Local DVC; :func:`_translation_system`).
    target : (n, 12) float64
        The warps the penalty pulls towards (unused when ``mu == 0``).
    hrow : (n, 3, 12) float64
        Local (``mu == 0``): the rows of the Gauss-Newton matrix at u, v, w
        (AL-DVC's quadratic model of each subset, :mod:`~..volume.aldvc`).
    status, iters, zncc, ustd, nvox : outputs per node
        ``status`` (int8, gauss_newton codes, SMALL_SUBSET), iterations,
        final ZNCC, standard uncertainty of (u, v, w) in voxels (n, 3) and
        usable voxels. The uncertainty is ``sqrt(s2 diag(H^-1))`` with
        ``s2`` the residual variance per voxel of the ZNSSD match
        (Gauss-Newton covariance, as in 2-D).
    """
    nz, ny, nx = f.shape
    lim = np.array([nx + 2.0, ny + 2.0, nz + 2.0])  # PAD3 - 2 beyond the last voxel
    for t in nb.prange(todo.shape[0]):
        k = todo[t]
        pk = p[k].copy()
        hinv = np.zeros(3)
        st, it, zn, s2, m = _solve_node(f, fg, gc, mask, nodes[k], pk, h, max_iter, tol,
                                        min_frac, lim, hinv, mu, target[k], hrow[k])
        p[k] = pk
        status[k] = st
        iters[k] = it
        zncc[k] = zn
        nvox[k] = m
        for a in range(3):
            ustd[k, a] = np.sqrt(s2 * hinv[a]) if st == OK else np.nan
