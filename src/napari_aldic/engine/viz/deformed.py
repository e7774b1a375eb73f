"""Lattice fields moved to the deformed configuration (NumPy/SciPy only).

A result's node values live on the node lattice of the reference image. To
draw them where the material is in the deformed frame, every lattice point
``x`` takes the value of the material point ``X`` with ``X + u(X) = x``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["to_deformed"]


def _fill_nearest(a: np.ndarray) -> np.ndarray:
    """``a`` with every non-finite entry replaced by its nearest finite one
    (all zeros when nothing is finite)."""
    from scipy import ndimage

    bad = ~np.isfinite(a)
    if not bad.any() or bad.all():
        return np.where(bad, 0.0, a)
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return a[tuple(idx)]


def to_deformed(grids: list[np.ndarray], u: np.ndarray, v: np.ndarray, step: float,
                iterations: int = 12) -> list[np.ndarray]:
    """Lattice fields moved to the deformed configuration.

    Parameters
    ----------
    grids : list of (rows, cols) arrays
        Node values on the lattice of the reference image (NaN where there
        is no trusted value).
    u, v : (rows, cols) arrays
        Displacement in pixels on the same lattice.
    step : float
        Lattice spacing in pixels.
    iterations : int
        Fixed-point iterations.

    Returns
    -------
    list of (rows, cols) arrays
        The value shown at lattice point ``x`` is that of the material point
        ``X`` with ``X + u(X) = x``, found by the fixed-point iteration
        ``X <- x - u(X)`` with bilinear interpolation; points that no trusted
        material reaches are NaN.
    """
    from scipy import ndimage

    ok = np.isfinite(u) & np.isfinite(v)
    if not ok.any():
        return [np.full_like(g, np.nan) for g in grids]
    uf, vf = _fill_nearest(u) / step, _fill_nearest(v) / step  # lattice units
    rr, cc = np.mgrid[0:u.shape[0], 0:u.shape[1]].astype(float)
    R, C = rr.copy(), cc.copy()
    for _ in range(iterations):
        du = ndimage.map_coordinates(uf, [R, C], order=1, mode="nearest")
        dv = ndimage.map_coordinates(vf, [R, C], order=1, mode="nearest")
        R, C = rr - dv, cc - du
    inside = ndimage.map_coordinates(ok.astype(float), [R, C], order=0, mode="constant",
                                     cval=0.0) > 0.5
    out = []
    for g in grids:
        val = ndimage.map_coordinates(_fill_nearest(g), [R, C], order=1, mode="nearest")
        val[~inside | ~np.isfinite(ndimage.map_coordinates(
            np.where(np.isfinite(g), 0.0, np.nan), [R, C], order=0, mode="nearest"))] = np.nan
        out.append(val)
    return out
