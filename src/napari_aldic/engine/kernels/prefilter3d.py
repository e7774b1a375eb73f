"""Tricubic B-spline prefilter and knot gradients of a volume, parallel (DVC).

The cubic B-spline interpolation coefficients solve ``(1/6, 2/3, 1/6) * c = s``
along each axis: a causal and an anti-causal first-order recursion with the
pole ``z = sqrt(3) - 2`` and gain 6 (Unser, IEEE Signal Proc. Mag. 16, 1999),
with the whole-sample mirror boundary (scipy.ndimage ``mode="mirror"``): the
causal start is the sum of the mirrored line weighed by ``z^k`` (truncated
where ``|z|^k`` is below 1e-16, as scipy does for lines longer than that),
the anti-causal start ``z / (z^2 - 1) (c+[N-1] + z c+[N-2])``. Computed in
float64 in place, parallel over slices (the lines along y and z are run
side by side along x, so every access is contiguous).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .flags import CALLEE, INLINE, PARALLEL

__all__ = ["prefilter_inplace", "knot_gradients"]

_POLE = math.sqrt(3.0) - 2.0
_GAIN = 6.0
_HORIZON = int(math.ceil(math.log(1e-16) / math.log(abs(_POLE))))


@nb.njit(**INLINE)
def _causal_start(line, n):
    """``c+[0]`` of one line (mirror boundary)."""
    z = _POLE
    if n <= 1:
        return line[0]
    if _HORIZON < n:
        s = 0.0
        zk = 1.0
        for k in range(_HORIZON):
            s += zk * line[k]
            zk *= z
        return s
    # exact: the mirrored line has period 2n - 2
    zn = z ** (n - 1)
    z2n = zn * zn
    s = line[0] + zn * line[n - 1]
    zk = z
    for k in range(1, n - 1):
        s += (zk + z2n / zk) * line[k]
        zk *= z
    return s / (1.0 - zn * zn)


@nb.njit(**INLINE)
def _filter_line(line, n):
    z = _POLE
    for k in range(n):
        line[k] *= _GAIN
    if n <= 1:
        return
    line[0] = _causal_start(line, n)
    for k in range(1, n):
        line[k] += z * line[k - 1]
    line[n - 1] = z / (z * z - 1.0) * (line[n - 1] + z * line[n - 2])
    for k in range(n - 2, -1, -1):
        line[k] = z * (line[k + 1] - line[k])


@nb.njit(**PARALLEL)
def _along_x(c):
    nz, ny, nx = c.shape
    for iz in nb.prange(nz):
        for iy in range(ny):
            _filter_line(c[iz, iy], nx)


@nb.njit(**CALLEE)
def _filter_cols(a):
    """Filter the 2-D array ``a`` (n, m) along axis 0, its m columns side by side."""
    n, m = a.shape
    z = _POLE
    for k in range(n):
        for i in range(m):
            a[k, i] *= _GAIN
    if n <= 1:
        return
    start = np.zeros(m)
    if _HORIZON < n:
        zk = 1.0
        for k in range(_HORIZON):
            for i in range(m):
                start[i] += zk * a[k, i]
            zk *= z
    else:
        zn = z ** (n - 1)
        for i in range(m):
            start[i] = a[0, i] + zn * a[n - 1, i]
        zk = z
        for k in range(1, n - 1):
            wk = zk + zn * zn / zk
            for i in range(m):
                start[i] += wk * a[k, i]
            zk *= z
        for i in range(m):
            start[i] /= 1.0 - zn * zn
    for i in range(m):
        a[0, i] = start[i]
    for k in range(1, n):
        for i in range(m):
            a[k, i] += z * a[k - 1, i]
    for i in range(m):
        a[n - 1, i] = z / (z * z - 1.0) * (a[n - 1, i] + z * a[n - 2, i])
    for k in range(n - 2, -1, -1):
        for i in range(m):
            a[k, i] = z * (a[k + 1, i] - a[k, i])


@nb.njit(**PARALLEL)
def _along_y(c):
    for iz in nb.prange(c.shape[0]):
        _filter_cols(c[iz])


@nb.njit(**PARALLEL)
def _along_z(c):
    for iy in nb.prange(c.shape[1]):
        _filter_cols(c[:, iy, :])


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
