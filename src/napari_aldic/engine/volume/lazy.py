"""Volumes opened without reading them: sliced block by block (:mod:`.blocked`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["open_volume"]

_TIFF = (".tif", ".tiff")


def open_volume(path):
    """One volume opened for block-by-block reading: slicing it reads only the
    chunks (zarr folder), tiles or strips (TIFF, through tifffile's zarr
    store) or pages (``.npy``, memory-mapped) it touches.

    Raises ``FileNotFoundError`` for a missing path and ``ValueError`` naming
    the file when it holds no 3-D array.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if p.suffix.lower() == ".npy":
        a = np.load(p, allow_pickle=False, mmap_mode="r")
    elif p.is_dir() or p.suffix.lower() in _TIFF:
        import zarr
        if p.is_dir():
            a = zarr.open_array(str(p), mode="r")
        else:
            import tifffile
            a = zarr.open_array(tifffile.imread(p, aszarr=True), mode="r")
    else:
        raise ValueError(f"{p}: a volume read by blocks must be a zarr folder, a TIFF or .npy")
    if a.ndim != 3:
        raise ValueError(f"{p}: a volume must be a 3-D array (z, y, x); it holds shape "
                         f"{tuple(a.shape)}")
    return a
