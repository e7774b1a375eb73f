"""B-spline prefilters: interpolation coefficients by recursive filtering.

The B-spline coefficients ``c`` of samples ``s`` solve ``b * c = s`` along
each axis, with ``b`` the B-spline at the knots (``(1, 4, 1) / 6`` cubic,
``(1, 26, 66, 26, 1) / 120`` quintic). The inverse of ``b`` factors into a
gain and, per pole ``z`` of ``b`` (cubic: ``sqrt(3) - 2``; quintic: two), a
causal and an anti-causal first-order recursion (M. Unser, "Splines: a
perfect fit for signal and image processing", IEEE Signal Proc. Mag. 16,
1999). The boundary is the whole-sample mirror (scipy.ndimage
``mode="mirror"``): the causal start is the mirrored line's sum weighed by
``z^k``, truncated where ``|z|^k`` falls below 1e-16 (as scipy does on lines
longer than that; exact on shorter ones), the anti-causal start
``z / (z^2 - 1) (c+[N-1] + z c+[N-2])``. Everything is float64, in place.

The line filters are shared by the 2-D prefilter here (serial, GIL released:
the image preparation runs two of them side by side) and the parallel 3-D one
(:mod:`.prefilter3d`). Lines along the slow axis are filtered side by side
(:func:`filter_cols`) so every access is contiguous.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .flags import CALLEE, INLINE, SERIAL

__all__ = ["POLES", "GAINS", "filter_line", "filter_cols", "prefilter_2d"]

#: poles of the inverse B-spline filter per order (Unser 1999: the roots of
#: ``b`` inside the unit circle; the quintic ones written out, as their
#: closed forms lose 1e-14 to cancellation)
POLES = {
    3: np.array([math.sqrt(3.0) - 2.0]),
    5: np.array([-0.43057534709997379185, -0.04309628820326465382]),
}

#: gain of the inverse filter, ``prod (1 - z)(1 - 1/z)`` over the poles: the
#: reciprocal of the B-spline's knot weights' normalisation (6 and 120)
GAINS = {3: 6.0, 5: 120.0}


@nb.njit(**INLINE)
def _horizon(z):
    """Terms of the causal start's sum before ``|z|^k`` is below 1e-16."""
    return int(math.ceil(math.log(1e-16) / math.log(abs(z))))


@nb.njit(**INLINE)
def _start_weights(z, n):
    """Weights ``w`` of the causal start ``c+[0] = sum_k w[k] s[k]`` of a line
    of ``n`` samples for the pole ``z`` (mirror boundary): ``z^k`` up to the
    horizon, or on shorter lines the exact sum over the mirrored line, whose
    period is ``2n - 2``."""
    horizon = _horizon(z)
    if horizon < n:
        w = np.empty(horizon)
        zk = 1.0
        for k in range(horizon):
            w[k] = zk
            zk *= z
        return w
    w = np.empty(n)
    zn = z ** (n - 1)
    scale = 1.0 / (1.0 - zn * zn)
    w[0] = scale
    w[n - 1] = zn * scale
    zk = z
    for k in range(1, n - 1):
        w[k] = (zk + zn * zn / zk) * scale
        zk *= z
    return w


@nb.njit(**INLINE)
def filter_line(line, n, poles, gain):
    """Replace the ``n`` samples of the contiguous ``line`` by their B-spline
    coefficients (``poles``, ``gain``: :data:`POLES`, :data:`GAINS`)."""
    if n <= 1:  # a constant's coefficients are itself
        return
    for k in range(n):
        line[k] *= gain
    for z in poles:
        w = _start_weights(z, n)
        s = 0.0
        for k in range(w.size):
            s += w[k] * line[k]
        line[0] = s
        for k in range(1, n):
            line[k] += z * line[k - 1]
        line[n - 1] = z / (z * z - 1.0) * (line[n - 1] + z * line[n - 2])
        for k in range(n - 2, -1, -1):
            line[k] = z * (line[k + 1] - line[k])


@nb.njit(**CALLEE)
def filter_cols(a, poles, gain):
    """Filter the 2-D array ``a`` (n, m) along axis 0, its m columns side by
    side (as :func:`filter_line` does one line)."""
    n, m = a.shape
    if n <= 1:
        return
    for k in range(n):
        for i in range(m):
            a[k, i] *= gain
    start = np.empty(m)
    for z in poles:
        w = _start_weights(z, n)
        for i in range(m):
            start[i] = w[0] * a[0, i]
        for k in range(1, w.size):
            for i in range(m):
                start[i] += w[k] * a[k, i]
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


@nb.njit(**SERIAL)
def prefilter_2d(c, poles, gain):
    """Replace the float64 C-contiguous image ``c`` (rows, columns) by its
    B-spline coefficients, in place (``poles``, ``gain``: :data:`POLES`,
    :data:`GAINS` of the order). One thread, 1024²: cubic ~0.009 s, quintic
    ~0.016 s, a third of scipy.ndimage.spline_filter's time, with the same
    float32 coefficients."""
    rows, cols = c.shape
    for r in range(rows):
        filter_line(c[r], cols, poles, gain)
    filter_cols(c, poles, gain)


@nb.njit(**INLINE)
def _reflect(i, n):
    """Index ``i`` (``-n <= i < 2n``) reflected into ``0..n-1`` about the
    pixel edges (``scipy.ndimage`` ``mode="reflect"``, NumPy's "symmetric")."""
    if i < 0:
        return -i - 1
    if i >= n:
        return 2 * n - 1 - i
    return i


@nb.njit(**SERIAL)
def symmetric_fir_2d(a, w, out):
    """Filter the float64 image ``a`` by the symmetric taps ``w`` (odd length
    ``2r + 1``, ``r`` below both sides) along columns, then along rows, with
    the half-sample reflecting boundary; the result goes to ``out``.

    Each output is ``w[r] x[i] + sum_{j=r..1} (x[i+j] + x[i-j]) w[r+j]`` in
    that order and without fast-math, so a Gaussian's taps give
    ``scipy.ndimage.gaussian_filter(a, sigma, mode="reflect")`` bit for bit
    (its sums run in this order). One thread, 1024² and 5 taps: ~5 ms (ndimage: ~22 ms).
    """
    rows, cols = a.shape
    r = (w.size - 1) // 2
    # one output row at a time: its column-filtered row (reflected at both
    # ends) in a buffer, then filtered along it; no image-sized temporary
    line = np.empty(cols + 2 * r)
    mid = line[r:r + cols]
    for i in range(rows):
        for c in range(cols):
            mid[c] = a[i, c] * w[r]
        for j in range(r, 0, -1):
            hi = a[_reflect(i + j, rows)]
            lo = a[_reflect(i - j, rows)]
            wj = w[r + j]
            for c in range(cols):
                mid[c] += (hi[c] + lo[c]) * wj
        for c in range(1, r + 1):
            line[r - c] = mid[c - 1]
            line[cols + r - 1 + c] = mid[cols - c]
        for c in range(cols):
            out[i, c] = line[c + r] * w[r]
        for j in range(r, 0, -1):
            wj = w[r + j]
            for c in range(cols):
                out[i, c] += (line[c + r + j] + line[c + r - j]) * wj
