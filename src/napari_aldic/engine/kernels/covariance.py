"""The interpolated-noise factor of subset matches (``dic.quality``).

:func:`mean_noise_factor` -- the variance that is left of unit white noise
after B-spline interpolation at a match's sub-pixel position (linear
interpolation in a tabulated curve, as ``np.interp``), averaged over a grid
of offsets across the subset when the displacement gradient sweeps the
subset across pixels. (The per-node matrices and covariances are batched
NumPy: ``dic.covariance``.)
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .flags import FASTMATH, INLINE, SERIAL

__all__ = ["mean_noise_factor"]


@nb.njit(**INLINE)
def _interp(x, t, rho):
    """``np.interp(x, t, rho)`` on a sorted table (NaN for NaN)."""
    n = t.size
    if not x == x:
        return np.nan
    if x <= t[0]:
        return rho[0]
    if x >= t[n - 1]:
        return rho[n - 1]
    # the table is evenly spaced: guess the interval, then settle it
    j = min(max(int((x - t[0]) / (t[n - 1] - t[0]) * (n - 1)), 0), n - 2)
    while j > 0 and x < t[j]:
        j -= 1
    while j < n - 2 and x >= t[j + 1]:
        j += 1
    if x == t[j]:
        return rho[j]
    slope = (rho[j + 1] - rho[j]) / (t[j + 1] - t[j])
    return slope * (x - t[j]) + rho[j]


# serial (issue 25): as fast as with threads (measured), compiles ~2x faster
@nb.njit(**SERIAL, fastmath=FASTMATH)
def mean_noise_factor(u, v, grad, half, offsets, t, rho):
    """Mean over a grid of subset offsets of the interpolated-noise factor.

    Parameters
    ----------
    u, v : (N,) float64
        Displacements (px).
    grad : (N, 4) float64
        Displacement gradient ``(du/dx, du/dy, dv/dx, dv/dy)`` (finite).
    half : (N,) float64
        Half-width of the offset grid per node (px).
    offsets : (K,) float64
        Offsets in units of ``half``; the grid is ``offsets x offsets``.
    t, rho : (T,) float64
        The 1-D factor ``rho(t)`` tabulated at fractional offsets ``t``.

    Returns
    -------
    (N,) float64
        ``mean_ij rho(frac(u_ij)) rho(frac(v_ij))``, ``u_ij = u + u_x o_i +
        u_y o_j`` (``o = offsets * half``), the same for ``v``.
    """
    n, k = u.size, offsets.size
    out = np.empty(n)
    for i in nb.prange(n):
        acc = 0.0
        for a in range(k):
            oa = offsets[a] * half[i]
            for b in range(k):
                ob = offsets[b] * half[i]
                ua = u[i] + grad[i, 0] * oa + grad[i, 1] * ob
                va = v[i] + grad[i, 2] * oa + grad[i, 3] * ob
                acc += _interp(ua % 1.0, t, rho) * _interp(va % 1.0, t, rho)
        out[i] = acc / (k * k)
    return out
