"""Summed-area tables and window sums.

An integral image turns the sum over any axis-aligned rectangle into four
look-ups: the mask tests of the subsets, the quadtree and the lattice
neighbours, and the window energies of the NCC search, use it.

Reference: F. C. Crow, "Summed-area tables for texture mapping", SIGGRAPH 1984.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import CACHED, SERIAL

__all__ = ["integral_image", "window_sums"]


@nb.njit(**CACHED)
def integral_image(mask):
    """Summed-area table of a boolean/uint8 image.

    Row by row, a running sum of the row is added to the table's row above.

    Parameters
    ----------
    mask : (H, W) uint8 or bool
        The image.

    Returns
    -------
    (H + 1, W + 1) int64
        ``ii[i, j]`` is the sum of ``mask[:i, :j]``.
    """
    h, w = mask.shape
    ii = np.zeros((h + 1, w + 1), np.int64)
    for i in range(h):
        run = 0
        for j in range(w):
            run += mask[i, j]
            ii[i + 1, j + 1] = ii[i, j + 1] + run
    return ii


# serial (issue 25): threads cost more than they gain here (measured, 2 cores),
# and a parallel kernel compiles ~3x longer
@nb.njit(**SERIAL)
def window_sums(a, S):
    """Sums of ``a`` and ``a**2`` over every ``S x S`` window of a batch.

    Per batch item, in parallel: build the float64 summed-area tables of the
    values and of their squares, then read every window's sums from four
    corners. They give the local energy of every shift of the NCC search.

    Parameters
    ----------
    a : (B, L, L) float32
        Search windows.
    S : int
        Window (subset) width.

    Returns
    -------
    s1, s2 : (B, L - S + 1, L - S + 1) float64
        Window sums of ``a`` and of ``a**2``.
    """
    B, L, _ = a.shape
    K = L - S + 1
    s1 = np.empty((B, K, K))
    s2 = np.empty((B, K, K))
    for b in nb.prange(B):
        c1 = np.zeros((L + 1, L + 1))
        c2 = np.zeros((L + 1, L + 1))
        for i in range(L):
            r1 = 0.0
            r2 = 0.0
            for j in range(L):
                x = np.float64(a[b, i, j])
                r1 += x
                r2 += x * x
                c1[i + 1, j + 1] = c1[i, j + 1] + r1
                c2[i + 1, j + 1] = c2[i, j + 1] + r2
        for i in range(K):
            for j in range(K):
                s1[b, i, j] = c1[i + S, j + S] - c1[i, j + S] - c1[i + S, j] + c1[i, j]
                s2[b, i, j] = c2[i + S, j + S] - c2[i, j + S] - c2[i + S, j] + c2[i, j]
    return s1, s2
