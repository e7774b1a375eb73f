"""Tricubic B-spline coefficients of a volume, padded for the kernels."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..kernels.bspline3d import PAD3

__all__ = ["coefficients"]


def coefficients(vol: np.ndarray) -> np.ndarray:
    """Padded float32 cubic B-spline coefficients of ``vol`` (z, y, x).

    Prefiltered in float64 (``ndimage.spline_filter``, mirror boundary, the
    same reflection that pads them) then stored float32 (see
    :mod:`~..kernels.bspline3d`).
    """
    c = ndimage.spline_filter(np.asarray(vol, np.float64), order=3, mode="mirror")
    return np.ascontiguousarray(np.pad(c.astype(np.float32), PAD3, mode="reflect"))
