"""The Gauss-Newton step shared by the IC-GN solvers of :mod:`.icgn`.

Both solvers run nodes in parallel chunks (:func:`chunk_layout`), write each
node's outcome with :func:`store_node`, and evaluate every iteration with
:func:`gn_step`: warp the gathered subset, sample the deformed image's
B-spline (:mod:`.bspline`, float32 taps) and accumulate, in one pass, the
nine sums from which the ZNCC and the Gauss-Newton right-hand side follow.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .bspline import sample_cubic_f32, sample_quintic_f32
from .flags import FASTMATH, INLINE, SERIAL_CALLEE

__all__ = ["OK", "NOT_CONVERGED", "OUT_OF_IMAGE", "NO_TEXTURE", "DIVERGED", "CHUNK",
           "chunk_layout", "store_node", "warp_sums", "gn_step"]

#: status codes the kernels write: the values of ``core.reasons.Reason``
#: (kernels import numpy/numba only; ``dic.icgn`` checks that they agree)
OK = 0
NOT_CONVERGED = 2
OUT_OF_IMAGE = 3
NO_TEXTURE = 5
DIVERGED = 6

CHUNK = 16  # nodes per parallel task


@nb.njit(**INLINE)
def chunk_layout(f, coef, n, h):
    """Set-up shared by the IC-GN kernels.

    Parameters
    ----------
    f : (H, W) array
        Reference image (its shape bounds the warped subsets).
    coef : (H + 2 PAD, W + 2 PAD) float32
        Padded B-spline coefficients of the deformed image.
    n : int
        Number of nodes.
    h : int
        Subset half-width.

    Returns
    -------
    c1 : 1-D float32
        ``coef`` flattened row by row (the samplers' view).
    stride : int
        Row length of ``coef``.
    span : int
        Subset width ``2h + 1``: a solution farther than this from its start
        has diverged.
    npx : int
        Pixels of the full square subset (buffer length).
    nchunks : int
        Parallel tasks of :data:`CHUNK` nodes.
    xmax, ymax : float
        Largest column and row a warped pixel may reach (inside the image).
    """
    rows, cols = f.shape
    span = 2 * h + 1
    return (coef.ravel(), coef.shape[1], span, span * span, (n + CHUNK - 1) // CHUNK,
            cols - 1.0, rows - 1.0)


@nb.njit(**INLINE)
def store_node(k, p, zn, it, status, p_out, zncc_out, iters_out, reason_out):
    """Write node ``k``'s outcome.

    Parameters
    ----------
    k : int
        Node index.
    p : tuple of float
        Its parameters (one per column of ``p_out``).
    zn : float
        Its ZNCC.
    it : int
        Gauss-Newton iterations run.
    status : int
        Status code (:data:`OK`, :data:`NO_TEXTURE`, ...).
    p_out, zncc_out, iters_out, reason_out : arrays
        The kernel's outputs.
    """
    for i in range(len(p)):
        p_out[k, i] = p[i]
    zncc_out[k] = zn
    iters_out[k] = it
    reason_out[k] = status


@nb.njit(**INLINE, fastmath=FASTMATH)
def warp_sums(c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
              dxs, dys, gx, gy, fs, m, xw, yw, gv, xmax, ymax, quad, qx, qy):
    """Warp the subset, sample the deformed image and sum one Gauss-Newton step.

    The first loop warps every pixel (affine map, plus the fixed offsets
    ``qx, qy`` of the second-order terms when ``quad``) and tracks the
    bounding box; the second samples the spline; the third accumulates the
    sums. The loops are split so that LLVM can vectorise the warp and the sums.

    Parameters
    ----------
    c1, stride, coef, order
        Deformed image: flat coefficients, row length, coefficients, 3 or 5.
    x0, y0 : int
        Node pixel.
    u, ux, uy, v, vx, vy : float
        Affine warp parameters.
    dxs, dys, gx, gy, fs : 1-D float64
        The gathered subset (offsets, reference gradients and values).
    m : int
        Subset pixels.
    xw, yw, gv
        Work buffers: warped positions, sampled values.
    xmax, ymax : float
        Image bounds of the warped pixels.
    quad : bool
        Add the second-order offsets ``qx, qy``.

    Returns
    -------
    inside : bool
        False if the warped subset leaves the image (the sums are then 0).
    sg, sgg, sfg : float
        ``sum g``, ``sum g^2``, ``sum f g``.
    t0, t1, t2, t3, t4, t5 : float
        ``sum gx g``, ``sum gx g dx``, ``sum gx g dy``, ``sum gy g``,
        ``sum gy g dx``, ``sum gy g dy``.
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
        sample_cubic_f32(c1, stride, xw, yw, gv, m)
    else:
        sample_quintic_f32(c1, stride, xw, yw, gv, m)
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


@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
def gn_step(c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
            dxs, dys, gx, gy, fs, m, fm, dfn, xw, yw, gv, xmax, ymax, quad, qx, qy):
    """Evaluate the warped subset for one Gauss-Newton step.

    Parameters
    ----------
    c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy, dxs, dys, gx, gy, fs, m
        As :func:`warp_sums`.
    xw, yw, gv, xmax, ymax, quad, qx, qy
        As :func:`warp_sums`.
    fm : float
        Mean of the reference subset.
    dfn : float
        ``sqrt(sum (f - fm)^2)`` of the reference subset.

    Returns
    -------
    status : int
        :data:`OK`, :data:`OUT_OF_IMAGE` or :data:`NO_TEXTURE` (flat
        deformed subset).
    zncc : float
        Zero-normalised cross-correlation of the subsets (NaN unless OK).
    r : float
        ``dfn / dgn``, the grey-level scale between the subsets.
    gm : float
        Mean of the deformed subset.
    t0, t1, t2, t3, t4, t5 : float
        The gradient-weighted sums of :func:`warp_sums`.
    """
    inside, sg, sgg, sfg, t0, t1, t2, t3, t4, t5 = warp_sums(
        c1, stride, coef, order, x0, y0, u, ux, uy, v, vx, vy,
        dxs, dys, gx, gy, fs, m, xw, yw, gv, xmax, ymax, quad, qx, qy)
    if not inside:
        return OUT_OF_IMAGE, np.nan, 0.0, 0.0, t0, t1, t2, t3, t4, t5
    gm = sg / m
    dg2 = sgg - m * gm * gm
    if dg2 <= 1e-6 * m:
        return NO_TEXTURE, np.nan, 0.0, gm, t0, t1, t2, t3, t4, t5
    dgn = np.sqrt(dg2)
    return OK, (sfg - m * fm * gm) / (dfn * dgn), dfn / dgn, gm, t0, t1, t2, t3, t4, t5
