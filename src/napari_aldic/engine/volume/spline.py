"""Tricubic B-spline coefficients of a volume, padded for the kernels."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..kernels.bspline3d import PAD3

__all__ = ["coefficients", "gradients"]


def coefficients(vol: np.ndarray) -> np.ndarray:
    """Padded float32 cubic B-spline coefficients of ``vol`` (z, y, x).

    Prefiltered in float64 (``ndimage.spline_filter``, mirror boundary, the
    same reflection that pads them) then stored float32 (see
    :mod:`~..kernels.bspline3d`).
    """
    c = ndimage.spline_filter(np.asarray(vol, np.float64), order=3, mode="mirror")
    return np.ascontiguousarray(np.pad(c.astype(np.float32), PAD3, mode="reflect"))


def gradients(c: np.ndarray) -> np.ndarray:
    """``(3, nz, ny, nx)`` float32 gradient (d/dx, d/dy, d/dz) at the voxels
    of the spline of padded coefficients ``c``: at a knot the cubic B-spline
    has weights (1/6, 2/3, 1/6) and derivative weights (-1/2, 0, 1/2),
    applied separably."""
    w = np.array([1 / 6, 2 / 3, 1 / 6], np.float32)
    dw = np.array([-0.5, 0.0, 0.5], np.float32)
    inner = tuple(slice(PAD3, s - PAD3) for s in c.shape)
    out = np.empty((3, *(s - 2 * PAD3 for s in c.shape)), np.float32)
    for a, axis in enumerate((2, 1, 0)):  # x, y, z
        g = c
        for ax in (0, 1, 2):
            g = ndimage.correlate1d(g, dw if ax == axis else w, axis=ax, mode="nearest")
        out[a] = g[inner]
    return out
