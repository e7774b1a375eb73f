"""Errors and atomic writes shared by every file the engine writes."""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path


# =================================================================== errors
class ExportError(OSError):
    """A result file could not be written; the message names the file and
    what to do. Nothing is left under the target name."""

    def __init__(self, message: str, path=None, code: int | None = None):
        super().__init__(message)
        self.message = message
        self.filename = None if path is None else str(path)
        if code is not None:
            self.errno = code

    def __str__(self) -> str:
        return self.message


class EncoderNotFoundError(RuntimeError):
    """The video encoder (ffmpeg through ``imageio-ffmpeg``) is not available."""


def explain_os_error(exc: OSError, path: Path) -> ExportError:
    code = getattr(exc, "errno", None)
    if code in (errno.ENOSPC, getattr(errno, "EDQUOT", -1)):
        msg = (f"cannot write {path}: no space left on the device (disk full or quota "
               "exceeded). Free some space or choose a folder on another disk, then export "
               "again; no partial file was left behind")
    elif code in (errno.EACCES, errno.EPERM):
        msg = (f"cannot write {path}: permission denied. Choose a folder you can write to "
               "(or change the folder's permissions)")
    elif code == errno.EROFS:
        msg = f"cannot write {path}: the file system is read-only. Choose another folder"
    elif code == errno.ENOENT:
        msg = (f"cannot write {path}: the folder {path.parent} does not exist (any more). "
               "Create it first or choose another output path")
    elif code == errno.ENAMETOOLONG:
        msg = f"cannot write {path}: the file name is too long. Choose a shorter name"
    else:
        msg = f"cannot write {path}: {exc.strerror or exc}"
    return ExportError(msg, path, code)


def target_path(path, suffixes: Sequence[str]) -> Path:
    """The output path (``suffixes[0]`` appended when the name has none of
    them), after checking that its folder exists and is writable."""
    path = Path(os.fspath(path)).expanduser()
    if path.suffix.lower() not in suffixes:
        path = path.with_name(path.name + suffixes[0])
    check_folder(path)
    return path


def check_folder(path: Path) -> None:
    folder = path.parent
    if not folder.exists():
        raise ExportError(f"cannot write {path}: the folder {folder} does not exist. Create it "
                          "first or choose another output path", path, errno.ENOENT)
    if not folder.is_dir():
        raise ExportError(f"cannot write {path}: {folder} is a file, not a folder. Choose "
                          "another output path", path, errno.ENOTDIR)
    if path.is_dir():
        raise ExportError(f"cannot write {path}: a folder of that name exists. Give a file "
                          "name", path, errno.EISDIR)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ExportError(f"cannot write {path}: permission denied on the folder {folder}. "
                          "Choose a folder you can write to", path, errno.EACCES)


def _remove(p: Path) -> None:
    try:
        os.unlink(p)
    except FileNotFoundError:
        pass
    except OSError:  # pragma: no cover - nothing more we can do
        pass


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_write(path):
    """Context manager yielding a temporary path beside ``path``.

    Write the file there; when the block ends without an exception it is
    renamed to ``path`` (replacing an older file atomically). On any error
    the temporary file is removed, an older ``path`` is left untouched, and
    ``OSError`` becomes :class:`ExportError` with an explanation.
    """
    path = Path(os.fspath(path)).expanduser()
    check_folder(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    except OSError as exc:
        raise explain_os_error(exc, path) from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600
        os.replace(tmp, path)
    except ExportError:
        _remove(tmp)
        raise
    except OSError as exc:
        _remove(tmp)
        raise explain_os_error(exc, path) from exc
    except BaseException:
        _remove(tmp)
        raise


def numbered_path(path: Path, k: int) -> Path:
    """``path`` with ``_frame#####`` before the suffix: one file per frame."""
    return path.with_name(f"{path.stem}_frame{k:05d}{path.suffix}")
