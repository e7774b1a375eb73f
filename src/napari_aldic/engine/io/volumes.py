"""Volumes in: 3-D TIFFs, a 4-D TIFF of volumes, a folder of 3-D TIFFs, ``.npy``.

:func:`read_volumes` reads them whole; :func:`open_volume` opens one volume
without reading it, for DVC by blocks (``correlate_volume(..., block=N)``).

A 3-D TIFF read as a volume is one (z, y, x) array; without that intent the
rest of the package reads the same file as a stack of 2-D frames.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .stack import TIFF_SUFFIXES, natural_key

__all__ = ["read_volumes", "open_volume"]


def _read(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".npy":
        return np.load(path, allow_pickle=False, mmap_mode="r")
    if path.suffix.lower() not in TIFF_SUFFIXES:
        raise ValueError(f"{path}: a volume must be a TIFF or .npy file")
    import tifffile
    return np.asarray(tifffile.imread(path))


def read_volumes(inputs) -> list[np.ndarray]:
    """The volumes of ``inputs`` (paths): each 3-D file is a volume, a 4-D
    file (t, z, y, x) and a folder of 3-D files are sequences of volumes.

    Raises ``ValueError`` naming the file whose array is not 3-D or 4-D,
    ``FileNotFoundError`` for a missing path.
    """
    out: list[np.ndarray] = []
    for p in map(Path, inputs):
        if not p.exists():
            raise FileNotFoundError(f"no such file or folder: {p}")
        if p.is_dir():
            files = sorted((f for f in p.iterdir() if f.suffix.lower() in (*TIFF_SUFFIXES, ".npy")),
                           key=lambda f: natural_key(f.name))
            out.extend(read_volumes(files))
            continue
        a = _read(p)
        if a.ndim == 3:
            out.append(a)
        elif a.ndim == 4:
            out.extend(a[k] for k in range(a.shape[0]))
        else:
            raise ValueError(f"{p}: a volume must be a 3-D array (z, y, x) or a 4-D sequence "
                             f"(t, z, y, x); this file holds shape {a.shape}")
    return out


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
    elif p.is_dir() or p.suffix.lower() in TIFF_SUFFIXES:
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
