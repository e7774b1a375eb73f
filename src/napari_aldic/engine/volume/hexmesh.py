"""Trilinear hexahedral (hex8) elements on the DVC node lattice.

Elements are the lattice cells whose eight corners are all nodes (VTK hex
order). :class:`HexOperators` holds, for 2 x 2 x 2 Gauss points per
element, the sparse gradient operator ``G`` (nodal values -> x, y, z
derivatives at every Gauss point) and the interpolation ``N`` (nodal
values -> Gauss-point values), both scipy.sparse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from .grid import VolumeGrid

__all__ = ["hex_elements", "HexOperators", "hex_operators", "nodal_gradient"]

# corner offsets (x, y, z) in VTK_HEXAHEDRON order
_CORNERS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0),
                     (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)])
_GAUSS = 0.5 + np.array([-1, 1]) / (2 * np.sqrt(3.0))  # on the unit cell


def hex_elements(grid: VolumeGrid) -> np.ndarray:
    """``(E, 8)`` node indices of the lattice cells with all corners present."""
    idx = grid.index_volume()
    nz, ny, nx = idx.shape
    if min(nz, ny, nx) < 2:
        return np.zeros((0, 8), np.int64)
    corners = [idx[c[2]:nz - 1 + c[2], c[1]:ny - 1 + c[1], c[0]:nx - 1 + c[0]].ravel()
               for c in _CORNERS]
    el = np.stack(corners, 1)
    return el[(el >= 0).all(1)]


@dataclass
class HexOperators:
    elements: np.ndarray
    G: sparse.csr_matrix  # (3 * 8E, n): d/dx, d/dy, d/dz blocks at every Gauss point
    N: sparse.csr_matrix  # (8E, n)


def _shape(x, y, z):
    """Values and (x, y, z) derivatives of the 8 trilinear shape functions at
    a point of the unit cell."""
    cx, cy, cz = _CORNERS.T
    fx = np.where(cx, x, 1 - x)
    fy = np.where(cy, y, 1 - y)
    fz = np.where(cz, z, 1 - z)
    sx, sy, sz = 2 * cx - 1, 2 * cy - 1, 2 * cz - 1
    return fx * fy * fz, np.stack([sx * fy * fz, fx * sy * fz, fx * fy * sz])


def hex_operators(grid: VolumeGrid, step: float) -> HexOperators:
    """Gradient and interpolation operators of the lattice's hexahedra."""
    el = hex_elements(grid)
    E, n = len(el), grid.n
    vals, ders = [], []
    for gz in _GAUSS:
        for gy in _GAUSS:
            for gx in _GAUSS:
                v, d = _shape(gx, gy, gz)
                vals.append(v)
                ders.append(d / step)
    vals = np.array(vals)  # (8 gp, 8 nodes)
    ders = np.array(ders)  # (8 gp, 3, 8 nodes)
    rows_n = (np.arange(E)[:, None, None] * 8 + np.arange(8)[None, :, None])  # (E, gp, 1)
    cols = el[:, None, :]  # (E, 1, 8)
    N = sparse.csr_matrix((np.broadcast_to(vals, (E, 8, 8)).ravel(),
                           (np.broadcast_to(rows_n, (E, 8, 8)).ravel(),
                            np.broadcast_to(cols, (E, 8, 8)).ravel())), shape=(8 * E, n))
    blocks = []
    for a in range(3):
        blocks.append(sparse.csr_matrix((np.broadcast_to(ders[:, a, :], (E, 8, 8)).ravel(),
                                         (np.broadcast_to(rows_n, (E, 8, 8)).ravel(),
                                          np.broadcast_to(cols, (E, 8, 8)).ravel())),
                                        shape=(8 * E, n)))
    return HexOperators(el, sparse.vstack(blocks).tocsr(), N)


def nodal_gradient(ops: HexOperators, values: np.ndarray) -> np.ndarray:
    """``(n, 3)`` gradient of nodal ``values`` (n,): the Gauss-point gradients
    of the elements averaged onto their nodes (weights: the shape functions)."""
    g = (ops.G @ values).reshape(3, -1)
    cnt = np.asarray(ops.N.sum(0)).ravel()
    return np.stack([(ops.N.T @ g[a]) / np.maximum(cnt, 1e-12) for a in range(3)], 1)
