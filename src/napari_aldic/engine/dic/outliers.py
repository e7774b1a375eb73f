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

from ..kernels.lattice import median_flags
from .mesh import NodeGrid
from .subsets import integral_image, rect_sums
from .threads import in_threads

__all__ = ["lattice_neighbours", "median_test", "median_test_at", "MedianTest"]

_RADIUS = 2  # lattice neighbourhood: 5 x 5 nodes


def lattice_neighbours(grid: NodeGrid, roi: np.ndarray, radius: int = _RADIUS) -> np.ndarray:
    """Indices (n, k) of each node's neighbours that it can see inside the ROI
    (-1 = none): the (2r+1)^2 lattice neighbourhood (r = ``radius``), or for
    grids with extra (quadtree) nodes every node within ``r + 0.9`` lattice
    steps (at most 4 (r+1)^2 of them).

    Two nodes are connected when the straight segment between them stays in
    the ROI, so neighbours across a crack or a hole are excluded.
    """
    step = int(grid.xs[1] - grid.xs[0]) if grid.xs.size > 1 else 1
    if np.any(grid.ix < 0):
        from scipy.spatial import cKDTree

        pts = np.column_stack([grid.x, grid.y]).astype(float)
        k = min(4 * (radius + 1) ** 2 + 1, grid.n)
        d, j = cKDTree(pts).query(pts, k=k, distance_upper_bound=(radius + 0.9) * step)
        j = np.where(np.isfinite(d), j, -1)[:, 1:]  # drop the node itself
        nb_ = np.where(j < grid.n, j, -1).astype(np.int64)
    else:
        idx = np.pad(grid.index_image(), radius, constant_values=-1)
        offsets = [(dy, dx) for dy in range(-radius, radius + 1)
                   for dx in range(-radius, radius + 1) if (dy, dx) != (0, 0)]
        nb_ = np.empty((grid.n, len(offsets)), np.int64)
        for k, (dy, dx) in enumerate(offsets):
            nb_[:, k] = idx[grid.iy + radius + dy, grid.ix + radius + dx]
    if roi.all():  # no hole anywhere: every neighbour is visible
        return nb_
    ii = integral_image((~roi).view(np.uint8))
    nsamp = int(2 * (radius + 1) * step) + 2
    t = np.linspace(0.0, 1.0, nsamp)
    for k in range(nb_.shape[1]):
        j = nb_[:, k]
        has = np.nonzero(j >= 0)[0]
        jj = j[has]
        xa, ya, xb, yb = grid.x[has], grid.y[has], grid.x[jj], grid.y[jj]
        # a segment whose bounding box is all ROI is certainly connected
        holes = rect_sums(ii, np.minimum(xa, xb), np.minimum(ya, yb),
                              np.maximum(xa, xb), np.maximum(ya, yb))
        check = np.nonzero(holes > 0)[0]
        if check.size:
            sx = np.rint(xa[check, None] + t * (xb - xa)[check, None]).astype(np.int64)
            sy = np.rint(ya[check, None] + t * (yb - ya)[check, None]).astype(np.int64)
            blocked = ~roi[sy, sx].all(axis=1)
            nb_[has[check[blocked]], k] = -1
    return nb_


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
    min_neighbours : nodes with fewer trusted neighbours are not tested.
    """
    out = np.zeros(u.size, bool)
    in_threads(median_flags, u.size, np.ascontiguousarray(u, np.float64),
               np.ascontiguousarray(v, np.float64), trusted, neighbours, float(threshold),
               float(eps), int(min_neighbours), out, grain=256)
    return out


def median_test_at(nodes: np.ndarray, u: np.ndarray, v: np.ndarray, trusted: np.ndarray,
                   neighbours: np.ndarray, **kw) -> np.ndarray:
    """:func:`median_test`'s flags at ``nodes`` only (sorted unique indices):
    the test of a sub-problem holding those nodes and the neighbours they
    read, the same flags as a test of every node at those nodes (``kw``: as
    :func:`median_test`)."""
    rows = neighbours[nodes]
    rest = np.setdiff1d(rows[rows >= 0], nodes)
    order = np.concatenate([nodes, rest])
    local = np.full(u.size + 1, -1, np.int64)  # index -1 (no neighbour) stays -1
    local[order] = np.arange(order.size)
    sub = np.full((order.size, neighbours.shape[1]), -1, np.int64)
    sub[:nodes.size] = local[rows]
    # the neighbours read have no rows of their own: never tested here
    return median_test(u[order], v[order], trusted[order], sub, **kw)[:nodes.size]


class MedianTest:
    """:func:`median_test` of inputs that change a little between calls.

    The test of a node reads only its own and its neighbours' trust and
    ``u, v``, so after a small change (at most :attr:`share` of the nodes)
    only the changed nodes (trusted or untrusted since, trusted and moved)
    and the nodes that read them are tested again (:func:`median_test_at`),
    usually a few dozen after a repair wave; the flags equal a full test."""

    share = 0.05

    def __init__(self):
        self._last = None  # (trusted, (n, 2) u v, flags) of the last call

    def flags(self, u: np.ndarray, v: np.ndarray, trusted: np.ndarray,
              neighbours: np.ndarray) -> np.ndarray:
        """The outlier flags (a new array) of ``u, v`` at ``trusted`` nodes."""
        uv = np.column_stack([u, v])
        if self._last is not None:
            was, uv_was, flags = self._last
            changed = (was != trusted) | (trusted & np.any(uv_was != uv, axis=1))
            if not changed.any():
                return flags.copy()
            if np.count_nonzero(changed) <= self.share * changed.size:
                # neighbour tables need not be symmetric (ROI visibility, the
                # quadtree's nearest nodes): who reads a changed node, looked up
                reads = np.append(changed, False)[neighbours].any(axis=1)
                redo = np.nonzero(changed | reads)[0]
                flags = flags.copy()
                flags[redo] = median_test_at(redo, u, v, trusted, neighbours)
                self._last = (trusted.copy(), uv, flags)
                return flags.copy()
        flags = median_test(u, v, trusted, neighbours)
        self._last = (trusted.copy(), uv, flags)
        return flags.copy()
