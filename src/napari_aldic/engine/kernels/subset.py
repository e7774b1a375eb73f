"""A node's subset: work buffers, gathering its pixels, and its noise model.

Every per-node kernel (the IC-GN solvers, the noise estimate of the
regularisation) works on the same packed subset: the pixels of the node's
square subset that belong to its mask component, gathered once into flat
buffers with their offsets, reference values and reference gradients.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import INLINE, PARALLEL

__all__ = ["subset_buffers", "gather_subset", "subset_noise"]


@nb.njit(**INLINE)
def subset_buffers(npx):
    """Per-task work arrays of a subset of at most ``npx`` pixels.

    Parameters
    ----------
    npx : int
        Pixels of the full square subset, ``(2h + 1)^2``.

    Returns
    -------
    dxs, dys, gx, gy, fs, xw, yw : (npx,) float64
        Pixel offsets, reference gradients and values, warped positions.
    gv : (npx,) float32
        Sampled deformed grey values.
    """
    return (np.empty(npx), np.empty(npx), np.empty(npx), np.empty(npx), np.empty(npx),
            np.empty(npx), np.empty(npx), np.empty(npx, np.float32))


@nb.njit(**INLINE)
def gather_subset(f, fgx, fgy, masks, slot, nx, ny, k, h, dxs, dys, gx, gy, fs):
    """Copy node ``k``'s subset pixels (its mask component only) into buffers.

    The loop runs over the square subset row by row and skips the pixels
    outside the node's mask component, so cut subsets pack densely.

    Parameters
    ----------
    f, fgx, fgy : (H, W) float32
        Reference image and its spline gradients.
    masks : (m, S, S) uint8
        Component masks of the cut nodes.
    slot : (n,) int32
        Mask slot per node, -1 for a full square subset.
    nx, ny : (n,) int64
        Node pixels.
    k : int
        The node.
    h : int
        Subset half-width.
    dxs, dys, gx, gy, fs : (>= S^2,) float64
        Receive the offsets, gradients and values of the used pixels.

    Returns
    -------
    x0, y0 : int
        The node pixel.
    m : int
        Number of pixels gathered.
    fm : float64
        Their mean grey value.
    df2 : float64
        Their sum of squared deviations from the mean.
    """
    x0 = nx[k]
    y0 = ny[k]
    sl = slot[k]
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
    return x0, y0, m, fm, sff - m * fm * fm


@nb.njit(**PARALLEL)
def subset_noise(f, fgx, fgy, xs, ys, slot, masks, h, one_minus_zncc, gain, out):
    """Predicted noise variance of each node's local displacement.

    Per node, in parallel: gather the subset exactly as IC-GN does, sum its
    2 x 2 Gauss-Newton matrix ``H`` from the reference gradients, estimate the
    image noise from the node's ZNCC (``var_e = (1 - ZNCC) df2 / m``), remove
    the noise energy the gradients carry (``m var_e gain`` per direction) to
    keep the speckle part ``S``, and return ``2 var_e S^-1 H S^-1`` (noise in
    both images).

    Parameters
    ----------
    f, fgx, fgy : (H, W) float32
        Reference image and its spline gradients.
    xs, ys : (n,) int64
        Node pixels.
    slot, masks
        Mask slot per node and the component masks of the cut nodes.
    h : int
        Subset half-width.
    one_minus_zncc : (n,) float64
        ``1 - ZNCC`` per node (NaN: unknown).
    gain : float
        Variance of the spline derivative of unit white noise.
    out : (n, 2) float64
        Receives the variances of ``u`` and ``v`` (NaN where undefined).
    """
    n = xs.size
    npx = (2 * h + 1) ** 2
    for i in nb.prange(n):
        dxs, dys, gx, gy, fs, _, _, _ = subset_buffers(npx)
        # the subset's pixels exactly as IC-GN gathers them (mask component only)
        _, _, m, fm, df2 = gather_subset(f, fgx, fgy, masks, slot, xs, ys, i, h,
                                         dxs, dys, gx, gy, fs)
        hxx = hxy = hyy = 0.0
        for q in range(m):
            hxx += gx[q] * gx[q]
            hxy += gx[q] * gy[q]
            hyy += gy[q] * gy[q]
        if m == 0 or not one_minus_zncc[i] >= 0.0:
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            continue
        var_e = one_minus_zncc[i] * df2 / m
        # the gradients of the noisy reference carry noise energy m var_e gain
        # per direction; only the rest (the speckle's) makes the subset match
        e = m * var_e * gain
        sxx = max(hxx - e, 0.1 * hxx)
        syy = max(hyy - e, 0.1 * hyy)
        det = sxx * syy - hxy * hxy
        if det <= 0.0:
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            continue
        # covariance 2 var_e S^-1 H S^-1 (S: signal part of H)
        a = syy / det
        b = -hxy / det
        c = sxx / det
        out[i, 0] = 2.0 * var_e * (a * a * hxx + 2 * a * b * hxy + b * b * hyy)
        out[i, 1] = 2.0 * var_e * (b * b * hxx + 2 * b * c * hxy + c * c * hyy)
