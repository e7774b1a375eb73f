"""The analytic speckle intensity of ``synthetic.speckle``.

``I(X) = lo + (hi - lo) (1 - exp(-sum_k a_k exp(-|X - X_k|^2 / (2 s_k^2))))``,
a smooth saturation of a sum of isotropic Gaussian blobs, evaluated at
reference points with the blobs binned on a coarse grid.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH_ALL, PARALLEL

__all__ = ["speckle_intensity"]


@nb.njit(**PARALLEL, fastmath=FASTMATH_ALL)
def speckle_intensity(X, Y, bx, by, sg, amp, start, x0, y0, bin_size, nbx, nby, lo, hi, out):
    """Intensity of the speckle pattern at reference points, in parallel.

    Per point: find its bin, then sum the blobs of the 3 x 3 surrounding bins
    (the bin size is four times the largest blob radius) that lie within four
    standard deviations, and saturate the sum.

    Parameters
    ----------
    X, Y : (n,) float64
        Reference points.
    bx, by, sg, amp : (B,) float64
        Blob centres, standard deviations and amplitudes, sorted by bin.
    start : (nbx * nby + 1,) int64
        CSR index: the blobs of bin ``b`` are ``start[b]:start[b + 1]``.
    x0, y0, bin_size : float
        Origin and size of the bins.
    nbx, nby : int
        Bins along x and y.
    lo, hi : float
        Grey levels of the background and of saturated speckles.
    out : (n,) float64
        Receives the intensities. Under :data:`~.flags.FASTMATH_ALL` (no-NaN
        assumption) LLVM may fold the NaN test of the points away; on x86 a
        NaN point then renders as ``lo``.
    """
    for k in nb.prange(X.size):
        xq = X[k]
        yq = Y[k]
        if np.isnan(xq) or np.isnan(yq):
            out[k] = np.nan
            continue
        ix = int(np.floor((xq - x0) / bin_size))
        iy = int(np.floor((yq - y0) / bin_size))
        s = 0.0
        for jy in range(iy - 1, iy + 2):
            if jy < 0 or jy >= nby:
                continue
            for jx in range(ix - 1, ix + 2):
                if jx < 0 or jx >= nbx:
                    continue
                b = jy * nbx + jx
                for m in range(start[b], start[b + 1]):
                    dx = xq - bx[m]
                    dy = yq - by[m]
                    r2 = dx * dx + dy * dy
                    s2 = sg[m] * sg[m]
                    if r2 < 16.0 * s2:
                        s += amp[m] * np.exp(-0.5 * r2 / s2)
        out[k] = lo + (hi - lo) * (1.0 - np.exp(-s))
