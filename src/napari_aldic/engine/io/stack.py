"""The one reader for images and image stacks.

The engine's ``track``, the command line and the napari reader all open their
frames here, so they accept the same files and explain problems the same way:

* :func:`read_image` -- one image file (tifffile for TIFF, scikit-image for the
  other formats of :data:`IMAGE_SUFFIXES`);
* :class:`FrameSource` / :func:`open_stack` -- the frames of a stack, read on
  demand: a (T, H, W) array, a multi-page TIFF file, a folder of images or a
  list of image files;
* :func:`image_files` and :func:`natural_key` -- the images of a folder in
  natural order (``img_2`` before ``img_10``);
* :func:`grey_frame` -- colour frames as grey values (for display).

Every error names the file: :class:`FileNotFoundError` for a missing path,
:class:`ValueError` for anything that is not a readable image or stack.
"""

from __future__ import annotations

import logging
import os
import re
import struct
import threading
import warnings
from collections.abc import Iterable
from contextlib import contextmanager
from numbers import Integral, Real
from pathlib import Path

import numpy as np

from ..core.files import regular_file
from ..core.images import as_gray_float
from . import metadata as md, tiles
from .axes import plan_frames
from .metadata import FrameInterval, PixelSize

__all__ = ["FrameSource", "open_stack", "read_image", "open_image", "image_files",
           "natural_key", "grey_frame", "frame_numbers", "IMAGE_SUFFIXES", "TIFF_SUFFIXES"]

#: file name endings read as TIFF (with tifffile; pages can be stack frames)
TIFF_SUFFIXES = (".tif", ".tiff")
#: file name endings read as images (TIFF, and scikit-image for the others)
IMAGE_SUFFIXES = TIFF_SUFFIXES + (".png", ".bmp", ".jpg", ".jpeg", ".jp2", ".pgm")


def natural_key(name) -> list:
    """Sort key putting ``img_2`` before ``img_10`` (case-insensitive).

    ``name`` is a string, or a path whose last part (the file name) is used.
    """
    if isinstance(name, os.PathLike):
        name = Path(name).name
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", str(name))]


def image_files(folder) -> list[Path]:
    """The image files (:data:`IMAGE_SUFFIXES`) of ``folder``, in natural order."""
    folder = Path(folder)
    return sorted((p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=natural_key)


def _is_zarr_dir(path: Path) -> bool:
    return path.is_dir() and tiles.is_lazy_source(path)


def _image_file(path) -> Path:
    """``path`` as a Path, checked to be an existing file or zarr/OME-Zarr image."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    if path.is_dir():
        if not _is_zarr_dir(path):
            raise ValueError(f"{path} is a folder; expected an image file (or a zarr image)")
        return path
    return regular_file(path, "image file")  # a pipe or device would block the reader


def read_image(path) -> np.ndarray:
    """Read one image file as an array, keeping its data type.

    TIFF files (:data:`TIFF_SUFFIXES`) are read with tifffile, zarr and
    OME-Zarr image folders with zarr, other files with scikit-image. A
    multi-page TIFF gives all its pages (use :class:`FrameSource` to read a
    stack frame by frame).

    Raises
    ------
    FileNotFoundError
        If there is no file at ``path``.
    ValueError
        If ``path`` is a folder or no reader understands the file; the
        message names the file and the reader's reason.
    """
    path = _image_file(path)
    if path.is_dir():  # a zarr / OME-Zarr image
        with tiles.open_lazy(path) as img:
            return img[0:img.shape[0], 0:img.shape[1]]
    try:
        with warnings.catch_warnings():  # the readers' own deprecation chatter
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", FutureWarning)
            if path.suffix.lower() in TIFF_SUFFIXES:
                import tifffile

                with _tiff_log() as damage:  # tifffile logs a damaged file, and goes on
                    img = np.asarray(tifffile.imread(path))
                if damage or img.ndim < 2 or img.size == 0:
                    raise ValueError(f"it is damaged ({damage[0] if damage else 'no image'})")
                return img
            from skimage import io as skio

            return np.asarray(skio.imread(path))
    except Exception as exc:  # any reader failure is a bad input file
        raise ValueError(f"cannot read image {path}: {_reader_error(exc)}") from None


def open_image(source):
    """One image opened for window-by-window reading (a
    :class:`~napari_aldic.engine.io.tiles.LazyImage`): TIFF/BigTIFF files, zarr
    and OME-Zarr folders and zarr arrays are read tile by tile (:mod:`.tiles`);
    other image files (PNG, BMP, ...) are read whole with :func:`read_image`;
    arrays are used as they are. Errors name the file."""
    from . import tiles

    if isinstance(source, (str, os.PathLike)) and not tiles.is_lazy_source(source):
        path = _image_file(source)
        return tiles.open_lazy(_one_frame(read_image(path), path))
    return tiles.open_lazy(source)


def grey_frame(frame) -> np.ndarray:
    """An RGB(A) frame as float32 grey values (ITU-R BT.709 luminance, no
    warning); a grey frame is returned as it is (its data type kept)."""
    arr = np.asarray(frame)
    if arr.ndim == 3 and arr.shape[-1] in (3, 4):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return as_gray_float(arr)
    return arr


def _one_frame(img: np.ndarray, path: Path) -> np.ndarray:
    """Reject a file holding several frames where one image is expected
    (grey and RGB(A) images pass)."""
    if img.ndim > 3 or (img.ndim == 3 and img.shape[-1] not in (3, 4)):
        raise ValueError(f"{path} holds {img.shape[0]} frames (shape {img.shape}); a folder "
                         "or list of image files needs one image per file (give a stack on "
                         "its own)")
    return img


def _size(shape) -> str:
    """``"96 x 128 pixels"`` (with the channels of colour images)."""
    text = f"{shape[0]} x {shape[1]} pixels"
    return text + (f" x {shape[2]} channels" if len(shape) > 2 else "")


def _reader_error(exc: Exception) -> str:
    """A reader's exception in words: an internal error of the parser (an
    index or a division on garbage) means a damaged header."""
    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    if isinstance(exc, (IndexError, KeyError, ZeroDivisionError, OverflowError,
                        struct.error, MemoryError)):
        return (f"its header or page directory is damaged, or it is not an image file "
                f"({type(exc).__name__}: {first})")
    return first


@contextmanager
def _tiff_log():
    """Collect what tifffile logs while a file is opened: a broken chain of
    page directories is only logged (and the pages after it silently lost)."""
    found: list[str] = []

    class _Keep(logging.Handler):
        def emit(self, record):
            msg = record.getMessage()
            low = msg.lower()
            if any(w in low for w in ("offset", "corrupt", "truncat", "segments",
                                      "incorrect")):
                found.append(msg.split("> ", 1)[-1])

    log = logging.getLogger("tifffile")
    handler, propagate = _Keep(logging.WARNING), log.propagate
    log.addHandler(handler)
    log.propagate = False
    try:
        yield found
    finally:
        log.removeHandler(handler)
        log.propagate = propagate


def _truncation(tf, series, size: int, n_frames: int) -> str | None:
    """``"truncated: page i of n ..."`` when the image data of a page lies
    past the end of the file (``size`` bytes), else None."""
    if series.dataoffset is not None:  # one contiguous block of every frame
        end = series.dataoffset + series.nbytes
        if end <= size:
            return None
        first = max(0, (size - series.dataoffset) * n_frames // max(series.nbytes, 1))
        return (f"truncated: page {first} of {n_frames} ends past the end of the file "
                f"({size} bytes; the frames need {end})")
    pages = tf.pages
    n = len(pages)
    first = n
    while first > 0:  # truncation cuts the last pages: look backwards
        page = pages[first - 1]
        ends = [o + c for o, c in zip(page.dataoffsets, page.databytecounts)]
        if not ends or max(ends) <= size:
            break
        first -= 1
    if first == n:
        return None
    return (f"truncated: page {first} of {n} needs bytes up to "
            f"{max(o + c for o, c in zip(pages[first].dataoffsets, pages[first].databytecounts))}"
            f" but the file ends at byte {size}; pages 0 to {first - 1} are complete")


class FrameSource:
    """The frames of a stack, read one at a time when asked for.

    ``FrameSource(stack)`` takes

    * a (T, H, W) NumPy or dask array (or any array-like with ``ndim == 3``);
    * the path of a multi-page TIFF file: the frames of its first series,
      along its one frame axis (T, or the page axis of plain multi-page files;
      :func:`~napari_aldic.engine.io.axes.plan_frames`); a hyperstack's
      channel axis needs ``channel=N``, other extra axes are refused; when
      every frame is one page, one page is read per request;
    * the path of a zarr array (T, H, W) or OME-Zarr image folder (its
      full-resolution level, axes as for TIFF);
    * the path of a folder of images (:data:`IMAGE_SUFFIXES`), in natural
      order (``img_2`` before ``img_10``);
    * a list of image file paths (or zarr images), one frame each, in the
      order given (a list holding one path is that path).

    ``len(src)`` is the number of frames (at least two), ``src[k]`` reads
    frame ``k``, ``src.frame_name(k)`` names it. Use it as a context manager,
    or call :meth:`close`, to release an open TIFF file early.

    Attributes
    ----------
    name : str or None
        The path given (None for arrays and lists of files).
    shape : tuple
        ``(frames, rows, cols)``.
    frame_shape : tuple
        Shape of one frame: ``(rows, cols)``, or ``(rows, cols, channels)``
        for colour frames.
    series_shape : tuple or None
        Shape of the TIFF series as stored in the file (None for other sources).
    axes : str or None
        Axis letters of a TIFF series or OME-Zarr image (e.g. ``"TYX"``).
    pixel_size, frame_interval : PixelSize, FrameInterval or None
        What the file's metadata records (OME, ImageJ, SEM, resolution tags,
        OME-Zarr scales; :mod:`.metadata`); see :attr:`units`.
    """

    def __init__(self, stack, channel: int | None = None):
        self.name: str | None = None
        self.series_shape: tuple | None = None
        self.axes: str | None = None
        self.channel = channel
        self.pixel_size: PixelSize | None = None
        self.frame_interval: FrameInterval | None = None
        self._plan = None
        self._files: list[Path] | None = None
        self._tiff: Path | None = None
        self._pages = False  # TIFF: one page per frame
        self._whole = None  # TIFF series read at once (frames are not single pages)
        self._arr = None
        self._handle = None
        self._lock = threading.Lock()
        if isinstance(stack, (list, tuple)) and stack and \
                all(isinstance(p, (str, os.PathLike)) for p in stack):
            if len(stack) == 1:
                stack = stack[0]
            else:
                self._use_files([_image_file(p) for p in stack])
        if isinstance(stack, (str, os.PathLike)):
            self._open_path(Path(stack))
        elif self._files is None:
            self._use_array(stack)
        if channel is not None and self._plan is None:
            raise ValueError(f"channel {channel} was chosen, but {self.name or 'the stack'} "
                             "has no channel axis")
        if len(self) < 2:
            raise ValueError(f"a sequence needs at least two frames; {self.name or 'the stack'} "
                             f"holds {len(self)}")

    # ------------------------------------------------------------ opening
    def _open_path(self, path: Path) -> None:
        self.name = str(path)
        if _is_zarr_dir(path):
            self._open_zarr(path)
        elif path.is_dir():
            files = image_files(path)
            if len(files) < 2:
                raise ValueError(f"folder {path} holds {len(files)} image(s); a sequence needs "
                                 "a reference and at least one deformed image ("
                                 f"{', '.join(s[1:] for s in IMAGE_SUFFIXES)})")
            self._use_files(files)
        elif not path.exists():
            raise FileNotFoundError(f"no image stack at {path} (no such file or folder)")
        elif not path.is_file():  # a pipe or device would block the reader
            regular_file(path, "image stack")
        elif path.suffix.lower() in TIFF_SUFFIXES:
            self._open_tiff(path)
        else:
            raise ValueError(f"{path} is a single image; a sequence needs a multi-page TIFF "
                             "stack, a folder of images or several image files")

    def _use_files(self, files: list[Path]) -> None:
        self._files = files
        self.frame_shape = tuple(_one_frame(read_image(files[0]), files[0]).shape)
        self.shape = (len(files),) + self.frame_shape[:2]
        if tiles.is_lazy_source(files[0]):  # TIFF, zarr: the first image's pixel size
            self.pixel_size = tiles.pixel_size_of(files[0])

    def _use_array(self, stack) -> None:
        if isinstance(stack, (list, tuple)) and stack and all(hasattr(f, "shape")
                                                              for f in stack):
            bad = next((k for k, f in enumerate(stack) if f.shape != stack[0].shape), None)
            if bad is not None:  # np.asarray would say "inhomogeneous shape"
                raise ValueError(f"frame {bad} is {_size(stack[bad].shape)}, but frame 0 is "
                                 f"{_size(stack[0].shape)}; every frame of a sequence must "
                                 "have the same size")
        arr = stack if hasattr(stack, "ndim") else np.asarray(stack)
        if arr.ndim != 3:
            raise ValueError(f"a stack must be 3-D (frames, rows, cols); got shape {arr.shape}")
        self._arr = arr
        self.shape = tuple(int(s) for s in arr.shape)
        self.frame_shape = self.shape[1:]

    def _open_tiff(self, path: Path) -> None:
        import tifffile

        try:
            with _tiff_log() as damage, tifffile.TiffFile(path) as tf:
                series = tf.series[0]
                shape, axes = tuple(series.shape), str(series.axes)
                n_pages = len(series.pages)
                page_shape = tuple(series.pages[0].shape) if n_pages else None
                n_image = 3 if axes.endswith("S") and shape[-1] in (3, 4) else 2
                planes = int(np.prod(shape[:-n_image]))
                cut = _truncation(tf, series, path.stat().st_size, planes)
                if damage and not cut:
                    cut = (f"damaged: {damage[0]}; only pages 0 to {len(tf.pages) - 1} can be "
                           "read")
                self.pixel_size, self.frame_interval = (md.tiff_pixel_size(tf),
                                                        md.tiff_frame_interval(tf))
        except Exception as exc:
            raise ValueError(f"cannot read TIFF stack {path}: {_reader_error(exc)}") from None
        if cut:
            raise ValueError(f"TIFF stack {path} is {cut} (an interrupted copy or "
                             "acquisition?)")
        self._use_plan(plan_frames(shape, axes, n_image, str(path), self.channel), shape,
                       n_image, str(path))
        self._tiff = path
        self.series_shape = shape
        self._pages = n_pages == planes and page_shape == self.frame_shape

    def _use_plan(self, plan, shape, n_image: int, name: str) -> None:
        if plan.n_frames < 2:
            raise ValueError(f"{name} holds a single frame (shape {shape}); a sequence needs "
                             "a reference and at least one deformed frame")
        self._plan, self.axes = plan, plan.axes
        self.frame_shape = tuple(int(n) for n in shape[-n_image:])
        self.shape = (plan.n_frames,) + self.frame_shape[:2]

    def _open_zarr(self, path: Path) -> None:
        """A zarr array (T, H, W) or the full-resolution level of an OME-Zarr image."""
        import zarr

        try:
            node = zarr.open(str(path), mode="r")
            axes = None
            if not hasattr(node, "shape"):  # a group: OME-Zarr multiscales
                ms = node.attrs.get("multiscales") or (node.attrs.get("ome") or {}).get(
                    "multiscales")
                if not ms:
                    raise ValueError("a zarr group without OME-Zarr 'multiscales' metadata")
                level0 = ms[0]["datasets"][0]
                names = [a.get("name") if isinstance(a, dict) else a
                         for a in ms[0].get("axes") or []]
                axes = "".join(str(a)[:1].upper() for a in names) or None
                self.pixel_size = md.ome_zarr_pixel_size(ms[0], level0)
                self.frame_interval = md.ome_zarr_frame_interval(ms[0], level0)
                node = node[level0["path"]]
        except Exception as exc:
            raise ValueError(f"cannot read {path} as a zarr/OME-Zarr stack: {exc}") from None
        shape = tuple(int(n) for n in node.shape)
        if axes is not None and len(axes) == len(shape):
            self._arr = node
            self._use_plan(plan_frames(shape, axes, 2, str(path), self.channel), shape, 2,
                           str(path))
        elif len(shape) == 3:
            self._use_array(node)
        else:
            raise ValueError(f"zarr array {path} has shape {shape}; a stack needs (frames, "
                             "rows, cols)")

    def _units(self):
        # a list of files is named by its first file (whose metadata is read)
        first = self.name or (str(self._files[0]) if self._files else "")
        return md.units_of(self.pixel_size, self.frame_interval,
                           Path(first).name if first else "")

    @property
    def units(self):
        """:class:`~napari_aldic.engine.Units` from the file's metadata, or None."""
        return self._units()[0]

    @property
    def units_source(self) -> dict:
        """Where :attr:`units` came from, e.g. ``{"pixel_size": "ImageJ metadata of
        s.tif", "frame_interval": ...}`` (empty without metadata)."""
        return self._units()[1]

    # ------------------------------------------------------------ reading
    def __len__(self) -> int:
        return int(self.shape[0])

    def __getitem__(self, k: int) -> np.ndarray:
        n = len(self)
        if not -n <= k < n:
            raise IndexError(f"frame {k} out of range for {n} frames")
        k = int(k) % n
        if self._files is not None:
            return self._read_file(k)
        if self._tiff is not None:
            return self._read_tiff(k)
        if self._plan is not None:
            return np.asarray(self._arr[self._plan.index(k)])
        return np.asarray(self._arr[k])

    def _read_file(self, k: int) -> np.ndarray:
        img = _one_frame(read_image(self._files[k]), self._files[k])
        if tuple(img.shape) != self.frame_shape:
            raise ValueError(f"{self._files[k]} is {_size(img.shape)}, but "
                             f"{self._files[0].name} (frame 0) is {_size(self.frame_shape)}; "
                             "every image of a sequence must have the same size")
        return img

    def _read_tiff(self, k: int) -> np.ndarray:
        import tifffile

        page = f" (page {k})" if self._pages else ""
        try:
            with self._lock, _tiff_log() as damage:  # one open file, shared by the threads
                if not self._pages:
                    if self._whole is None:
                        self._whole = tifffile.imread(self._tiff, series=0).reshape(
                            *self._plan.lead, *self.frame_shape)
                    frame = self._whole[self._plan.index(k)]
                else:
                    if self._handle is None:
                        self._handle = tifffile.TiffFile(self._tiff)
                    frame = self._handle.asarray(series=0, key=self._plan.page(k))
        except Exception as exc:
            raise ValueError(f"cannot read frame {k}{page} of {self._tiff}: "
                             f"{_reader_error(exc)}") from None
        if damage:  # tifffile only logs it, and fills the lost strips with zeros
            self._whole = None
            raise ValueError(f"cannot read frame {k}{page} of {self._tiff}: it is damaged "
                             f"({damage[0]})")
        return frame

    @property
    def in_memory(self) -> bool:
        """True for an array (its pickle holds every frame); False for files
        (its pickle is the path: workers read their frames themselves)."""
        return self._arr is not None

    def frame_name(self, k: int) -> str:
        """A readable name of frame ``k``: its file, ``STACK.tif[k]`` or ``frame k``."""
        if self._files is not None:
            return str(self._files[k])
        if self._tiff is not None:
            return f"{self._tiff}[{k}]"
        return f"frame {k}"

    # ------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Release the open TIFF file (it is opened again when needed)."""
        with self._lock:
            if self._handle is not None:
                self._handle.close()
                self._handle = None

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            if self._handle is not None:
                self._handle.close()
        except Exception:
            pass

    def __getstate__(self) -> dict:  # for worker processes: no file handle, no lock
        state = dict(self.__dict__)
        state.update(_handle=None, _lock=None, _whole=None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()


def open_stack(stack) -> FrameSource:
    """A :class:`FrameSource` for an array, a TIFF stack path, an image folder
    or a list of image files (a FrameSource is returned as it is)."""
    return stack if isinstance(stack, FrameSource) else FrameSource(stack)


def frame_numbers(frames, n: int) -> list[int]:
    """The frame numbers to analyse in a stack of ``n`` frames (None: all).

    Raises
    ------
    TypeError
        ``frames`` is not a list of whole numbers.
    ValueError
        Fewer than two frames, not starting at 0, not increasing, or past the
        last frame.
    """
    if frames is None:
        return list(range(n))
    if isinstance(frames, (str, bytes, dict)) or not isinstance(frames, Iterable):
        raise TypeError(f"frames={frames!r} must be a list of frame numbers starting with 0, "
                        f"not {type(frames).__name__}")
    idx = []
    for k in frames:
        whole = isinstance(k, Integral) or (isinstance(k, Real) and float(k).is_integer())
        if isinstance(k, (bool, np.bool_)) or not whole:
            raise TypeError(f"frame {k!r} in frames is not a whole number")
        idx.append(int(k))
    if len(idx) < 2:
        raise ValueError(f"frames={idx} must hold frame 0 and at least one more frame to "
                         "track")
    if idx[0] != 0 or any(b <= a for a, b in zip(idx, idx[1:])) or idx[-1] >= n:
        raise ValueError(f"frames must start at 0, increase and stay below {n} (the stack "
                         f"has {n} frames); got {idx}")
    return idx
