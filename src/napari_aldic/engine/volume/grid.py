"""The node lattice of a volume: nodes every ``step`` voxels, whole subset inside."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["VolumeGrid", "make_volume_grid"]

EDGE = 1  # voxels between a node's full subset and the volume border (as in 2-D)


@dataclass
class VolumeGrid:
    """Nodes of a uniform 3-D lattice whose centre lies in the ROI.

    ``xs, ys, zs`` are the lattice coordinates along x, y, z (voxels);
    ``ix, iy, iz`` the lattice indices of each kept node.
    """

    xs: np.ndarray
    ys: np.ndarray
    zs: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    iz: np.ndarray

    @property
    def n(self) -> int:
        return int(self.ix.size)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.zs.size, self.ys.size, self.xs.size)

    @property
    def xyz(self) -> np.ndarray:
        """``(n, 3)`` int64 node voxels (x, y, z)."""
        return np.stack([self.xs[self.ix], self.ys[self.iy], self.zs[self.iz]], 1)

    def index_volume(self) -> np.ndarray:
        """Lattice-shaped (z, y, x) array of node indices, -1 where no node."""
        out = np.full(self.shape, -1, np.int64)
        out[self.iz, self.iy, self.ix] = np.arange(self.n)
        return out


def make_volume_grid(shape, subset: int, step: int, roi=None) -> VolumeGrid:
    """Nodes at ``h + EDGE + k * step`` along each axis (``h = subset // 2``).

    Raises ``ValueError`` when the subset does not fit in the volume or no
    node lies in the ROI.
    """
    h = subset // 2
    m = h + EDGE
    if any(subset + 2 * EDGE > s for s in shape):
        raise ValueError(f"subset={subset} voxels is larger than the volume "
                         f"{' x '.join(map(str, shape))} (z, y, x); choose a smaller subset")
    zs, ys, xs = (np.arange(m, s - m, step, dtype=np.int64) for s in shape)
    iz, iy, ix = np.meshgrid(np.arange(zs.size), np.arange(ys.size), np.arange(xs.size),
                             indexing="ij")
    iz, iy, ix = iz.ravel(), iy.ravel(), ix.ravel()
    if roi is not None:
        keep = np.asarray(roi, bool)[zs[iz], ys[iy], xs[ix]]
        iz, iy, ix = iz[keep], iy[keep], ix[keep]
        if not keep.any():
            raise ValueError("no node lies inside the ROI: it is empty or smaller than the "
                             "node spacing")
    return VolumeGrid(xs, ys, zs, ix, iy, iz)
