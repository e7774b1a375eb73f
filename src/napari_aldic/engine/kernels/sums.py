"""Window sums from summed-area tables.

A summed-area table turns the sum over any axis-aligned rectangle into four
look-ups: the window energies of the NCC search and of the static-feature
test use it (the integral images of masks are NumPy's cumulative sums:
``dic.subsets.integral_image``).

Reference: F. C. Crow, "Summed-area tables for texture mapping", SIGGRAPH 1984.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import SERIAL

__all__ = ["window_sums"]


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
