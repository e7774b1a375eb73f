"""Tricubic B-spline coefficients of a volume, padded for the kernels."""

from __future__ import annotations

import numpy as np

from ..kernels.bspline3d import PAD3
from ..kernels.prefilter3d import knot_gradients, prefilter_inplace

__all__ = ["coefficients", "gradients"]


def coefficients(vol: np.ndarray) -> np.ndarray:
    """Padded float32 cubic B-spline coefficients of ``vol`` (z, y, x).

    Prefiltered in float64 (:mod:`~..kernels.prefilter3d`, parallel; the
    same as ``ndimage.spline_filter(order=3, mode="mirror")`` to 1e-15, and
    the same reflection pads them) then stored float32 (see
    :mod:`~..kernels.bspline3d`).
    """
    c = np.array(vol, np.float64, order="C")
    prefilter_inplace(c)
    return np.ascontiguousarray(np.pad(c.astype(np.float32), PAD3, mode="reflect"))


def gradients(c: np.ndarray) -> np.ndarray:
    """``(3, nz, ny, nx)`` float32 gradient (d/dx, d/dy, d/dz) at the voxels
    of the spline of padded coefficients ``c``: at a knot the cubic B-spline
    has weights (1/6, 2/3, 1/6) and derivative weights (-1/2, 0, 1/2),
    applied separably."""
    out = np.empty((3, *(s - 2 * PAD3 for s in c.shape)), np.float32)
    knot_gradients(c, PAD3, out)
    return out
