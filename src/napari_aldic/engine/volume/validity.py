"""Final validity reasons of DVC nodes: solver codes, then the tests of 2-D.

ZNCC below ``zncc_min`` (``LOW_CORRELATION``), predicted uncertainty above
``max_uncertainty`` (``UNCERTAIN``) and the normalised median test over the
3 x 3 x 3 lattice neighbours (``OUTLIER``; Westerweel & Scarano 2005,
threshold 2 with a 0.1 voxel noise floor).
"""

from __future__ import annotations

import numpy as np

from ..core.reasons import Reason

__all__ = ["final_reasons", "median_outliers"]

_MEDIAN_THRESHOLD = 2.0
_MEDIAN_EPS = 0.1  # voxels


def _neighbours(grid) -> np.ndarray:
    """``(n, 26)`` lattice neighbours of every node (-1 where none)."""
    pad = np.pad(grid.index_volume(), 1, constant_values=-1)
    z, y, x = grid.iz + 1, grid.iy + 1, grid.ix + 1
    return np.stack([pad[z + a, y + b, x + c] for a in (-1, 0, 1) for b in (-1, 0, 1)
                     for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], 1)


def median_outliers(grid, p: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Nodes (among ``ok``) failing the normalised median test in u, v or w.

    Each ``ok`` neighbour predicts the node's displacement with its own
    affine warp (``u_j + G_j (x_i - x_j)``), so uniform strain and rotation,
    which change ``u`` by a gradient times the spacing per node, are not
    mistaken for outliers at the faces of the lattice.
    """
    nb = _neighbours(grid)
    have = nb >= 0
    have[have] = ok[nb[have]]
    j = np.maximum(nb, 0)
    xyz = grid.xyz.astype(float)
    d = xyz[:, None, :] - xyz[j]  # (n, 26, 3)
    enough = have.sum(1) >= 3
    bad = np.zeros(grid.n, bool)
    for a in range(3):
        pred = p[j, 4 * a] + (p[j, 4 * a + 1:4 * a + 4] * d).sum(-1)
        pred = np.where(have & enough[:, None], pred, np.nan)
        pred[~enough] = 0.0
        med = np.nanmedian(pred, axis=1)
        res = np.nanmedian(np.abs(pred - med[:, None]), axis=1)
        r = np.abs(p[:, 4 * a] - med) / (res + _MEDIAN_EPS)
        bad |= enough & (r > _MEDIAN_THRESHOLD)
    return bad & ok


def final_reasons(st, p=None) -> np.ndarray:
    """Reason per node from the local state (and the AL-DVC warps ``p``)."""
    pr = st.params
    reason = st.status.astype(np.int8).copy()
    ok = reason == Reason.OK
    low = ok & ~(st.zncc >= pr.zncc_min)
    reason[low] = Reason.LOW_CORRELATION
    ok &= ~low
    if pr.max_uncertainty is not None:
        unc = ok & (np.nan_to_num(st.ustd, nan=0.0).max(1) > pr.max_uncertainty)
        reason[unc] = Reason.UNCERTAIN
        ok &= ~unc
    q = st.p if p is None else p
    out = median_outliers(st.grid, q, ok)
    reason[out] = Reason.OUTLIER
    return reason
