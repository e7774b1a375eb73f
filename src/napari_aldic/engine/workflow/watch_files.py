"""Frame files of a watched folder: which files are frames, and when one is complete.

Cameras write a frame either at its final name in several chunks, or under
a temporary name (``.tmp``, ``.part``, ``~``, a leading dot) that is renamed
when the frame is done. A file is read as a frame only when

* its name matches the pattern (default: the image files ``napari-aldic
  run FOLDER`` reads, :data:`~napari_aldic.engine.io.IMAGE_SUFFIXES`) and is
  not a temporary name;
* it is not empty, and its size and modification time did not change for
  ``settle`` seconds -- or for one poll when its size equals the previous
  frame's (a camera writes every frame of a series at the same size), so the
  last chunk of a frame is picked up without waiting;
* it decodes completely (a TIFF whose strips run past the end of the file,
  a truncated PNG, ... do not) into an image of frame 0's size.

Frames are taken in natural order (``img_2`` before ``img_10``), as
``napari-aldic run FOLDER`` numbers them; a file that is not complete yet
holds the later ones back. A file that stays undecodable (junk that
matches the pattern) is skipped once a later file is complete and it has
not changed for ``stall`` seconds; an empty file is never skipped (cameras
create the file first and fill it later).
"""

from __future__ import annotations

import fnmatch
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io.stack import IMAGE_SUFFIXES, TIFF_SUFFIXES, natural_key, read_image

__all__ = ["FrameFiles", "decode_frame", "is_temporary"]

#: name endings and beginnings of files still being written by their program
TEMPORARY_ENDINGS = (".tmp", ".temp", ".part", ".partial", ".crdownload", "~", ".lock")


def is_temporary(name: str) -> bool:
    """Whether ``name`` is a temporary name (written, then renamed)."""
    low = name.lower()
    return low.startswith((".", "~")) or low.endswith(TEMPORARY_ENDINGS)


def _tiff_complete(path: Path, size: int) -> str | None:
    """Why the TIFF ``path`` of ``size`` bytes is incomplete (None: it is not):
    a page whose image data ends past the end of the file."""
    import tifffile

    with tifffile.TiffFile(path) as tf:
        for page in tf.pages:
            ends = [o + c for o, c in zip(page.dataoffsets, page.databytecounts)]
            if ends and max(ends) > size:
                return f"its image data needs {max(ends)} bytes, the file has {size}"
    return None


def decode_frame(path: Path, size: int | None = None) -> np.ndarray:
    """The image of ``path``, decoded completely; raises ValueError naming
    the file when it is not a complete single image."""
    path = Path(path)
    if size is None:
        size = path.stat().st_size
    if size == 0:
        raise ValueError(f"{path} is empty")
    if path.suffix.lower() in TIFF_SUFFIXES:
        try:
            why = _tiff_complete(path, size)
        except Exception as exc:  # not a TIFF (yet): the header is incomplete
            raise ValueError(f"cannot read image {path}: {exc}") from None
        if why:
            raise ValueError(f"{path} is incomplete: {why}")
    img = read_image(path)
    if img.ndim > 3 or (img.ndim == 3 and img.shape[-1] not in (3, 4)) or img.ndim < 2:
        raise ValueError(f"{path} is not one image (shape {img.shape})")
    return img


@dataclass
class _Seen:
    """What the scans saw of one file."""

    size: int
    mtime_ns: int
    since: float  # when (monotonic) it was first seen with this size and mtime
    scans: int = 1  # consecutive scans with this size and mtime
    failed: str | None = None  # why the last decode failed at this size and mtime


@dataclass
class FrameFiles:
    """The frame files of ``folder``, taken one by one in natural order.

    :meth:`next_frame` returns the next complete frame after those taken (its
    path and decoded image) or None; call it every poll interval.
    ``skipped`` lists ``(name, reason)`` of files left out; ``late`` the
    files that appeared (or completed) before a frame already taken.
    """

    folder: Path
    pattern: str | None = None
    settle: float = 0.25
    stall: float = 10.0
    taken: list = field(default_factory=list)  # Paths of the frames, in order
    skipped: list = field(default_factory=list)
    late: list = field(default_factory=list)
    shape: tuple | None = None  # frame 0's image shape
    _seen: dict = field(default_factory=dict)
    _last_size: int | None = None

    def __post_init__(self):
        self.folder = Path(self.folder)

    def matches(self, name: str) -> bool:
        if is_temporary(name):
            return False
        if self.pattern:
            return fnmatch.fnmatch(name.lower(), self.pattern.lower())
        return os.path.splitext(name)[1].lower() in IMAGE_SUFFIXES

    def candidates(self) -> list[os.DirEntry]:
        """The matching files after the last frame taken, in natural order
        (files sorting before it are noted in ``late`` once)."""
        try:
            entries = [e for e in os.scandir(self.folder)
                       if self.matches(e.name) and e.is_file()]
        except FileNotFoundError:
            return []
        done = {p.name for p in self.taken} | {n for n, _ in self.skipped}
        last = natural_key(self.taken[-1].name) if self.taken else None
        out = []
        for e in sorted(entries, key=lambda e: natural_key(e.name)):
            if e.name in done:
                continue
            if last is not None and natural_key(e.name) <= last:
                if e.name not in self.late:
                    self.late.append(e.name)
                continue
            out.append(e)
        return out

    def next_frame(self) -> tuple[Path, np.ndarray] | None:
        """The next frame (path, image) if it is complete now, else None."""
        now = time.monotonic()
        files = self.candidates()
        for pos, entry in enumerate(files):
            seen = self._update(entry, now)
            if seen is None:
                return None
            ok = self._complete(entry, seen, now)
            if ok is not None:
                return ok
            if not self._skip(entry, seen, files[pos + 1:], now):
                return None
        return None

    def _update(self, entry: os.DirEntry, now: float) -> _Seen | None:
        try:
            st = entry.stat()
        except OSError:  # renamed or removed meanwhile
            return None
        old = self._seen.get(entry.name)
        if old is None or (old.size, old.mtime_ns) != (st.st_size, st.st_mtime_ns):
            old = self._seen[entry.name] = _Seen(st.st_size, st.st_mtime_ns, now)
        else:
            old.scans += 1
        return old

    def _complete(self, entry: os.DirEntry, seen: _Seen, now: float):
        """(path, image) when ``entry`` is a complete frame, else None."""
        if seen.size == 0 or seen.failed is not None:
            return None
        settled = now - seen.since >= self.settle or (
            seen.scans >= 2 and seen.size == self._last_size)
        if not settled:
            return None
        path = Path(entry.path)
        try:
            img = decode_frame(path, seen.size)
            st = os.stat(path)
        except (ValueError, OSError) as exc:
            seen.failed = str(exc)
            return None
        if (st.st_size, st.st_mtime_ns) != (seen.size, seen.mtime_ns):
            return None  # written to while decoded: judge it again
        if self.shape is not None and tuple(img.shape) != self.shape:
            self.skipped.append((entry.name, f"{img.shape} is not the size of frame 0 "
                                             f"{self.shape}"))
            return None
        if self.shape is None:
            self.shape = tuple(img.shape)
        self._last_size = seen.size
        self.taken.append(path)
        self._seen.pop(entry.name, None)
        return path, img

    def _skip(self, entry: os.DirEntry, seen: _Seen, later: list, now: float) -> bool:
        """Skip ``entry`` (True) when it is undecodable, unchanged for
        ``stall`` seconds, and a later file looks complete."""
        if entry.name in {n for n, _ in self.skipped}:
            return True  # skipped just now (another size)
        if seen.failed is None or seen.size == 0 or now - seen.since < self.stall:
            return False
        for e in later:
            try:
                st = e.stat()
            except OSError:
                continue
            if st.st_size > 0 and time.time() - st.st_mtime_ns / 1e9 >= self.settle:
                self.skipped.append((entry.name, seen.failed))
                return True
        return False
