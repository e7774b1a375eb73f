"""The ROI carried into a deformed configuration.

A sequence correlated frame by frame (incremental references, reference
updates) analyses frame r as a reference image. Its ROI must describe where
the material is *in frame r*: frame 0's mask laid on frame r puts a crack or
a notch where it was, not where it has moved, and subsets next to it then mix
material with background. Pixel ``x`` of frame r is in the carried ROI when
the material point ``X`` with ``X + u(X) = x`` is in frame 0's ROI; ``X`` is
found by the fixed-point iteration ``X <- x - u(X)`` on the measured field
(bilinear on the node lattice, untrusted nodes filled from the nearest
trusted one). Points whose material was outside frame 0's image keep the
nearest edge pixel's value, so a ROI covering the whole image stays whole.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..core.results import DICResult

__all__ = ["carry_roi"]

_ITERATIONS = 4  # X <- x - u(X): converges geometrically for strains << 1
_BAND = 256  # rows per band (memory stays small at 10k^2 and more)


def carry_roi(roi: np.ndarray, res: DICResult) -> np.ndarray:
    """Frame 0's ``roi`` (bool, image shape) carried by ``res`` (a result
    against frame 0) into ``res``'s deformed configuration; ``roi`` itself
    when it covers the whole image or ``res`` has no trusted node."""
    if roi.all() or not np.any(res.valid):
        return roi
    ug, vg = _filled(res, "u"), _filled(res, "v")
    xs, ys = res.grid_xs.astype(float), res.grid_ys.astype(float)
    rows, cols = roi.shape
    out = np.empty_like(roi)
    src = roi.astype(np.uint8)
    for r0 in range(0, rows, _BAND):
        r1 = min(rows, r0 + _BAND)
        y, x = np.mgrid[r0:r1, 0:cols].astype(float)
        X, Y = x, y
        for _ in range(_ITERATIONS):
            # lattice coordinates of the current estimate of X
            gx = np.interp(X, xs, np.arange(xs.size))
            gy = np.interp(Y, ys, np.arange(ys.size))
            X = x - ndimage.map_coordinates(ug, [gy, gx], order=1, mode="nearest")
            Y = y - ndimage.map_coordinates(vg, [gy, gx], order=1, mode="nearest")
        out[r0:r1] = ndimage.map_coordinates(src, [Y, X], order=0, mode="nearest") > 0
    return out


def _filled(res: DICResult, name: str) -> np.ndarray:
    """``res``'s field on its lattice, untrusted nodes filled from the nearest trusted."""
    g = res.to_grid(name)
    bad = ~np.isfinite(g)
    if bad.any():
        idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
        g = g[tuple(idx)]
    return g
