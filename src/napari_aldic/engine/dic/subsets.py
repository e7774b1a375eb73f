"""Mask-aware subset splitting.

A subset that overlaps the edge of the ROI (a hole, a crack, the outline) is
intersected with the ROI and split into 4-connected components
(``scipy.ndimage.label``); only the component that contains the subset centre
is correlated, so a node never mixes pixels from the two faces of a crack.
4-connectivity is used so that a crack one pixel wide along a diagonal still
separates its faces. A node whose component keeps less than ``min_component``
of the full subset area is flagged unreliable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..core.reasons import Reason

__all__ = ["SubsetMasks", "split_subsets", "check_masks", "integral_image", "rect_sums"]


@dataclass
class SubsetMasks:
    """Per-node subset pixel sets.

    Attributes
    ----------
    slot : (n,) int32
        Index into ``masks`` for nodes whose subset is cut by the ROI edge,
        -1 for nodes whose full square subset lies in the ROI.
    masks : (m, S, S) uint8
        Component masks (1 = pixel used) of the cut nodes.
    fraction : (n,) float64
        Fraction of the full subset area that each node correlates.
    reason : (n,) int8
        ``Reason.OK`` or ``Reason.SMALL_COMPONENT``.
    """

    slot: np.ndarray
    masks: np.ndarray
    fraction: np.ndarray
    reason: np.ndarray


def integral_image(mask: np.ndarray) -> np.ndarray:
    """Summed-area table of a boolean/uint8 image (F. C. Crow, SIGGRAPH 1984).

    Two cumulative sums in int64, exact: NumPy's rather than a compiled
    kernel (~3 ms on a megapixel mask, ~0.5 s less compiling on a first run:
    issue 25).

    Parameters
    ----------
    mask : (H, W) uint8 or bool
        The image.

    Returns
    -------
    (H + 1, W + 1) int64
        ``ii[i, j]`` is the sum of ``mask[:i, :j]``.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2 or mask.dtype.kind not in "bu":
        raise ValueError(f"integral_image wants a 2-D boolean or unsigned image, "
                         f"not {mask.ndim}-D {mask.dtype}")
    h, w = mask.shape
    ii = np.zeros((h + 1, w + 1), np.int64)
    np.cumsum(mask, axis=1, dtype=np.int64, out=ii[1:, 1:])
    np.cumsum(ii[1:, 1:], axis=0, out=ii[1:, 1:])
    return ii


def rect_sums(ii: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    """Sums over the pixel rectangles [x0, x1] x [y0, y1] (inclusive) from an
    integral image of :func:`integral_image`."""
    return ii[y1 + 1, x1 + 1] - ii[y0, x1 + 1] - ii[y1 + 1, x0] + ii[y0, x0]


def split_subsets(roi: np.ndarray, grid, subset: int,
                  min_component: float = 0.5) -> SubsetMasks:
    """Compute the pixel set each node correlates (see module docstring).

    Raises
    ------
    ValueError
        If no node keeps enough of its subset inside the ROI, i.e. the subset
        is larger than the ROI regions.
    """
    h = subset // 2
    area = subset * subset
    if roi.all():  # nothing cut: skip the integral image
        outside = np.zeros(grid.n, np.int64)
    else:
        outside = rect_sums(integral_image((~roi).view(np.uint8)), grid.x - h, grid.y - h,
                            grid.x + h, grid.y + h)
    slot = np.full(grid.n, -1, np.int32)
    fraction = np.ones(grid.n)
    reason = np.zeros(grid.n, np.int8)
    cut = np.nonzero(outside > 0)[0]
    masks = np.zeros((cut.size, subset, subset), np.uint8)
    for m, k in enumerate(cut):
        win = roi[grid.y[k] - h:grid.y[k] + h + 1, grid.x[k] - h:grid.x[k] + h + 1]
        lab, _ = ndimage.label(win)  # default structure: 4-connectivity
        comp = lab == lab[h, h]
        masks[m] = comp
        slot[k] = m
        fraction[k] = comp.sum() / area
    reason[fraction < min_component] = Reason.SMALL_COMPONENT
    if not np.any(reason == Reason.OK):
        raise ValueError(
            f"subset={subset} px is too large for the ROI: every node keeps less than "
            f"{min_component:.0%} of its subset inside the ROI. Use a smaller subset or "
            "a larger ROI"
        )
    return SubsetMasks(slot, masks, fraction, reason)


def check_masks(slot, masks, half: int, n: int) -> None:
    """Refuse ``slot, masks`` (:class:`SubsetMasks`) that do not fit ``n``
    nodes with subsets of half-width ``half``.

    The kernels index ``masks[slot[k], a + half, b + half]`` without bounds
    checks (they run in the hot loop): masks built for another subset size
    (``split_subsets`` takes the full width, the solvers the half-width)
    would read memory outside the array and give results that change from
    run to run.
    """
    side = 2 * int(half) + 1
    if masks.ndim != 3 or masks.shape[1:] != (side, side):
        raise ValueError(
            f"component masks of shape {masks.shape[1:]} do not fit subsets of half-width "
            f"{half} ({side} x {side} px): build them with split_subsets(..., subset={side})")
    if slot.shape != (n,):
        raise ValueError(f"slot has shape {slot.shape}, expected one entry per node ({n})")
    if slot.max(initial=-1) >= masks.shape[0] or slot.min(initial=-1) < -1:
        raise ValueError(f"slot refers to masks outside 0..{masks.shape[0] - 1}")
