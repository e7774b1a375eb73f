"""The input check before a run, in words (no Qt: plain values and layers).

:func:`problems` turns the panels' current choices (:class:`Choices`) into
``(errors, warnings)``: errors keep the Run button disabled, warnings are
shown under it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._roi import labels_mask, points_xy
from ..engine import needs_tiling
from ..i18n import tr

__all__ = ["Choices", "problems", "IN_MEMORY_BYTES_PER_PIXEL"]

#: peak memory of an in-memory correlate per image pixel, measured at 10,000²
#: (about 6 GB at step 8: both images, gradients, spline coefficients, quality
#: sums; benchmarks/RESULTS.md)
IN_MEMORY_BYTES_PER_PIXEL = 60


@dataclass(frozen=True)
class Choices:
    """What the panels say, as plain values (layers are napari layer objects)."""

    image: Any  # the Image layer, or None
    shape: tuple | None  # the image data's shape
    subset: int
    step: int
    window: int  # strain window (nodes)
    start: int
    stop: int
    stride: int
    init: str
    reference: str
    seeds: Any = None  # Points layer
    brush: Any = None  # Labels layer of the refine region
    #: ``(rows, cols) -> (roi mask or None, notes)`` of the chosen ROI layers
    roi: Callable[[tuple], tuple] | None = None


def problems(c: Choices) -> tuple[list[str], list[str]]:
    """(errors, warnings) of the choices ``c``, in words."""
    img = c.image
    if img is None:
        return [tr("Choose an image stack (open a TIFF stack or a folder of "
                   "images).")], []
    stack_error = _stack_problem(img, c.shape)
    if stack_error:
        return [stack_error], []
    _, rows, cols = c.shape
    errors = _number_problems(c)
    try:
        roi = c.roi((rows, cols))[0] if c.roi is not None else None
    except Exception as exc:  # a layer that cannot be read as a region
        errors.append(tr("ROI: {exc}").format(exc=exc))
        roi = None
    else:
        errors += _roi_problems(roi, c.subset)
    if c.subset + 2 > min(rows, cols):
        errors.append(tr("Subset {subset} px does not fit in the image ({cols} x {rows} "
                         "px).").format(
                             subset=c.subset, cols=cols, rows=rows))
    if c.init == "seeds":
        errors += _seed_problems(c.seeds, img, roi, rows, cols)
    if c.brush is not None:
        try:
            labels_mask(c.brush, (rows, cols), c.start, img)
        except ValueError as exc:
            errors.append(tr("Refine region: {exc}").format(exc=exc))
        if c.reference != "accumulative":
            errors.append(tr("A painted refine region needs 'accumulative' tracking."))
    warnings = _size_warnings(rows, cols)
    if c.step > c.subset:
        warnings.append(tr("Step {step} px is larger than the subset: pixels between "
                           "subsets are not used.").format(step=c.step))
    return errors, warnings


def _size_warnings(rows: int, cols: int) -> list[str]:
    """Frames so large that an in-memory analysis may not fit: point to the
    block-by-block path of the command line."""
    if not needs_tiling((rows, cols)):
        return []
    gb = rows * cols * IN_MEMORY_BYTES_PER_PIXEL / 1e9
    return [tr("Frames of {cols} x {rows} px: an analysis in napari holds them whole and "
               "needs about {gb:.0f} GB of memory. Images larger than memory are "
               "correlated block by block from the command line: napari-aldic run REF.tif "
               "DEF.tif --step 32 -o out.npz (see the large-images guide).").format(
                   cols=cols, rows=rows, gb=gb)]


def _stack_problem(img, shape) -> str | None:
    """Why the image is not a grey stack of at least two frames (None: it is)."""
    if img.rgb:
        return (tr("'{name}' is RGB; DIC needs grey images (open the stack with "
                   "this plugin's reader, which converts RGB to grey).").format(
                       name=img.name))
    if len(shape) != 3 or shape[0] < 2:
        return (tr("'{name}' has shape {shape}; DIC needs a stack (frames, rows, "
                   "cols) with at least two frames. Open the reference and "
                   "deformed images as one stack: File > Open Files as Stack... "
                   "(choose the napari-aldic reader), or File > Open Folder... "
                   "for a folder of images.").format(name=img.name, shape=shape))
    return None


def _number_problems(c: Choices) -> list[str]:
    """Subset and strain window parity, frame range."""
    errors = []
    if c.subset % 2 == 0:
        errors.append(tr("Subset {subset} px must be odd (e.g. {odd}).").format(
                             subset=c.subset, odd=c.subset + 1))
    if c.window % 2 == 0:
        errors.append(tr("Strain window {window} must be odd.").format(window=c.window))
    if not c.start < c.stop:
        errors.append(tr("First frame ({start}) must come before the last frame "
                         "({stop}).").format(start=c.start, stop=c.stop))
    elif (c.stop - c.start) < c.stride:
        errors.append(tr("Frames {start}..{stop} every {stride} hold only the reference "
                         "frame.").format(
                             start=c.start, stop=c.stop, stride=c.stride))
    return errors


def _roi_problems(roi: np.ndarray | None, subset: int) -> list[str]:
    """An empty ROI, or one too small for the subset."""
    if roi is None:
        return []
    if not roi.any():
        return [tr("The ROI is empty: draw shapes on the material or choose other "
                   "ROI layers.")]
    ys, xs = np.nonzero(roi)
    bh, bw = ys.max() - ys.min() + 1, xs.max() - xs.min() + 1
    if subset > min(bh, bw):
        return [tr("Subset {subset} px is larger than the ROI bounding box ({bw} "
                   "x {bh} px); reduce the subset or enlarge the ROI.").format(
                       subset=subset, bw=bw, bh=bh)]
    return []


def _seed_problems(seeds, img, roi, rows: int, cols: int) -> list[str]:
    """No seed points, or seed points outside the ROI."""
    if seeds is None or len(seeds.data) == 0:
        return [tr("Initial guess 'seed points' needs a Points layer with at "
                   "least one point (choose it under 'Seeds').")]
    xy = points_xy(seeds, img)
    inside = [(0 <= x < cols and 0 <= y < rows
               and (roi is None or roi[int(round(y)), int(round(x))]))
              for x, y in xy]
    if all(inside):
        return []
    bad = [f"({x:.0f}, {y:.0f})" for (x, y), ok in zip(xy, inside) if not ok]
    return [tr("Seed point(s) {join} (x, y) lie outside the ROI; move them "
               "onto analysed material.").format(join=', '.join(bad))]
