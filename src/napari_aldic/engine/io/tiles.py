"""Images read lazily, tile by tile: tiled/strip TIFF and BigTIFF, zarr, OME-Zarr.

An SEM mosaic of 40,000 x 40,000 pixels does not fit in memory as the float
arrays DIC needs. :func:`open_lazy` opens it without reading its pixels;
``img[r0:r1, c0:c1]`` then reads only the TIFF tiles (or strips, or zarr
chunks) that the window touches:

* TIFF/BigTIFF through tifffile's ``aszarr`` store (tiles and strips are its
  chunks); an uncompressed image stored in one piece is read row band by row
  band from the file instead, so a window never costs the whole image;
* zarr arrays (a folder, or a ``zarr.Array``) and OME-Zarr images (the first
  dataset of the ``multiscales`` metadata: full resolution);
* NumPy arrays, kept as they are (for tests and small images).

The pixel size is read from the file's metadata (:func:`pixel_size_of`): OME-XML,
ImageJ, FEI and Zeiss SEM tags, TIFF resolution tags, OME-Zarr scales. Every
error names the file. :func:`napari_aldic.engine.io.open_image` (``io.stack``) is
the entry point that also accepts the other image formats.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np

from ..core.files import regular_file
from .metadata import PixelSize, ome_zarr_pixel_size, tiff_pixel_size

__all__ = ["LazyImage", "PixelSize", "open_lazy", "pixel_size_of", "is_lazy_source"]

_TIFF = (".tif", ".tiff", ".btf", ".tf8")


class LazyImage:
    """A 2-D image whose pixels are read on demand, window by window.

    ``img[r0:r1, c0:c1]`` returns a NumPy array of the window (the file's data
    type; colour images as grey float32). ``shape``, ``dtype``, ``name``,
    ``pixel_size`` (:class:`PixelSize` or None), ``chunks`` (the file's tile
    shape) describe it; ``bytes_read`` counts the window bytes returned.
    """

    def __init__(self, reader, shape, dtype, name: str, pixel_size: PixelSize | None,
                 chunks=None, closer=None):
        self._reader = reader
        self.shape = (int(shape[0]), int(shape[1]))
        self.dtype = np.dtype(dtype)
        self.name = name
        self.pixel_size = pixel_size
        self.chunks = tuple(chunks) if chunks is not None else self.shape
        self._closer = closer
        self.bytes_read = 0
        self._lock = threading.Lock()

    ndim = 2

    @property
    def nbytes(self) -> int:
        return self.shape[0] * self.shape[1] * self.dtype.itemsize

    def __getitem__(self, key) -> np.ndarray:
        rows, cols = _window(key, self.shape)
        try:
            out = self._reader(rows, cols)
        except Exception as exc:  # a damaged tile, a truncated file...
            raise ValueError(f"cannot read rows {rows.start}-{rows.stop}, columns "
                             f"{cols.start}-{cols.stop} of {self.name}: {exc}") from exc
        out = _grey(np.asarray(out), self.name)
        with self._lock:
            self.bytes_read += out.nbytes
        return out

    def close(self) -> None:
        if self._closer is not None:
            self._closer()
            self._closer = None

    def __enter__(self) -> LazyImage:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"LazyImage({self.name}, shape={self.shape}, dtype={self.dtype})"


def _window(key, shape) -> tuple[slice, slice]:
    """``key`` as two plain slices (steps of 1) inside ``shape``."""
    if not isinstance(key, tuple) or len(key) != 2:
        raise IndexError("index a LazyImage with two slices: img[r0:r1, c0:c1]")
    out = []
    for k, n in zip(key, shape):
        if not isinstance(k, slice):
            raise IndexError("index a LazyImage with two slices: img[r0:r1, c0:c1]")
        start, stop, step = k.indices(n)
        if step != 1:
            raise IndexError("LazyImage windows take a step of 1")
        out.append(slice(start, max(start, stop)))
    return out[0], out[1]


def _grey(arr: np.ndarray, name: str) -> np.ndarray:
    """A window as 2-D grey values (colour samples averaged by luminance)."""
    if arr.ndim == 3 and arr.shape[-1] in (3, 4):
        return arr[..., :3].astype(np.float32) @ np.array([0.2126, 0.7152, 0.0722],
                                                          np.float32)
    if arr.ndim != 2:
        raise ValueError(f"{name} is not a 2-D grey or colour image (window shape "
                         f"{arr.shape})")
    return arr


def is_lazy_source(source) -> bool:
    """Whether :func:`open_lazy` reads ``source`` without loading it all:
    TIFF files, zarr/OME-Zarr folders and zarr arrays."""
    if _is_zarr_array(source):
        return True
    if isinstance(source, (str, Path)):
        p = Path(source)
        return p.suffix.lower() in _TIFF or (p.is_dir() and _zarr_meta(p) is not None)
    return False


def open_lazy(source) -> LazyImage:
    """Open ``source`` for reading window by window.

    ``source`` is a TIFF/BigTIFF file (tiled, strips or one piece), a zarr
    array or OME-Zarr image folder, a ``zarr.Array`` or a NumPy array.

    Raises
    ------
    FileNotFoundError
        If the path does not exist.
    ValueError
        If it is not a 2-D image of one of these kinds; the message names it.
    """
    if isinstance(source, LazyImage):
        return source
    if isinstance(source, np.ndarray):
        return _from_array(source, "array", None)
    if _is_zarr_array(source):
        return _from_array(source, f"zarr array {getattr(source, 'path', '')}".strip(), None)
    path = Path(source).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    if path.is_dir():
        return _open_zarr(path)
    regular_file(path, "image file")  # a pipe or device would block the reader
    if path.suffix.lower() in _TIFF:
        return _open_tiff(path)
    raise ValueError(f"{path}: not a TIFF file or zarr folder; these are the formats read "
                     "tile by tile (open other images with read_image)")


def _is_zarr_array(obj) -> bool:
    return type(obj).__module__.startswith("zarr") and hasattr(obj, "shape") and \
        hasattr(obj, "chunks")


def _squeezed_shape(shape, name: str) -> tuple[int, int, bool]:
    """(rows, cols, colour) of an array shape whose other axes have length 1."""
    colour = len(shape) >= 3 and shape[-1] in (3, 4)
    plane = shape[-3:-1] if colour else shape[-2:]
    rest = shape[:-3] if colour else shape[:-2]
    if len(plane) != 2 or any(n != 1 for n in rest):
        raise ValueError(f"{name} has shape {tuple(shape)}; a single 2-D image (rows, cols) "
                         "is needed here (open a stack with open_stack)")
    return int(plane[0]), int(plane[1]), colour


def _from_array(arr, name: str, pixel_size, closer=None) -> LazyImage:
    rows, cols, colour = _squeezed_shape(tuple(arr.shape), name)
    lead = (0,) * (len(arr.shape) - (3 if colour else 2))

    def read(r: slice, c: slice):
        return np.asarray(arr[lead + (r, c)])

    chunks = getattr(arr, "chunks", None)
    chunks = tuple(chunks[len(lead):len(lead) + 2]) if chunks is not None else None
    return LazyImage(read, (rows, cols), np.float32 if colour else arr.dtype, name,
                     pixel_size, chunks, closer)


# ------------------------------------------------------------------ TIFF
def _open_tiff(path: Path) -> LazyImage:
    import tifffile

    try:
        tf = tifffile.TiffFile(path)
    except Exception as exc:
        raise ValueError(f"cannot read {path} as a TIFF file: {exc}") from None
    try:
        if not tf.series:
            raise ValueError("no image in the file")
        series = tf.series[0]
        ps = tiff_pixel_size(tf)
        contiguous = _contiguous_reader(tf, series)
        if contiguous is not None:
            rows, cols = series.shape[-2:]
            return LazyImage(contiguous, (rows, cols), series.dtype, str(path), ps,
                             None, tf.close)
        import zarr  # only here: ~0.2 s of every run's start-up otherwise

        store = tf.aszarr(series=0, level=0)
        arr = zarr.open_array(store=store, mode="r")
        return _from_array(arr, str(path), ps, closer=lambda: (store.close(), tf.close()))
    except Exception as exc:
        tf.close()
        raise ValueError(f"cannot read {path} tile by tile: {exc}") from None


def _contiguous_reader(tf, series):
    """A row-band reader for an uncompressed 2-D image stored in one piece
    (its only chunk would be the whole image); None for any other layout."""
    shape = tuple(series.shape)
    if len(shape) != 2 or len(series.pages) != 1:
        return None
    page = series.pages[0]
    offset = getattr(series, "dataoffset", None)
    # tiles are chunks already; compressed data cannot be read by offset
    if offset is None or page.is_tiled or page.compression != 1:
        return None
    rows, cols = shape
    dtype = np.dtype(series.dtype).newbyteorder(tf.byteorder)
    fh = tf.filehandle
    lock = threading.Lock()

    def read(r: slice, c: slice) -> np.ndarray:
        n = (r.stop - r.start) * cols
        with lock:
            fh.seek(offset + r.start * cols * dtype.itemsize)
            buf = fh.read(n * dtype.itemsize)
        band = np.frombuffer(buf, dtype, n).reshape(-1, cols)
        return np.ascontiguousarray(band[:, c], dtype=dtype.newbyteorder("="))

    return read


# ------------------------------------------------------------------ zarr
def _zarr_meta(path: Path) -> dict | None:
    """The attributes of a zarr folder (v2 ``.zattrs``/``.zarray``, v3
    ``zarr.json``), or None when it is not one."""
    for name in ("zarr.json", ".zattrs", ".zarray", ".zgroup"):
        f = path / name
        if f.is_file():
            try:
                meta = json.loads(f.read_text())
            except (OSError, ValueError):
                return {}
            return meta.get("attributes", meta) if name == "zarr.json" else meta
    return None


def _open_zarr(path: Path) -> LazyImage:
    import zarr

    meta = _zarr_meta(path)
    if meta is None:
        raise ValueError(f"{path} is a folder but not a zarr array or OME-Zarr image; give "
                         "an image file (use open_stack for a folder of images)")
    try:
        node = zarr.open(str(path), mode="r")
        ps = None
        if not _is_zarr_array(node):
            ms = node.attrs.get("multiscales") or (node.attrs.get("ome") or {}).get(
                "multiscales")
            if not ms:
                raise ValueError("a zarr group without OME-Zarr 'multiscales' metadata")
            level0 = ms[0]["datasets"][0]
            ps = ome_zarr_pixel_size(ms[0], level0)
            node = node[level0["path"]]
        return _from_array(node, str(path), ps)
    except Exception as exc:
        raise ValueError(f"cannot read {path} as a zarr/OME-Zarr image: {exc}") from None


def pixel_size_of(source) -> PixelSize | None:
    """The pixel size recorded in an image file's metadata, or None."""
    try:
        with open_lazy(source) as img:
            return img.pixel_size
    except (OSError, ValueError):
        return None
