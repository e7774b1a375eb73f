"""Errors and atomic writes shared by every file the engine writes; the lock,
temporary-file cleanup and content digests of run folders."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import secrets
import shutil
import socket
import stat
import sys
import tempfile
import time
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np


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


class RunFolderError(ValueError):
    """A run folder cannot be used for this run: it holds another analysis,
    an input changed since its frames were computed, its manifest is from an
    older version, or another process is writing it (``owner`` then describes
    that process: pid, host, start time, command). ``folder`` is the folder."""

    def __init__(self, message: str, folder=None, owner: dict | None = None):
        super().__init__(message)
        self.folder = None if folder is None else str(folder)
        self.owner = owner


def explain_os_error(exc: OSError, path: Path) -> ExportError:
    code = getattr(exc, "errno", None)
    if code in (errno.ENOSPC, getattr(errno, "EDQUOT", -1)):
        msg = (f"cannot write {path}: no space left on the device (disk full or quota "
               "exceeded). Free some space or choose a folder on another disk, then try "
               "again; no partial file was left behind")
    elif code in (errno.EACCES, errno.EPERM):
        msg = (f"cannot write {path}: permission denied. Choose a folder you can write to "
               "(or change the folder's permissions)")
    elif code == errno.EROFS:
        msg = f"cannot write {path}: the file system is read-only. Choose another folder"
    elif code == errno.ENOENT:
        msg = (f"cannot write {path}: the folder {path.parent} does not exist (any more). "
               "Create it first or choose another output path")
    elif code in (errno.ENOTDIR, errno.EEXIST) and file_above(path) is not None:
        msg = (f"cannot write {path}: {file_above(path)} is a file, not a folder. Choose "
               "another output path")
    elif code == errno.ENAMETOOLONG:
        msg = f"cannot write {path}: the file name is too long. Choose a shorter name"
    else:
        msg = f"cannot write {path}: {exc.strerror or exc}"
    return ExportError(msg, path, code)


@contextmanager
def explained(path):
    """Turn an ``OSError`` of the ``with`` block (a full disk, a permission)
    into :class:`ExportError` naming ``path`` and the cause."""
    try:
        yield
    except ExportError:
        raise
    except OSError as exc:
        raise explain_os_error(exc, Path(path)) from None


def file_above(path: Path) -> Path | None:
    """The part of ``path`` (itself or a folder above it) that is a file."""
    for p in (path, *path.parents):
        if os.path.lexists(p):
            return None if p.is_dir() else p
    return None


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
    above = file_above(folder)
    if above is not None:
        raise ExportError(f"cannot write {path}: {above} is a file, not a folder. Choose "
                          "another output path", path, errno.ENOTDIR)
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


def _disk_full(folder: Path) -> bool:
    """Whether the file system of ``folder`` has (almost) no space left."""
    try:
        return shutil.disk_usage(folder).free < (1 << 20)
    except OSError:
        return False


class AtomicFiles:
    """Several files written as one: each under a temporary name beside it
    (:meth:`write`), all renamed into place when the ``with`` block ends
    without an error, none otherwise (a file series and the index naming it,
    e.g. ``.vtu`` frames and their ``.pvd``, appear together or not at all).

    Errors become :class:`ExportError` with an explanation; an error of a
    library while the disk is full (a compressor's "error while flushing")
    is reported as the full disk it is.
    """

    def __init__(self):
        self._written: list[tuple[Path, Path]] = []

    def __enter__(self) -> AtomicFiles:
        return self

    @contextmanager
    def write(self, path):
        """Yield a temporary path for ``path``; write the file there."""
        path = Path(os.fspath(path)).expanduser()
        check_folder(path)
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part",
                                       dir=path.parent)
        except OSError as exc:
            raise explain_os_error(exc, path) from None
        made = os.fstat(fd)
        os.close(fd)
        tmp = Path(tmp)
        try:
            yield tmp
            now = os.lstat(tmp)
            if not stat.S_ISREG(now.st_mode) or (now.st_ino, now.st_dev) != (made.st_ino,
                                                                              made.st_dev):
                # swapped for another file or a link while we wrote: never rename it
                raise ExportError(f"cannot write {path}: its temporary file {tmp.name} was "
                                  "replaced by another program during the write", path)
        except ExportError:
            _remove(tmp)
            raise
        except OSError as exc:
            _remove(tmp)
            raise explain_os_error(exc, path) from exc
        except Exception as exc:
            _remove(tmp)
            if _disk_full(path.parent):
                raise explain_os_error(OSError(errno.ENOSPC, "disk full"), path) from exc
            raise
        except BaseException:
            _remove(tmp)
            raise
        self._written.append((tmp, path))

    def __exit__(self, kind, exc, tb) -> bool:
        todo = list(self._written)
        self._written.clear()
        if kind is not None:
            for tmp, _ in todo:
                _remove(tmp)
            return False
        mode = 0o666 & ~_umask()  # mkstemp creates 0600
        for n, (tmp, path) in enumerate(todo):
            try:
                os.chmod(tmp, mode)
                os.replace(tmp, path)
            except OSError as err:
                for left, _ in todo[n:]:
                    _remove(left)
                raise explain_os_error(err, path) from err
        return False


@contextmanager
def atomic_write(path):
    """Context manager yielding a temporary path beside ``path``.

    Write the file there; when the block ends without an exception it is
    renamed to ``path`` (replacing an older file atomically). On any error
    the temporary file is removed, an older ``path`` is left untouched, and
    ``OSError`` becomes :class:`ExportError` with an explanation (see
    :class:`AtomicFiles`, of which this is the one-file case).
    """
    with AtomicFiles() as files, files.write(path) as tmp:
        yield tmp


def numbered_path(path: Path, k: int) -> Path:
    """``path`` with ``_frame#####`` before the suffix: one file per frame."""
    return path.with_name(f"{path.stem}_frame{k:05d}{path.suffix}")


# =================================================================== reading
class InputFileError(ValueError):
    """An input file cannot be read: it is not a regular file (a folder, a
    named pipe, a device, a socket), is too large, or its text is not what
    was expected. The message names the file; ``filename`` is its path;
    ``kind`` says what failed ("encoding", "json", "nesting", "value", else
    None) and ``problem`` the words after "it" (for a caller that names the
    file its own way)."""

    def __init__(self, message: str, path=None, kind: str | None = None, problem: str = ""):
        super().__init__(message)
        self.filename = None if path is None else str(path)
        self.kind, self.problem = kind, problem


_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def _not_regular(st: os.stat_result) -> str | None:
    if stat.S_ISREG(st.st_mode):
        return None
    return next((words for test, words in _KINDS if test(st.st_mode)), "not a regular file")


def regular_file(path, what: str = "file") -> Path:
    """``path`` (``~`` expanded) after checking that it names a regular file
    (a link to one is fine): a named pipe, device or socket would block or
    stream forever when opened, so it is refused before anything opens it.

    Raises ``FileNotFoundError`` when nothing is there and
    :class:`InputFileError` (a ``ValueError``) naming the file otherwise.
    """
    p = Path(os.fspath(path)).expanduser()
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise FileNotFoundError(errno.ENOENT, f"no {what} at {p}", str(p)) from None
    except OSError as exc:
        raise InputFileError(f"cannot read the {what} {p}: {exc.strerror or exc}", p) from None
    kind = _not_regular(st)
    if kind is not None:
        raise InputFileError(f"cannot read the {what} {p}: it is {kind}, not a regular file",
                             p)
    return p


def open_regular(path, what: str = "file"):
    """``path`` opened for binary reading, refused (as :func:`regular_file`)
    unless it is a regular file. The check is made on the opened file
    (``O_NONBLOCK``, so that opening a pipe cannot block), not on the name."""
    p = regular_file(path, what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(p, flags | getattr(os, "O_BINARY", 0))
    except OSError as exc:
        raise InputFileError(f"cannot read the {what} {p}: {exc.strerror or exc}", p) from None
    kind = _not_regular(os.fstat(fd))
    if kind is not None:  # swapped between the check and the open
        os.close(fd)
        raise InputFileError(f"cannot read the {what} {p}: it is {kind}, not a regular file",
                             p)
    if hasattr(os, "set_blocking"):
        os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


#: largest JSON or text file read whole (settings, manifests, projects), bytes
MAX_TEXT_BYTES = 256 << 20


def read_text_file(path, what: str = "file", encoding: str = "utf-8",
                   limit: int = MAX_TEXT_BYTES) -> str:
    """The text of a regular file (see :func:`open_regular`) of at most
    ``limit`` bytes; :class:`InputFileError` naming the file otherwise."""
    with open_regular(path, what) as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > limit:
            raise InputFileError(f"cannot read the {what} {path}: it holds {size:,} bytes, "
                                 f"more than the {limit >> 20} MB such a file can have", path)
        raw = fh.read(limit + 1)
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        problem = f"is not {encoding.upper()} text ({exc.reason} at byte {exc.start})"
        raise InputFileError(f"cannot read the {what} {path}: it {problem}", path, "encoding",
                             problem) from None


def parse_json(text: str, source) -> object:
    """``json.loads(text)`` with every way it fails (bad syntax, nesting too
    deep for the parser, integers too long to convert) a ``ValueError``
    naming ``source`` (a file, or where the text was found)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        kind, problem = "json", f"is not valid JSON ({exc})"
    except RecursionError:
        kind, problem = "nesting", "nests lists or objects too deeply (a damaged or hostile file)"
    except ValueError as exc:  # e.g. an integer of thousands of digits
        kind, problem = "value", f"holds a value that cannot be read ({exc})"
    raise InputFileError(f"cannot read {source}: it {problem}", source, kind, problem)


def read_json_file(path, what: str = "file", limit: int = MAX_TEXT_BYTES) -> object:
    """The JSON document of a regular file; errors name the file."""
    return parse_json(read_text_file(path, what, limit=limit), f"the {what} {path}")


def file_sha256(path, what: str = "file") -> str:
    """SHA-256 (hex) of a regular file's bytes, read in blocks."""
    h = hashlib.sha256()
    with open_regular(path, what) as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def available_memory() -> int | None:
    """Memory a new allocation can have now, in bytes (None when unknown):
    Linux's ``MemAvailable`` (free memory plus what caches would give back),
    else the free pages, else the physical memory. Sizes declared by a file
    are checked against it before anything is decompressed."""
    try:
        with open("/proc/meminfo", "rb") as fh:
            for line in fh:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    for pages in ("SC_AVPHYS_PAGES", "SC_PHYS_PAGES"):
        try:
            return os.sysconf("SC_PAGE_SIZE") * os.sysconf(pages)
        except (ValueError, OSError, AttributeError):
            continue
    return None


# =================================================================== digests
def array_digest(arr) -> str:
    """SHA-256 (hex) of an array's dtype, shape and values: equal digests mean
    equal arrays (used to identify ROIs, refinement brushes and frames)."""
    a = np.ascontiguousarray(arr)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a.reshape(-1).view(np.uint8)))
    return h.hexdigest()


# =================================================================== run folders
LOCK_NAME = ".napari-aldic.lock"
#: an empty or unreadable lock older than this (s) was left by a process killed
#: between creating and filling it
_UNREADABLE_LOCK_AGE = 30.0
#: tokens of the locks this process holds (a lock naming our pid but none of
#: these was left by an earlier process that had the same pid)
_HELD: set[str] = set()


def _lock_in_making(name: str) -> bool:
    """Whether ``name`` is the temporary of a lock that a live process on
    this host is creating now (``.napari-aldic.lock.<pid>.<token>.part``)."""
    if not name.startswith(LOCK_NAME + "."):
        return False
    pid = name[len(LOCK_NAME) + 1:].split(".")[0]
    return pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid))


def clean_temporaries(folder) -> list[str]:
    """Remove the temporaries (``*.part``, files or links) that killed runs
    left in the run ``folder``; call it while holding the folder's lock (no
    write of another process can then be in progress). Returns their names."""
    gone = []
    for entry in os.scandir(folder):
        if not entry.name.endswith(".part") or _lock_in_making(entry.name):
            continue
        if entry.is_dir(follow_symlinks=False):  # a field store being built
            shutil.rmtree(entry.path, ignore_errors=True)
        else:
            _remove(Path(entry.path))  # unlink: a planted link is removed, never followed
        gone.append(entry.name)
    return gone


@contextmanager
def folder_lock(folder):
    """Hold the exclusive lock of a run ``folder`` for the ``with`` block.

    The lock is the file ``.napari-aldic.lock``, created atomically
    (``O_CREAT | O_EXCL``) with the owner's pid, host, start time and command.
    A lock whose process has died on this host is taken over; any other
    existing lock raises :class:`RunFolderError` naming the folder and the
    owner. The lock is removed when the block ends.
    """
    path = Path(folder) / LOCK_NAME
    me = {"pid": os.getpid(), "host": socket.gethostname(),
          "started": time.strftime("%Y-%m-%d %H:%M:%S"),
          "command": " ".join(sys.argv)[:300], "token": secrets.token_hex(8)}
    _acquire(path, me)
    _HELD.add(me["token"])
    try:
        yield
    finally:
        _HELD.discard(me["token"])
        owner, _ = _read_lock(path)
        if owner is not None and owner.get("token") == me["token"]:
            _remove(path)


def _acquire(path: Path, me: dict) -> None:
    for _ in range(5):
        try:
            _create_lock(path, json.dumps(me).encode())
        except FileExistsError:
            owner, raw = _read_lock(path)
            if not _stale(path, owner):
                raise _in_use(path, owner) from None
            _take_over(path, raw)
            continue
        except OSError as exc:
            raise explain_os_error(exc, path) from None
        return
    raise RunFolderError(f"cannot lock the run folder {path.parent}: its lock file {path.name} "
                         "keeps changing (several runs starting at once?)", path.parent)


def _create_lock(path: Path, body: bytes) -> None:
    """Create the lock ``path`` holding ``body``, or raise FileExistsError.

    The body is written to a temporary file first and hard-linked to the
    lock's name (atomic, and fails if the name exists), so the lock is never
    seen empty: a run killed while locking, or a full disk, leaves no empty
    lock behind. Where hard links are not possible, ``O_EXCL`` creates it
    and a failed write removes it again."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.{secrets.token_hex(4)}.part")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(tmp, flags, 0o644)
        try:
            os.write(fd, body)
        finally:
            os.close(fd)
        try:
            os.link(tmp, path)
            return
        except FileExistsError:
            raise
        except OSError:  # no hard links on this file system
            pass
        fd = os.open(path, flags, 0o644)
        try:
            if os.write(fd, body) != len(body):
                raise OSError(errno.ENOSPC, "short write")
        except OSError:
            os.close(fd)
            _remove(path)
            raise
        os.close(fd)
    finally:
        _remove(tmp)


def _read_lock(path: Path) -> tuple[dict | None, bytes | None]:
    """The lock's owner (None if empty or unreadable) and its raw bytes."""
    try:
        raw = path.read_bytes()
    except OSError:
        return None, None
    try:
        owner = json.loads(raw)
    except ValueError:
        return None, raw
    return (owner if isinstance(owner, dict) else None), raw


def _alive(pid: int) -> bool:
    if os.name == "nt":  # os.kill would stop the process there: never assume it dead
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def _stale(path: Path, owner: dict | None) -> bool:
    """Was the lock left by a process that no longer runs?"""
    if owner is None:  # being written right now, or its writer was killed at once
        try:
            return time.time() - path.stat().st_mtime > _UNREADABLE_LOCK_AGE
        except OSError:
            return True  # gone meanwhile: try again
    pid = owner.get("pid")
    if owner.get("host") != socket.gethostname() or not isinstance(pid, int):
        return False  # a process on another computer cannot be checked from here
    if pid == os.getpid():
        return owner.get("token") not in _HELD
    return not _alive(pid)


def _take_over(path: Path, raw: bytes | None) -> None:
    """Remove the stale lock ``path`` if it still holds ``raw``: it is moved
    aside first (atomic), and put back if another process has replaced it."""
    aside = path.with_name(f"{path.name}.{secrets.token_hex(4)}.part")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return  # another process removed it first
    except OSError as exc:
        raise explain_os_error(exc, path) from None
    try:
        if raw is None or aside.read_bytes() != raw:  # a fresh lock: restore it
            try:
                os.link(aside, path)
            except FileExistsError:
                pass
            except OSError:
                if not path.exists():
                    os.rename(aside, path)
    finally:
        _remove(aside)


def _in_use(path: Path, owner: dict | None) -> RunFolderError:
    folder = path.parent
    if owner is None:
        who = "a process that is starting now"
    else:
        who = (f"process {owner.get('pid')} on host {owner.get('host')}, started "
               f"{owner.get('started')}")
        if owner.get("command"):
            who += f": {owner['command']}"
    return RunFolderError(
        f"the run folder {folder} is in use by another napari-aldic run ({who}). Wait for "
        f"it to finish or choose another folder; if that run is no longer active (e.g. it "
        f"ran on another computer and crashed), delete {path}", folder, owner)
