"""Inverse-compositional Gauss-Newton with the second-order subset shape function.

The quadratic warp has twelve parameters, stored as the affine six followed
by the second derivatives,
``p = (u, ux, uy, v, vx, vy, uxx, uxy, uyy, vxx, vxy, vyy)``, so that the
first six columns mean what they mean for :func:`~.icgn.icgn_affine`: the
subset pixel at offset ``(dx, dy)`` maps to
``x0 + dx + u + ux dx + uy dy + uxx dx^2/2 + uxy dx dy + uyy dy^2/2`` (and
likewise in ``y``). A subset can then follow a displacement that bends over
its width, which an affine subset averages away.

The skeleton is the affine solver's (:mod:`.icgn`, :mod:`.gauss_newton`,
:mod:`.icgn_node`): the reference Hessian (12 x 12) is built and factorised
once per node, and every step warps the subset (the second-order part as
the fixed offsets that :func:`~.gauss_newton.gn_step` already adds), samples
the deformed image once and forms the right-hand side. The inverse
composition of second-order warps is not closed; the increment is composed
to first order in the increment and truncated at second order in the
offsets (:func:`compose_quadratic`). Gauss-Newton stops where the increment
vanishes, so the truncation changes the path, not the solution.

References: H. Lu, P. D. Cary, "Deformation measurements by digital image
correlation: implementation of a second-order displacement gradient",
Exp. Mech. 40, 2000; Y. Gao, T. Cheng, Y. Su, X. Xu, Y. Zhang, Q. Zhang,
"High-efficiency and high-accuracy digital image correlation for
three-dimensional measurement", Opt. Lasers Eng. 65, 2015.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import CALLEE, FASTMATH, INLINE, SERIAL
from .gauss_newton import CHUNK, NOT_CONVERGED, OK, chunk_layout, gn_step, store_node
from .icgn_node import begin_node, lu_solve, solve_buffers, step_status
from .subset import gather_gradients, gather_subset, subset_buffers

__all__ = ["NPAR", "quadratic_jacobian", "quadratic_reference_sums", "quadratic_offsets",
           "compose_quadratic", "quadratic_step", "icgn_quadratic"]

#: parameters of the second-order shape function
NPAR = 12


@nb.njit(**INLINE, fastmath=FASTMATH)
def quadratic_jacobian(dx, dy, gx, gy, J):
    """Steepest-descent image of one pixel for the twelve parameters.

    Parameters
    ----------
    dx, dy : float
        Offset of the pixel from the node.
    gx, gy : float
        Reference gradient at the pixel.
    J : (12,) float64
        Receives ``(gx, gx dx, gx dy, gy, gy dx, gy dy, gx dx^2/2, gx dx dy,
        gx dy^2/2, gy dx^2/2, gy dx dy, gy dy^2/2)``.
    """
    xx = 0.5 * dx * dx
    xy = dx * dy
    yy = 0.5 * dy * dy
    J[0] = gx
    J[1] = gx * dx
    J[2] = gx * dy
    J[3] = gy
    J[4] = gy * dx
    J[5] = gy * dy
    J[6] = gx * xx
    J[7] = gx * xy
    J[8] = gx * yy
    J[9] = gy * xx
    J[10] = gy * xy
    J[11] = gy * yy


@nb.njit(**INLINE, fastmath=FASTMATH)
def quadratic_reference_sums(dxs, dys, gx, gy, ex, ey, fs, m, fm, Jm, Em, sj, bf):
    """Gauss-Newton matrix and sums of the reference subset (quadratic warp).

    The steepest-descent images of the ``m`` pixels fill the rows of ``Jm``
    and their exact linearisations those of ``Em``; ``H = Jm^T Em`` (the
    instrumental-variable matrix of :func:`~.icgn.affine_reference_sums`) is
    then one matrix product (BLAS), faster than accumulating the products of
    every pixel one by one.

    Parameters
    ----------
    dxs, dys, gx, gy, ex, ey, fs, m, fm
        As :func:`~.icgn.affine_reference_sums`.
    Jm, Em : (>= m, 12) float64
        Work arrays: receive the steepest-descent image and the exact
        linearisation of each pixel.
    sj, bf : (12,) float64
        Receive ``sum J`` and ``sum J (f - fm)``.

    Returns
    -------
    (12, 12) float64
        ``H = sum J e^T``.
    """
    sj[:] = 0.0
    bf[:] = 0.0
    for q in range(m):
        row = Jm[q]
        quadratic_jacobian(dxs[q], dys[q], gx[q], gy[q], row)
        quadratic_jacobian(dxs[q], dys[q], ex[q], ey[q], Em[q])
        fv = fs[q] - fm
        for i in range(NPAR):
            sj[i] += row[i]
            bf[i] += row[i] * fv
    return np.dot(Jm[:m].T, Em[:m])


@nb.njit(**INLINE, fastmath=FASTMATH)
def quadratic_offsets(p, dxs, dys, m, qx, qy):
    """Second-order part of the warp at every subset pixel.

    Parameters
    ----------
    p : (12,) float64
        Current parameters.
    dxs, dys : 1-D float64
        Pixel offsets.
    m : int
        Subset pixels.
    qx, qy : 1-D float64
        Receive ``uxx dx^2/2 + uxy dx dy + uyy dy^2/2`` and the same for ``v``.
    """
    for q in range(m):
        dx = dxs[q]
        dy = dys[q]
        xx = 0.5 * dx * dx
        xy = dx * dy
        yy = 0.5 * dy * dy
        qx[q] = p[6] * xx + p[7] * xy + p[8] * yy
        qy[q] = p[9] * xx + p[10] * xy + p[11] * yy


@nb.njit(**INLINE, fastmath=FASTMATH)
def compose_quadratic(p, d):
    """Inverse-compositional update ``W(p) <- W(p) o W(d)^-1``, to first order.

    With the Gauss-Newton increment ``-d``, ``W(-d)^-1`` moves a pixel by
    ``+d(X)`` to first order in ``d``; through ``W(p)`` that is
    ``(I + grad u_p(X)) d(X)``, a polynomial of degree three in the offsets
    whose terms up to degree two are kept.

    Parameters
    ----------
    p : (12,) float64
        Current parameters, updated in place.
    d : (12,) float64
        ``H^-1 b``, minus the Gauss-Newton increment.
    """
    a1, a2, b1, b2, a3, a4, a5, b3, b4, b5 = (
        p[1], p[2], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11])
    d0, d1, d2, e0, e1, e2, d3, d4, d5, e3, e4, e5 = (
        d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7], d[8], d[9], d[10], d[11])
    for c in range(2):
        # row c of I + grad(u_p): constant part (A, B), x slope (ax, bx), y slope (ay, by)
        if c == 0:
            A, B, ax, ay, bx, by = 1.0 + a1, a2, a3, a4, a4, a5
        else:
            A, B, ax, ay, bx, by = b1, 1.0 + b2, b3, b4, b4, b5
        k0 = A * d0 + B * e0
        kx = A * d1 + ax * d0 + B * e1 + bx * e0
        ky = A * d2 + ay * d0 + B * e2 + by * e0
        kxx = A * d3 + 2.0 * ax * d1 + B * e3 + 2.0 * bx * e1
        kxy = A * d4 + ax * d2 + ay * d1 + B * e4 + bx * e2 + by * e1
        kyy = A * d5 + 2.0 * ay * d2 + B * e5 + 2.0 * by * e2
        o = 3 * c  # u: columns 0-2 and 6-8; v: 3-5 and 9-11
        p[o] += k0
        p[o + 1] += kx
        p[o + 2] += ky
        p[6 + o] += kxx
        p[7 + o] += kxy
        p[8 + o] += kyy


@nb.njit(**CALLEE, fastmath=FASTMATH)
def quadratic_step(c1, stride, coef, order, x0, y0, p, dxs, dys, gx, gy, fs, m, fm, dfn,
                   xw, yw, gv, xmax, ymax, qx, qy, sj, bf, fac, b, dp, h, span, start, tol):
    """One quadratic IC-GN step of a node.

    Warps the subset (affine part plus :func:`quadratic_offsets`), samples
    it (:func:`~.gauss_newton.gn_step`), adds the six second-order sums of
    ``J g`` from the sampled values, solves ``H d = b`` with the factors
    ``fac`` and composes ``d`` into ``p`` (:func:`compose_quadratic`).

    Parameters
    ----------
    c1, stride, coef, order, x0, y0, dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv
        As :func:`~.gauss_newton.gn_step`.
    xmax, ymax, qx, qy
        As :func:`~.gauss_newton.gn_step`; ``qx, qy`` are work arrays here.
    p : (12,) float64
        Current parameters, updated in place on success.
    sj, bf : (12,) float64
        Reference sums (:func:`quadratic_reference_sums`).
    fac : ((12, 12) float64, (12,) int64)
        Factors of the reference matrix and their row swaps
        (:func:`~.icgn_node.lu_factor`).
    b, dp : (12,) float64
        Work arrays.
    h, span, start
        As :func:`~.icgn.affine_step`.
    tol : float
        Convergence tolerance (pixels) on the increment's largest
        displacement at the subset edge.

    Returns
    -------
    status : int
        ``NOT_CONVERGED`` to go on, ``OK`` on convergence, else the failure.
    zn : float
        ZNCC of this step (NaN if the step failed).
    """
    quadratic_offsets(p, dxs, dys, m, qx, qy)
    st, zn, r, gm, t0, t1, t2, t3, t4, t5 = gn_step(
        c1, stride, coef, order, x0, y0, p[0], p[1], p[2], p[3], p[4], p[5],
        dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, True, qx, qy)
    if st != OK:
        return st, np.nan
    s6 = s7 = s8 = s9 = s10 = s11 = 0.0
    for q in range(m):
        g = np.float64(gv[q])
        xx = 0.5 * dxs[q] * dxs[q]
        xy = dxs[q] * dys[q]
        yy = 0.5 * dys[q] * dys[q]
        a1 = gx[q] * g
        a2 = gy[q] * g
        s6 += a1 * xx
        s7 += a1 * xy
        s8 += a1 * yy
        s9 += a2 * xx
        s10 += a2 * xy
        s11 += a2 * yy
    t = (t0, t1, t2, t3, t4, t5, s6, s7, s8, s9, s10, s11)
    for i in range(NPAR):  # b = sum J [(f - fm) - (df/dg)(g - gm)]
        b[i] = bf[i] - r * (t[i] - gm * sj[i])
    lu_solve(fac[0], fac[1], b, dp)
    compose_quadratic(p, dp)
    h2 = h * h
    h4 = 0.25 * h2 * h2
    nrm = (dp[0] * dp[0] + dp[3] * dp[3]
           + h2 * (dp[1] * dp[1] + dp[2] * dp[2] + dp[4] * dp[4] + dp[5] * dp[5])
           + h4 * (dp[6] * dp[6] + dp[7] * dp[7] + dp[8] * dp[8] + dp[9] * dp[9]
                   + dp[10] * dp[10] + dp[11] * dp[11]))
    return step_status(p[0] - start[0], p[3] - start[1], span, nrm, tol), zn


@nb.njit(**SERIAL, fastmath=FASTMATH)
def icgn_quadratic(first, stop, f, fgx, fgy, egx, egy, coef, order, nx, ny, p_init, active,
                   slot, masks, h, max_iter, tol, p_out, zncc_out, iters_out, reason_out,
                   stats_out):
    """Quadratic IC-GN at the ``active`` nodes of chunks ``first`` to ``stop``
    (serial, as :func:`~.icgn.icgn_affine`).

    As :func:`~.icgn.icgn_affine` with twelve parameters: per node gather the
    subset, build and factorise the 12 x 12 reference matrix
    (:func:`~.icgn_node.begin_node`; a node without texture is stored as
    ``NO_TEXTURE`` with its initial parameters), then
    iterate :func:`quadratic_step` while it reports ``NOT_CONVERGED`` and
    ``max_iter`` allows.

    Parameters
    ----------
    first, stop, f, fgx, fgy, egx, egy, coef, order, nx, ny, active, slot, masks, h,
    max_iter, tol
        As :func:`~.icgn.icgn_affine`.
    p_init : (n, 12) float64
        Initial parameters (layout in the module docstring).
    p_out, zncc_out, iters_out, reason_out : (n, 12), (n,), (n,), (n,)
        Receive parameters, ZNCC, iterations and status.
    stats_out : (n, 5) float64
        Receives the reference subset's statistics, as for the affine solver.
    """
    n = nx.size
    c1, stride, span, npx, _, xmax, ymax = chunk_layout(f, coef, n, h)
    for c in range(first, stop):
        dxs, dys, gx, gy, fs, xw, yw, gv = subset_buffers(npx)
        qx = np.empty(npx)
        qy = np.empty(npx)
        Jm = np.empty((npx, NPAR))
        Em = np.empty((npx, NPAR))
        ex = np.empty(npx)
        ey = np.empty(npx)
        sj = np.empty(NPAR)
        bf = np.empty(NPAR)
        p = np.empty(NPAR)
        LU, piv, b, dp = solve_buffers(NPAR)
        for k in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if not active[k]:
                continue
            x0, y0, m, fm, df2 = gather_subset(f, fgx, fgy, masks, slot, nx, ny, k, h,
                                               dxs, dys, gx, gy, fs)
            hs = gather_gradients(egx, egy, masks, slot, nx, ny, k, h, ex, ey)
            H = quadratic_reference_sums(dxs, dys, gx, gy, ex, ey, fs, m, fm, Jm, Em, sj, bf)
            for j in range(p.size):  # (no array copy: its shape check compiles slowly)
                p[j] = p_init[k, j]
            status, zn, it, dfn = begin_node(k, m, df2, hs, H, LU, piv, stats_out)
            start = (p[0], p[3])
            while status == NOT_CONVERGED and it < max_iter:
                it += 1
                status, z = quadratic_step(c1, stride, coef, order, x0, y0, p, dxs, dys, gx,
                                           gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, qx, qy,
                                           sj, bf, (LU, piv), b, dp, h, span, start, tol)
                if np.isfinite(z):
                    zn = z
            store_node(k, p, zn, it, status, p_out, zncc_out, iters_out, reason_out)
