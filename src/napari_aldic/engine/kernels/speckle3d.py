"""Renderer of 3-D speckle volumes: Gaussian blobs seen through an affine map.

The volume is ``I(x) = lo + (hi - lo) * sum_i a_i exp(-|X(x) - c_i|^2 / (2 s_i^2))``
with ``X(x) = Ainv (x - t)`` the reference point of voxel ``x``: a deformed
volume is the reference pattern evaluated at inverse-mapped coordinates, so
it is exact (no interpolation) for any affine motion, rotation included.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .flags import FASTMATH, PARALLEL

__all__ = ["render_blobs"]


@nb.njit(**PARALLEL, fastmath=FASTMATH)
def render_blobs(out, centres, sigma, amp, Ainv, t, reach):
    """Add the blobs to ``out`` (parallel over z planes, so no two threads
    write one voxel).

    Parameters
    ----------
    out : (nz, ny, nx) float64
        Receives the sum (added to).
    centres : (n, 3) float64
        Blob centres in the reference, (x, y, z) voxels.
    sigma, amp : (n,) float64
        Blob widths (voxels) and amplitudes.
    Ainv : (3, 3) float64
        Inverse of the linear part of the motion (x, y, z order).
    t : (3,) float64
        Translation part: a reference point ``X`` maps to ``A X + t``.
    reach : float
        Blob footprint half-width in units of its sigma (4 keeps 3e-4).
    """
    nz, ny, nx = out.shape
    n = centres.shape[0]
    A = np.linalg.inv(Ainv)
    # deformed centre and footprint radius of each blob (A stretches it)
    cd = np.empty((n, 3))
    norm = 0.0
    for i in range(3):
        for j in range(3):
            norm += A[i, j] * A[i, j]
    stretch = math.sqrt(norm)
    for b in range(n):
        for i in range(3):
            cd[b, i] = t[i] + A[i, 0] * centres[b, 0] + A[i, 1] * centres[b, 1] \
                + A[i, 2] * centres[b, 2]
    for z in nb.prange(nz):
        for b in range(n):
            r = reach * sigma[b] * stretch
            if abs(z - cd[b, 2]) > r:
                continue
            inv2 = 0.5 / (sigma[b] * sigma[b])
            y0 = max(int(math.floor(cd[b, 1] - r)), 0)
            y1 = min(int(math.ceil(cd[b, 1] + r)), ny - 1)
            x0 = max(int(math.floor(cd[b, 0] - r)), 0)
            x1 = min(int(math.ceil(cd[b, 0] + r)), nx - 1)
            dz = z - t[2]
            for y in range(y0, y1 + 1):
                dy = y - t[1]
                for x in range(x0, x1 + 1):
                    dx = x - t[0]
                    X = Ainv[0, 0] * dx + Ainv[0, 1] * dy + Ainv[0, 2] * dz - centres[b, 0]
                    Y = Ainv[1, 0] * dx + Ainv[1, 1] * dy + Ainv[1, 2] * dz - centres[b, 1]
                    Z = Ainv[2, 0] * dx + Ainv[2, 1] * dy + Ainv[2, 2] * dz - centres[b, 2]
                    out[z, y, x] += amp[b] * math.exp(-(X * X + Y * Y + Z * Z) * inv2)
