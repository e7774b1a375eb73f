"""Tricubic B-spline sampling over padded float32 coefficients (DVC).

The coefficients come from :mod:`.prefilter3d` (order 3, mirror boundary:
``scipy.ndimage.spline_filter``'s to 1e-15) padded by :data:`PAD3` voxels on
every side by mirroring, so the samplers never bounds-check inside a subset.
They are float32 on purpose: the 64-tap sum is memory bound, float32 halves
its traffic, and its rounding (~1e-7 of the grey level) is far below the 1e-3
voxel the solver resolves; weights and sums are float32 too, positions
float64.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .bspline import cubic_weights
from .flags import FASTMATH, INLINE

__all__ = ["PAD3", "tricubic"]

PAD3 = 6  # coefficient padding in voxels on every side


@nb.njit(**INLINE, fastmath=FASTMATH)
def tricubic(c, x, y, z):
    """Value of the spline of padded coefficients ``c`` (z, y, x) at voxel
    point ``(x, y, z)`` of the unpadded volume (caller keeps it within
    ``PAD3 - 2`` voxels of the volume)."""
    xf = math.floor(x)
    yf = math.floor(y)
    zf = math.floor(z)
    ix = int(xf) + PAD3 - 1
    iy = int(yf) + PAD3 - 1
    iz = int(zf) + PAD3 - 1
    wx0, wx1, wx2, wx3 = cubic_weights(np.float32(x - xf))
    wy0, wy1, wy2, wy3 = cubic_weights(np.float32(y - yf))
    wz0, wz1, wz2, wz3 = cubic_weights(np.float32(z - zf))
    acc = np.float32(0.0)
    for k in range(4):
        wz = wz0 if k == 0 else (wz1 if k == 1 else (wz2 if k == 2 else wz3))
        row = np.float32(0.0)
        for j in range(4):
            wy = wy0 if j == 0 else (wy1 if j == 1 else (wy2 if j == 2 else wy3))
            p = c[iz + k, iy + j]
            row += wy * (wx0 * p[ix] + wx1 * p[ix + 1] + wx2 * p[ix + 2] + wx3 * p[ix + 3])
        acc += wz * row
    return acc
