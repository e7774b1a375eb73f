"""A node's subset: work buffers, gathering its pixels, and its statistics.

Every per-node kernel (the IC-GN solvers, the subset statistics behind the
noise model and the validity tests) works on the same packed subset: the pixels of the node's
square subset that belong to its mask component, gathered once into flat
buffers with their offsets, reference values and reference gradients.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE, PARALLEL, SERIAL_CALLEE

__all__ = ["subset_buffers", "gather_subset", "gather_gradients", "subset_stats"]


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


# called once per node: compiled once as a function (shared by the IC-GN kernels,
# ~2 s less compiling), not inlined; the call costs nothing measurable
@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
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


# called once per node: compiled once as a function (shared by the IC-GN kernels,
# ~2 s less compiling), not inlined; the call costs nothing measurable
@nb.njit(**SERIAL_CALLEE, fastmath=FASTMATH)
def gather_gradients(egx, egy, masks, slot, nx, ny, k, h, ex, ey):
    """Copy the gradients ``egx, egy`` of node ``k``'s subset pixels into
    buffers, in the order of :func:`gather_subset`.

    The IC-GN solvers linearise the warp with the exact spline gradients
    while their steepest-descent images may use smoothed ones (gathered by
    :func:`gather_subset`): the instrumental-variable step needs both.

    Parameters
    ----------
    egx, egy : (H, W) float32
        Reference gradients.
    masks, slot, nx, ny, k, h
        As :func:`gather_subset`.
    ex, ey : (>= S^2,) float64
        Receive the gradients of the used pixels.

    Returns
    -------
    hxx, hxy, hyy : float
        ``sum ex^2, sum ex ey, sum ey^2``: the subset's 2 x 2 Gauss-Newton
        matrix of the displacement, as :func:`subset_stats` sums it.
    """
    x0 = nx[k]
    y0 = ny[k]
    sl = slot[k]
    m = 0
    hxx = hxy = hyy = 0.0
    for a in range(-h, h + 1):
        for bb in range(-h, h + 1):
            if sl >= 0 and masks[sl, a + h, bb + h] == 0:
                continue
            gxv = np.float64(egx[y0 + a, x0 + bb])
            gyv = np.float64(egy[y0 + a, x0 + bb])
            ex[m] = gxv
            ey[m] = gyv
            hxx += gxv * gxv
            hxy += gxv * gyv
            hyy += gyv * gyv
            m += 1
    return hxx, hxy, hyy


@nb.njit(**PARALLEL)
def subset_stats(f, fgx, fgy, xs, ys, slot, masks, h, out):
    """Per-node statistics of the reference subset, in parallel.

    Each subset is gathered exactly as IC-GN gathers it (mask component
    only); the sums give its grey-level variance and its 2 x 2 Gauss-Newton
    matrix of the displacement, from which the expected correlation of a
    correct match and the noise of the displacement follow.

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
    out : (n, 5) float64
        Receives ``(m, var_f, hxx, hxy, hyy)``: pixels used, grey-level
        variance ``sum (f - fm)^2 / m`` and ``sum gx^2, sum gx gy, sum gy^2``.
    """
    n = xs.size
    npx = (2 * h + 1) ** 2
    for i in nb.prange(n):
        dxs, dys, gx, gy, fs, _, _, _ = subset_buffers(npx)
        _, _, m, fm, df2 = gather_subset(f, fgx, fgy, masks, slot, xs, ys, i, h,
                                         dxs, dys, gx, gy, fs)
        hxx = hxy = hyy = 0.0
        for q in range(m):
            hxx += gx[q] * gx[q]
            hxy += gx[q] * gy[q]
            hyy += gy[q] * gy[q]
        out[i, 0] = m
        out[i, 1] = df2 / m if m > 0 else 0.0
        out[i, 2] = hxx
        out[i, 3] = hxy
        out[i, 4] = hyy
