"""Outlier detection on the node lattice (normalised median test).

A node is an outlier when its displacement departs from the median of its
trusted neighbours by more than ``threshold`` times the neighbours' median
absolute fluctuation plus ``eps`` (J. Westerweel, F. Scarano, "Universal
outlier detection for PIV data", Exp. Fluids 39, 2005). Neighbours are
mask-aware: only neighbours joined to the node by a straight segment inside
the ROI count, so the two faces of a crack never vote against each other.
"""

from __future__ import annotations

import numpy as np

from .mesh import NodeGrid

__all__ = ["lattice_neighbours", "median_test"]

_RADIUS = 2  # lattice neighbourhood: 5 x 5 nodes


def _window_count(ii: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    return ii[y1 + 1, x1 + 1] - ii[y0, x1 + 1] - ii[y1 + 1, x0] + ii[y0, x0]


def lattice_neighbours(grid: NodeGrid, roi: np.ndarray) -> np.ndarray:
    """Indices (n, 24) of the nodes in each node's 5 x 5 lattice neighbourhood
    that it can see inside the ROI (-1 = none).

    Two nodes are connected when the straight segment between them stays in
    the ROI, so neighbours across a crack or a hole are excluded.
    """
    idx = np.pad(grid.index_image(), _RADIUS, constant_values=-1)
    offsets = [(dy, dx) for dy in range(-_RADIUS, _RADIUS + 1)
               for dx in range(-_RADIUS, _RADIUS + 1) if (dy, dx) != (0, 0)]
    nb = np.empty((grid.n, len(offsets)), np.int64)
    ii = np.zeros((roi.shape[0] + 1, roi.shape[1] + 1), np.int64)
    np.cumsum(np.cumsum(~roi, axis=0, dtype=np.int64), axis=1, out=ii[1:, 1:])
    for k, (dy, dx) in enumerate(offsets):
        j = idx[grid.iy + _RADIUS + dy, grid.ix + _RADIUS + dx]
        has = np.nonzero(j >= 0)[0]
        jj = j[has]
        xa, ya, xb, yb = grid.x[has], grid.y[has], grid.x[jj], grid.y[jj]
        # a segment whose bounding box is all ROI is certainly connected
        holes = _window_count(ii, np.minimum(xa, xb), np.minimum(ya, yb),
                              np.maximum(xa, xb), np.maximum(ya, yb))
        check = np.nonzero(holes > 0)[0]
        if check.size:
            nsamp = int(2 * max(abs(dx), abs(dy)) * max(1, grid.xs[1] - grid.xs[0]
                                                        if grid.xs.size > 1 else 1)) + 2
            t = np.linspace(0.0, 1.0, nsamp)
            sx = np.rint(xa[check, None] + t * (xb - xa)[check, None]).astype(np.int64)
            sy = np.rint(ya[check, None] + t * (yb - ya)[check, None]).astype(np.int64)
            blocked = ~roi[sy, sx].all(axis=1)
            j[has[check[blocked]]] = -1
        nb[:, k] = j
    return nb


def median_test(u: np.ndarray, v: np.ndarray, trusted: np.ndarray, neighbours: np.ndarray,
                threshold: float = 3.0, eps: float = 0.1, min_neighbours: int = 3) -> np.ndarray:
    """Boolean outlier flags for ``trusted`` nodes (others return False).

    Parameters
    ----------
    u, v : (n,) displacements in pixels.
    trusted : (n,) bool, nodes that may serve as neighbours and be tested.
    neighbours : (n, k) from :func:`lattice_neighbours`.
    threshold : normalised residual above which a node is an outlier.
    eps : pixels, the noise floor of the fluctuation (avoids flagging
        everything on noise-free, perfectly smooth fields).
    """
    ok = (neighbours >= 0)
    ok[ok] = trusted[neighbours[ok]]
    count = ok.sum(axis=1)
    out = np.zeros(u.size, bool)
    test = trusted & (count >= min_neighbours)
    if not test.any():
        return out
    nbr = neighbours[test]
    m = ok[test]
    for comp in (u, v):
        vals = np.where(m, comp[np.where(m, nbr, 0)], np.nan)
        med = np.nanmedian(vals, axis=1)
        fluct = np.nanmedian(np.abs(vals - med[:, None]), axis=1)
        r = np.abs(comp[test] - med) / (fluct + eps)
        out[np.nonzero(test)[0][r > threshold]] = True
    return out
