"""B-spline weights and samplers over precomputed, padded coefficients.

The coefficients (``dic.interpolation.prefilter``) are padded by :data:`PAD`
pixels on every side, so no sampler bounds-checks in its inner loop. Two
families of samplers:

* float64, one point at a time (:func:`sample_cubic`, :func:`sample_quintic`,
  run in parallel by :func:`sample_points`): the public ``sample``;
* float32 taps over a flat coefficient array (:func:`sample_cubic_f32`,
  :func:`sample_quintic_f32`): the hot loop of IC-GN, inlined into its kernels.

Reference: M. Unser, "Splines: a perfect fit for signal and image
processing", IEEE Signal Processing Magazine 16(6), 1999.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE, PARALLEL, SERIAL

__all__ = ["PAD", "cubic_weights", "quintic_weights", "quintic_basis", "sample_cubic",
           "sample_quintic", "sample_points", "spline_gradients", "sample_cubic_f32",
           "sample_quintic_f32"]

PAD = 8  # coefficient padding in pixels on every side


@nb.njit(**INLINE, fastmath=FASTMATH)
def cubic_weights(t):
    """Cubic B-spline weights of the taps at offsets -1, 0, 1, 2.

    One implementation for float64 and float32: every constant takes the
    type of ``t`` (``type(t)(...)``), so a float32 ``t`` is weighed in float32
    throughout. Under :data:`~.flags.FASTMATH` (the IC-GN kernels) the
    ``arcp`` flag compiles the divisions by 6 into multiplications by the
    rounded reciprocal.

    Parameters
    ----------
    t : float64 or float32
        Fractional position, ``0 <= t < 1``.

    Returns
    -------
    w0, w1, w2, w3 : the type of ``t``
        ``w1`` and ``w2`` from the closed forms; ``w2 = 1 - w0 - w1 - w3``, so
        the weights sum to one exactly.
    """
    real = type(t)
    one = real(1.0)
    s = one - t
    t2 = t * t
    t3 = t2 * t
    w0 = s * s * s / real(6.0)
    w3 = t3 / real(6.0)
    w1 = real(2.0) / real(3.0) - t2 + real(0.5) * t3
    w2 = one - w0 - w1 - w3
    return w0, w1, w2, w3


@nb.njit(**INLINE, fastmath=FASTMATH)
def quintic_weights(t):
    """Quintic B-spline weights of the taps at offsets -2 .. 3.

    Closed forms in powers of ``1 - t``, ``1 + t``, ``2 - t`` and ``3 - t``
    (every constant of the type of ``t``); ``w3`` is one minus the others, so
    the weights sum to one exactly.

    Parameters
    ----------
    t : float32 or float64
        Fractional position, ``0 <= t < 1``.

    Returns
    -------
    w0, w1, w2, w3, w4, w5 : the type of ``t``
    """
    real = type(t)
    one = real(1.0)
    c = real(1.0 / 120.0)
    s = one - t
    a1 = one + t
    b1 = real(2.0) - t
    b2 = real(3.0) - t
    s5 = s * s * s * s * s
    t5 = t * t * t * t * t
    w0 = s5 * c
    w1 = (b1 * b1 * b1 * b1 * b1 - real(6.0) * s5) * c
    w2 = (b2 * b2 * b2 * b2 * b2 - real(6.0) * b1 * b1 * b1 * b1 * b1
          + real(15.0) * s5) * c
    w4 = (a1 * a1 * a1 * a1 * a1 - real(6.0) * t5) * c
    w5 = t5 * c
    w3 = one - w0 - w1 - w2 - w4 - w5  # weights sum to one
    return w0, w1, w2, w3, w4, w5


@nb.njit(**INLINE, fastmath=FASTMATH)
def quintic_basis(x):
    """The centred quintic B-spline ``beta5(x)`` (float64), piece by piece.

    Parameters
    ----------
    x : float64
        Distance from the knot centre; the support is ``|x| < 3``.

    Returns
    -------
    float64
        ``sum_k (-1)^k C(6, k) (3 - k - |x|)_+^5 / 120``.
    """
    ax = abs(x)
    if ax < 1.0:
        a = 3.0 - ax
        b = 2.0 - ax
        c = 1.0 - ax
        return (a**5 - 6.0 * b**5 + 15.0 * c**5) / 120.0
    elif ax < 2.0:
        a = 3.0 - ax
        b = 2.0 - ax
        return (a**5 - 6.0 * b**5) / 120.0
    elif ax < 3.0:
        a = 3.0 - ax
        return a**5 / 120.0
    return 0.0


@nb.njit(**INLINE, fastmath=FASTMATH)
def sample_cubic(coef, x, y):
    """Cubic B-spline value at the image point ``(x, y)`` (float64).

    Parameters
    ----------
    coef : (H + 2 PAD, W + 2 PAD) float32
        Padded coefficients.
    x, y : float64
        Column and row of the point, within the padded border.

    Returns
    -------
    float64
        The separable 4 x 4 weighted sum of the coefficients around the point.
    """
    xf = np.floor(x)
    yf = np.floor(y)
    ix = int(xf) + PAD - 1
    iy = int(yf) + PAD - 1
    wx0, wx1, wx2, wx3 = cubic_weights(x - xf)
    wy0, wy1, wy2, wy3 = cubic_weights(y - yf)
    r0 = (wx0 * coef[iy, ix] + wx1 * coef[iy, ix + 1]
          + wx2 * coef[iy, ix + 2] + wx3 * coef[iy, ix + 3])
    r1 = (wx0 * coef[iy + 1, ix] + wx1 * coef[iy + 1, ix + 1]
          + wx2 * coef[iy + 1, ix + 2] + wx3 * coef[iy + 1, ix + 3])
    r2 = (wx0 * coef[iy + 2, ix] + wx1 * coef[iy + 2, ix + 1]
          + wx2 * coef[iy + 2, ix + 2] + wx3 * coef[iy + 2, ix + 3])
    r3 = (wx0 * coef[iy + 3, ix] + wx1 * coef[iy + 3, ix + 1]
          + wx2 * coef[iy + 3, ix + 2] + wx3 * coef[iy + 3, ix + 3])
    return wy0 * r0 + wy1 * r1 + wy2 * r2 + wy3 * r3


@nb.njit(**INLINE, fastmath=FASTMATH)
def sample_quintic(coef, x, y):
    """Quintic B-spline value at the image point ``(x, y)`` (float64).

    Parameters
    ----------
    coef, x, y
        As :func:`sample_cubic`.

    Returns
    -------
    float64
        The 6 x 6 sum over the taps at offsets -2 .. 3, each weighted by
        :func:`quintic_basis` of its distance along x times that along y.
    """
    xf = np.floor(x)
    yf = np.floor(y)
    tx = x - xf
    ty = y - yf
    ix = int(xf) + PAD - 2
    iy = int(yf) + PAD - 2
    acc = 0.0
    for a in range(6):
        wy = quintic_basis(ty + 2.0 - a)
        row = 0.0
        for b in range(6):
            row += quintic_basis(tx + 2.0 - b) * coef[iy + a, ix + b]
        acc += wy * row
    return acc


@nb.njit(**PARALLEL)
def sample_points(coef, order, xs, ys, out):
    """Sample the spline at many points, in parallel.

    Parameters
    ----------
    coef : (H + 2 PAD, W + 2 PAD) float32
        Padded coefficients.
    order : int
        3 (cubic) or 5 (quintic).
    xs, ys : (n,) float64
        Columns and rows of the points.
    out : (n,) float64
        Receives the values.
    """
    for k in nb.prange(xs.size):
        if order == 3:
            out[k] = sample_cubic(coef, xs[k], ys[k])
        else:
            out[k] = sample_quintic(coef, xs[k], ys[k])


# serial (issue 25): the rows in parallel were no faster (1024², 2048², 2
# cores: memory-bound) and compiled 3x longer (0.73 s against 0.21 s)
@nb.njit(**SERIAL)
def spline_gradients(c, value, deriv, gx, gy):
    """Exact spline derivatives at the integer pixel centres.

    ``f'(i) = sum_k c_k B'(i - k)``: at a knot the spline's value and
    derivative are short stencils (``value``, ``deriv``) of the coefficients,
    so each gradient is a separable value x derivative stencil. The stencil
    is summed tap by tap over a whole output row at a time (contiguous rows,
    so LLVM vectorises the sums: 5x faster at 1024² than a stencil loop per
    pixel), in float64 and in the per-pixel order of the taps, so every
    pixel's sum is the same as the per-pixel loop's, bit for bit.

    Parameters
    ----------
    c : (H + 2 PAD, W + 2 PAD) float32
        Padded coefficients.
    value, deriv : (2r + 1,) float64
        The B-spline and its derivative at the integer offsets -r .. r.
    gx, gy : (H, W) float32
        Receive d/dx (along columns) and d/dy (along rows).
    """
    h, w = gx.shape
    r = value.size // 2
    sx = np.empty(w)
    sy = np.empty(w)
    for i in range(h):
        for j in range(w):  # (loops, not slice fills: issue 25's compile time)
            sx[j] = sy[j] = 0.0
        for a in range(-r, r + 1):
            row = c[PAD + i + a]
            for b in range(-r, r + 1):
                wx = value[a + r] * deriv[b + r]
                wy = deriv[a + r] * value[b + r]
                c0 = PAD + b
                for j in range(w):
                    cv = np.float64(row[c0 + j])
                    sx[j] += wx * cv
                    sy[j] += wy * cv
        for j in range(w):
            gx[i, j] = sx[j]
            gy[i, j] = sy[j]


@nb.njit(**INLINE, fastmath=FASTMATH)
def sample_cubic_f32(c1, stride, xw, yw, out, m):
    """Cubic B-spline samples at the points ``(xw, yw)[:m]`` (all >= 0).

    Positions stay float64 (exact to 1e-12 px); the fractional parts, the
    weights (:func:`cubic_weights` in float32) and the 16-tap sum are
    float32, which halves the cost of the IC-GN hot loop.

    Parameters
    ----------
    c1 : (N,) float32
        Padded coefficients, flattened row by row.
    stride : int
        Row length of the padded coefficients.
    xw, yw : (>= m,) float64
        Columns and rows of the points; non-negative, so truncation is floor.
    out : (>= m,) float32
        Receives the values.
    m : int
        Number of points.
    """
    for q in range(m):
        x = xw[q]
        y = yw[q]
        xi = np.int64(x)  # positions are >= 0, so truncation is floor
        yi = np.int64(y)
        wx0, wx1, wx2, wx3 = cubic_weights(np.float32(x - xi))
        wy0, wy1, wy2, wy3 = cubic_weights(np.float32(y - yi))
        b = (yi + PAD - 1) * stride + xi + PAD - 1
        r0 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        b += stride
        r1 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        b += stride
        r2 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        b += stride
        r3 = wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
        out[q] = wy0 * r0 + wy1 * r1 + wy2 * r2 + wy3 * r3


@nb.njit(**INLINE, fastmath=FASTMATH)
def sample_quintic_f32(c1, stride, xw, yw, out, m):
    """Quintic B-spline samples at the points ``(xw, yw)[:m]`` (all >= 0).

    As :func:`sample_cubic_f32`, with the float32 :func:`quintic_weights`
    and a 6 x 6 tap sum accumulated row by row.

    Parameters
    ----------
    c1, stride, xw, yw, out, m
        See :func:`sample_cubic_f32`.
    """
    for q in range(m):
        x = xw[q]
        y = yw[q]
        xi = np.int64(x)
        yi = np.int64(y)
        wx0, wx1, wx2, wx3, wx4, wx5 = quintic_weights(np.float32(x - xi))
        wy0, wy1, wy2, wy3, wy4, wy5 = quintic_weights(np.float32(y - yi))
        b = (yi + PAD - 2) * stride + xi + PAD - 2
        acc = np.float32(0.0)
        for r in range(6):
            wy = wy0 if r == 0 else wy1 if r == 1 else wy2 if r == 2 else \
                wy3 if r == 3 else wy4 if r == 4 else wy5
            row = (wx0 * c1[b] + wx1 * c1[b + 1] + wx2 * c1[b + 2] + wx3 * c1[b + 3]
                   + wx4 * c1[b + 4] + wx5 * c1[b + 5])
            acc += wy * row
            b += stride
        out[q] = acc
