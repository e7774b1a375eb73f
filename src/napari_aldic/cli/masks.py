"""ROI masks given on the command line (``--roi``): read whole, or opened
window by window for a pair correlated block by block."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..engine.io import open_lazy, read_image, regular_file
from ..i18n import tr
from .console import CLIError


def read_mask(path: Path) -> np.ndarray:
    """ROI mask from a ``.npy`` array or an image file (nonzero = analysed)."""
    _check_file(path)
    if path.suffix.lower() == ".npy":
        m = _load_npy(path, None)
    else:
        m = read_image(path)
    m = np.asarray(m)
    if m.ndim == 3 and m.shape[-1] in (3, 4):  # RGB(A) mask image: any nonzero colour
        m = (m[..., :3] != 0).any(axis=-1)
    _check_2d(path, m.shape)
    return m != 0


def open_mask(path: Path):
    """ROI mask of an image pair larger than memory, without reading it: a
    memory-mapped ``.npy`` array, or a TIFF/zarr mask read window by window
    (nonzero = analysed; the engine slices it block by block). Other formats
    are read whole."""
    if not path.is_dir():
        _check_file(path)
    if path.suffix.lower() == ".npy":
        m = _load_npy(path, "r")
        if m.ndim != 2:  # e.g. an RGB mask saved as an array
            return read_mask(path)
        return m
    try:
        m = open_lazy(path)  # colour samples become grey: nonzero stays nonzero
    except ValueError:  # not TIFF or zarr (or unreadable as such): read whole, or say why
        return read_mask(path)
    _check_2d(path, m.shape)
    return m


def _check_file(path: Path) -> None:
    """A regular file is there (a named pipe or device would block the read)."""
    if not os.path.lexists(path):
        raise CLIError(tr("no such file: {path}").format(path=path))
    regular_file(path, "ROI mask")


def _load_npy(path: Path, mmap_mode):
    try:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except Exception as exc:
        raise CLIError(tr("cannot read ROI mask {path}: {exc}").format(
            path=path, exc=exc)) from None


def _check_2d(path: Path, shape) -> None:
    if len(shape) != 2:
        raise CLIError(tr("ROI mask {path} must be a 2-D image; got shape {shape}").format(
            path=path, shape=tuple(shape)))
