"""One reader for image stacks: arrays, multi-page TIFF files and image folders.

The engine's ``track``, the command line and the napari reader all open their
frames through :class:`FrameSource`, so they accept the same files.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

__all__ = ["FrameSource", "open_stack", "natural_key", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".bmp", ".jpg", ".jpeg")


def natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


class FrameSource:
    """Read-on-demand access to the frames of a stack.

    Accepts a (T, H, W) NumPy or dask array, a multi-page TIFF path (one page
    read per request with ``tifffile``) or a folder of
    BMP/PNG/TIF/JPG images sorted naturally (``img_2`` before ``img_10``).
    """

    def __init__(self, stack):
        self.name = None
        self._files = None
        self._tiff = None
        if isinstance(stack, (str, os.PathLike)):
            path = Path(stack)
            self.name = str(path)
            if path.is_dir():
                files = sorted((p for p in path.iterdir()
                                if p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: natural_key(p.name))
                if len(files) < 2:
                    raise ValueError(f"folder {path} holds {len(files)} image(s); a sequence "
                                     "needs at least two (BMP, PNG, TIF or JPG)")
                self._files = files
                first = self._read_file(files[0])
                self.shape = (len(files),) + first.shape[:2]
                self._arr = None
            elif path.exists():
                import tifffile

                with tifffile.TiffFile(path) as tf:
                    shape = tuple(tf.series[0].shape)
                if len(shape) == 2:
                    raise ValueError(f"{path} holds a single image; a sequence needs a stack")
                if len(shape) != 3:
                    raise ValueError(f"{path}: expected a (frames, rows, cols) stack, got "
                                     f"shape {shape}")
                self._tiff = path  # pages are read one at a time in __getitem__
                self._arr = None
                self.shape = shape
            else:
                raise FileNotFoundError(f"no image stack at {path}")
        else:
            arr = stack
            if not hasattr(arr, "ndim"):
                arr = np.asarray(arr)
            if arr.ndim != 3:
                raise ValueError(f"a stack must be 3-D (frames, rows, cols); got shape {arr.shape}")
            self._arr = arr
            self.shape = tuple(arr.shape)
        if self.shape[0] < 2:
            raise ValueError("a sequence needs at least two frames")

    @staticmethod
    def _read_file(p: Path) -> np.ndarray:
        if p.suffix.lower() in (".tif", ".tiff"):
            import tifffile

            return tifffile.imread(p)
        from skimage import io

        return io.imread(p)

    def __len__(self) -> int:
        return int(self.shape[0])

    def frame_name(self, k: int) -> str:
        """A readable name of frame ``k`` (file name, or stack path and page)."""
        if self._files is not None:
            return str(self._files[k])
        if self._tiff is not None:
            return f"{self._tiff}[page {k}]"
        return f"frame {k}"

    def __getitem__(self, k: int) -> np.ndarray:
        if not -len(self) <= k < len(self):
            raise IndexError(f"frame {k} out of range for {len(self)} frames")
        if self._files is not None:
            return self._read_file(self._files[k])
        if self._tiff is not None:
            import tifffile

            with tifffile.TiffFile(self._tiff) as tf:
                return tf.asarray(series=0, key=k % len(self))
        return np.asarray(self._arr[k])


def open_stack(stack) -> FrameSource:
    """A :class:`FrameSource` for an array, a TIFF stack path or an image folder."""
    return stack if isinstance(stack, FrameSource) else FrameSource(stack)


