"""Uniform node grids inside a region of interest."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.reasons import DICError

__all__ = ["NodeGrid", "make_grid", "EDGE"]

#: pixels kept between node subsets and the image border. B-spline values
#: within one pixel of the border depend on the (unknown) image beyond it,
#: which biases sub-pixel matches there by up to ~0.01 px; the margin keeps
#: undeformed subsets clear of that band.
EDGE = 1


@dataclass
class NodeGrid:
    """Nodes of a uniform lattice kept inside the ROI.

    Attributes
    ----------
    x, y : (n,) int64
        Node pixel coordinates (x = column, y = row).
    ix, iy : (n,) int64
        Lattice column/row index of every node.
    xs, ys : 1-D int64
        Lattice coordinates along x and y (the full lattice, kept or not).
    """

    x: np.ndarray
    y: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    xs: np.ndarray
    ys: np.ndarray

    @property
    def n(self) -> int:
        return int(self.x.size)

    @property
    def shape(self) -> tuple[int, int]:
        """Lattice shape ``(len(ys), len(xs))``."""
        return (self.ys.size, self.xs.size)

    def index_image(self) -> np.ndarray:
        """Lattice-shaped array of node indices, -1 where no node is kept
        (extra nodes off the lattice, with ``ix = -1``, are not included)."""
        idx = np.full(self.shape, -1, np.int64)
        on = self.ix >= 0
        idx[self.iy[on], self.ix[on]] = np.nonzero(on)[0]
        return idx

    def with_extra(self, x, y) -> NodeGrid:
        """This grid plus extra nodes at integer (x, y) off the lattice (ix = iy = -1)."""
        x = np.asarray(x, np.int64)
        y = np.asarray(y, np.int64)
        m = -np.ones(x.size, np.int64)
        return NodeGrid(np.concatenate([self.x, x]), np.concatenate([self.y, y]),
                        np.concatenate([self.ix, m]), np.concatenate([self.iy, m]),
                        self.xs, self.ys)


def make_grid(roi: np.ndarray, subset: int, step: int) -> NodeGrid:
    """Nodes at ``h + EDGE + k*step`` (h = subset // 2) whose centre lies in ``roi``.

    The lattice stops ``h + EDGE`` pixels from the image border, so every
    node's full subset lies inside the image with :data:`EDGE` pixels to spare.

    Raises
    ------
    ValueError
        If the subset does not fit in the image or no node falls in the ROI.
    """
    h = subset // 2
    rows, cols = roi.shape
    if subset + 2 * EDGE > rows or subset + 2 * EDGE > cols:
        raise DICError(
            "subset_too_large", f"subset={subset} px is larger than the image ({rows} x "
            f"{cols} px); choose a smaller subset", subset=subset, shape=(rows, cols))
    m = h + EDGE
    xs = np.arange(m, cols - m, step, dtype=np.int64)
    ys = np.arange(m, rows - m, step, dtype=np.int64)
    keep = roi[np.ix_(ys, xs)]
    iy, ix = np.nonzero(keep)
    if iy.size == 0:
        raise ValueError(
            f"no node of the step={step} px lattice falls inside the ROI (nodes stay "
            f"{h + EDGE} px from the image border for subset={subset}); enlarge the ROI or "
            "reduce subset/step"
        )
    return NodeGrid(xs[ix], ys[iy], ix.astype(np.int64), iy.astype(np.int64), xs, ys)
