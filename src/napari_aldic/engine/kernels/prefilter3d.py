"""Tricubic B-spline prefilter and knot gradients of a volume, parallel (DVC).

The cubic B-spline coefficients along each axis come from the recursive line
filters of :mod:`.prefilter` (whole-sample mirror boundary, float64, in
place), run in parallel over slices; the lines along y and z are filtered
side by side along x, so every access is contiguous.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import PARALLEL
from .prefilter import GAINS, POLES, filter_cols, filter_line

__all__ = ["prefilter_inplace", "knot_gradients"]

_CUBIC = POLES[3]
_GAIN = GAINS[3]


@nb.njit(**PARALLEL)
def _along_x(c):
    nz, ny, nx = c.shape
    for iz in nb.prange(nz):
        for iy in range(ny):
            filter_line(c[iz, iy], nx, _CUBIC, _GAIN)


@nb.njit(**PARALLEL)
def _along_y(c):
    for iz in nb.prange(c.shape[0]):
        filter_cols(c[iz], _CUBIC, _GAIN)


@nb.njit(**PARALLEL)
def _along_z(c):
    for iy in nb.prange(c.shape[1]):
        filter_cols(c[:, iy, :], _CUBIC, _GAIN)


def prefilter_inplace(c: np.ndarray) -> None:
    """Replace the float64 C-contiguous volume ``c`` (z, y, x) by its cubic
    B-spline coefficients (mirror boundary)."""
    _along_x(c)
    _along_y(c)
    _along_z(c)


@nb.njit(**PARALLEL)
def knot_gradients(c, pad, out):
    """``out (3, nz, ny, nx)`` = d/dx, d/dy, d/dz of the spline of padded
    coefficients ``c`` at the voxels: separable (1/6, 2/3, 1/6) and
    (-1/2, 0, 1/2) weights per slice (z, then y, then x)."""
    _, nz, ny, nx = out.shape
    py, px = c.shape[1], c.shape[2]
    a, b = 1.0 / 6.0, 2.0 / 3.0
    for k in nb.prange(nz):
        zc = k + pad
        sz = np.empty((py, px), np.float32)  # z-smoothed slice
        dz = np.empty((py, px), np.float32)  # z-derivative slice
        for j in range(py):
            for i in range(px):
                lo = c[zc - 1, j, i]
                hi = c[zc + 1, j, i]
                sz[j, i] = a * (lo + hi) + b * c[zc, j, i]
                dz[j, i] = 0.5 * (hi - lo)
        r_s = np.empty(px, np.float32)
        r_d = np.empty(px, np.float32)
        r_z = np.empty(px, np.float32)
        for j in range(ny):
            yc = j + pad
            for i in range(px):
                lo = sz[yc - 1, i]
                hi = sz[yc + 1, i]
                r_s[i] = a * (lo + hi) + b * sz[yc, i]
                r_d[i] = 0.5 * (hi - lo)
                r_z[i] = a * (dz[yc - 1, i] + dz[yc + 1, i]) + b * dz[yc, i]
            for i in range(nx):
                xc = i + pad
                out[0, k, j, i] = 0.5 * (r_s[xc + 1] - r_s[xc - 1])
                out[1, k, j, i] = a * (r_d[xc - 1] + r_d[xc + 1]) + b * r_d[xc]
                out[2, k, j, i] = a * (r_z[xc - 1] + r_z[xc + 1]) + b * r_z[xc]
