"""Image input: conversion to float32 greyscale and validation."""

from __future__ import annotations

import os
import warnings

import numpy as np

from .reasons import DICError

__all__ = ["as_gray_float", "validate_pair", "validate_roi"]


def as_gray_float(image, name: str = "image") -> np.ndarray:
    """Return ``image`` as a C-contiguous 2-D float32 array.

    Integer (8/16-bit or other) and float inputs keep their grey values (no
    rescaling: DIC is insensitive to affine intensity changes). RGB(A) images
    are converted to grey with luminance weights and a warning.

    Raises
    ------
    ValueError
        If the array is not 2-D (or 3-D with 3/4 channels), is empty, holds
        NaN/inf values, or (wider floats) values outside the float32 range.
    """
    if isinstance(image, (str, bytes, os.PathLike)):
        raise TypeError(f"{name} is a file name ({os.fsdecode(image)!r}), not an image "
                        "array; read it first (napari_aldic.engine.io.read_image)")
    arr = np.asarray(image)
    if arr.dtype == bool or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise ValueError(
            f"{name} has dtype {arr.dtype}; expected an integer or float greyscale image"
        )
    if np.issubdtype(arr.dtype, np.floating) and arr.size:
        nbad = int(np.count_nonzero(~np.isfinite(arr)))
        if nbad:
            raise ValueError(
                f"{name} contains {nbad} NaN or infinite pixel(s); replace them (e.g. "
                "interpolate) and exclude the area from the ROI"
            )
        if arr.dtype.itemsize > 4:
            _check_float32_range(arr, name)
    if arr.ndim == 3 and arr.shape[-1] in (3, 4):
        warnings.warn(
            f"{name} looks like an RGB{'A' if arr.shape[-1] == 4 else ''} image "
            f"(shape {arr.shape}); converting to greyscale (ITU-R BT.709 luminance).",
            UserWarning,
            stacklevel=3,
        )
        rgb = arr[..., :3].astype(np.float32)
        arr = rgb @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    if arr.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D greyscale image (rows, cols); got shape {arr.shape}. "
            "For a stack, pass frames one at a time or use track()."
        )
    if arr.size == 0 or min(arr.shape) < 2:
        raise ValueError(f"{name} is empty or degenerate (shape {arr.shape})")
    return np.ascontiguousarray(arr, dtype=np.float32)


def _check_float32_range(arr: np.ndarray, name: str) -> None:
    """Refuse finite wide-float values that float32 (what the engine
    correlates) would turn into infinity or flush towards zero."""
    f32 = np.finfo(np.float32)
    top = max(abs(float(arr.max())), abs(float(arr.min())))
    if top > float(f32.max):
        raise ValueError(
            f"{name} holds values up to {top:.3g}, beyond the float32 range "
            f"(|value| <= {float(f32.max):.3g}) the correlation computes in; rescale the "
            "image (DIC does not depend on a linear grey-level scaling)"
        )
    if 0 < top < float(f32.tiny):
        raise ValueError(
            f"{name} holds only values below {float(f32.tiny):.3g} in magnitude (largest "
            f"{top:.3g}), under the float32 range the correlation computes in; rescale the "
            "image (DIC does not depend on a linear grey-level scaling)"
        )


def validate_pair(reference, deformed) -> tuple[np.ndarray, np.ndarray]:
    """Convert and check a reference/deformed pair (same shape, textured)."""
    f = as_gray_float(reference, "reference image")
    g = as_gray_float(deformed, "deformed image")
    if f.shape != g.shape:
        raise ValueError(
            f"reference image shape {f.shape} differs from deformed image shape "
            f"{g.shape}; crop or pad them to the same size"
        )
    for img, name in ((f, "reference image"), (g, "deformed image")):
        lo, hi = float(img.min()), float(img.max())
        if hi - lo <= 1e-6 * max(1.0, abs(hi)):
            raise ValueError(
                f"{name} is blank (every pixel equals {lo:g}); DIC needs a speckle "
                "pattern with grey-level contrast"
            )
    return f, g


def validate_roi(roi, shape: tuple[int, int]) -> np.ndarray:
    """Return the ROI as a boolean mask of ``shape`` (``None`` = whole image)."""
    if roi is None:
        return np.ones(shape, dtype=bool)
    if isinstance(roi, (str, bytes, os.PathLike)):
        raise TypeError(f"the ROI is a file name ({os.fsdecode(roi)!r}), not a mask array; "
                        "read it first (napari_aldic.engine.io.read_image, nonzero = analysed)")
    m = np.asarray(roi)
    if m.shape != tuple(shape):
        raise DICError("shape_mismatch",
                       f"ROI mask shape {m.shape} differs from image shape {tuple(shape)}",
                       what="roi", shape=m.shape, image_shape=tuple(shape))
    if m.dtype != bool:
        if not (np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)):
            raise ValueError(f"ROI mask has dtype {m.dtype}; expected a boolean mask")
        m = m != 0
    if not m.any():
        raise ValueError("ROI mask is empty (no True pixel); draw a region to analyse")
    return np.ascontiguousarray(m)
