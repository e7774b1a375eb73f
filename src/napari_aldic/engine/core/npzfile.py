"""Reading result ``.npz`` files defensively: structure first, data second.

A result file can be empty, truncated by an interrupted copy, a text file
given the ``.npz`` name, edited so that its arrays disagree, or made to
decompress into more memory than the computer has (a "zip bomb"). Every
``.npy`` member of an ``.npz`` starts with a small header giving its shape and
data type, so :func:`read_result_npz` reads those headers first (nothing is
decompressed beyond them), checks that the arrays fit together and fit in
memory, and only then loads them. Every error is a ``ValueError`` (or
``FileNotFoundError``) whose message names the file and the problem.
"""

from __future__ import annotations

import errno
import math
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .files import available_memory, open_regular, parse_json
from .params import DICParams

__all__ = ["read_result_npz", "npz_headers", "check_invariants", "MAX_IMAGE_SIDE"]

#: largest image side (pixels) a result file may declare
MAX_IMAGE_SIDE = 1 << 20
#: largest header (JSON text) a result file may declare, bytes
_MAX_HEADER_BYTES = 64 << 20
_ZIP_MAGIC = b"PK\x03\x04"


def _fail(path: Path, problem: str) -> ValueError:
    return ValueError(f"cannot read result file {path}: {problem}")


def _opening_bytes(path: Path) -> bytes:
    if not os.path.lexists(path):
        raise FileNotFoundError(errno.ENOENT, f"no result file at {path}", str(path))
    try:
        with open_regular(path, "result file") as fh:
            return fh.read(64)
    except OSError as exc:
        raise _fail(path, exc.strerror or str(exc)) from None


def _what_it_is(start: bytes) -> str:
    if not start:
        return "the file is empty (0 bytes)"
    if start.startswith(b"\x93NUMPY"):
        return "it is a single NumPy array (.npy), not a result archive (.npz)"
    if start.startswith(b"MATLAB"):
        return "it is a MATLAB file; read it with load_mat"
    if all(32 <= c < 127 or c in b"\t\r\n" for c in start.rstrip(b"\0")):
        return "it is a text file, not an .npz archive"
    return "it is not an .npz (zip) archive"


def npz_headers(path) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Shape and data type of every array of an ``.npz``, read from the
    ``.npy`` headers only (no array data is decompressed).

    Raises ``ValueError`` naming the file when it is empty, not a zip
    archive, truncated, damaged, or holds Python objects (pickles).
    """
    path = Path(os.fspath(path))
    start = _opening_bytes(path)
    if not start.startswith(_ZIP_MAGIC):
        raise _fail(path, _what_it_is(start))
    heads = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if info.filename.endswith(".npy"):
                    heads[info.filename[:-4]] = _member_header(path, zf, info)
    except zipfile.BadZipFile as exc:
        raise _fail(path, f"the archive is truncated or damaged ({exc}); an interrupted "
                          "copy or save leaves such a file") from None
    except (OSError, EOFError, zlib.error, NotImplementedError, RuntimeError) as exc:
        raise _fail(path, f"the archive is damaged ({exc})") from None
    return heads


def _member_header(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo):
    name = info.filename[:-4]
    fmt = np.lib.format
    try:
        with zf.open(info) as fh:
            version = fmt.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = fmt.read_array_header_1_0(fh)
            elif version == (2, 0):
                shape, _, dtype = fmt.read_array_header_2_0(fh)
            else:
                raise ValueError(f".npy format version {version} is not supported")
    except (ValueError, EOFError, zlib.error, zipfile.BadZipFile, NotImplementedError,
            RuntimeError) as exc:  # RuntimeError: zipfile's "encrypted" member
        raise _fail(path, f"array {name!r} is damaged ({exc})") from None
    if dtype.hasobject:
        raise _fail(path, f"array {name!r} holds Python objects (pickled data), which "
                          "napari-aldic never writes; it is not loaded")
    return tuple(int(s) for s in shape), dtype


def _nbytes(head) -> int:
    shape, dtype = head
    return math.prod(shape) * dtype.itemsize


def _read_header(path: Path, heads: dict, fmt: str) -> dict:
    """The JSON header of a result file, with ``image_shape`` (a tuple),
    ``params`` (a DICParams) and ``meta`` (a dict) checked."""
    if "header" not in heads:
        raise _fail(path, "it is not a napari-aldic result file (no header)")
    shape, dtype = heads["header"]
    if shape != () or dtype.kind != "U" or _nbytes(heads["header"]) > _MAX_HEADER_BYTES:
        raise _fail(path, f"its header is not a text of at most {_MAX_HEADER_BYTES >> 20} MB "
                          f"(shape {shape}, dtype {dtype})")
    try:
        with np.load(path, allow_pickle=False) as z:
            text = str(z["header"])
    except (ValueError, OSError, EOFError, zlib.error, zipfile.BadZipFile,
            NotImplementedError, RuntimeError) as exc:
        raise _fail(path, f"its header is damaged ({exc})") from None
    try:
        header = parse_json(text, path)
    except ValueError as exc:
        raise _fail(path, f"its header {exc.problem}") from None
    if not isinstance(header, dict) or header.get("format") != fmt:
        raise _fail(path, "it is not a napari-aldic result file (wrong format in its header)")
    dims = header.get("image_shape")
    if not (isinstance(dims, list) and len(dims) == 2 and all(
            isinstance(d, int) and not isinstance(d, bool) and 1 <= d <= MAX_IMAGE_SIDE
            for d in dims)):
        raise _fail(path, f"image_shape {dims!r} in its header is not two whole numbers "
                          f"(rows, cols) between 1 and {MAX_IMAGE_SIDE}")
    header["image_shape"] = (dims[0], dims[1])
    try:
        header["params"] = DICParams.from_dict(header.get("params") or {})
    except (TypeError, ValueError) as exc:
        raise _fail(path, f"the parameters in its header are invalid: {exc}") from None
    meta = header.get("meta", {})
    if not isinstance(meta, dict):
        raise _fail(path, f"'meta' in its header is a {type(meta).__name__}, not an object")
    header["meta"] = meta
    return header


def _check_layout(path: Path, heads: dict, shape: tuple[int, int], required, optional):
    """Refuse arrays that do not fit together, before any is decompressed."""
    missing = [k for k in required if k not in heads]
    if missing:
        raise _fail(path, f"the file is incomplete: array(s) {missing} are missing")
    rows, cols = shape
    n_shape = heads["x"][0]
    if len(n_shape) != 1:
        raise _fail(path, f"array 'x' has shape {n_shape}; expected one value per node")
    n = n_shape[0]
    if n > rows * cols:
        raise _fail(path, f"it declares {n} nodes for a {rows} x {cols} image (more nodes "
                          "than pixels); the file is damaged")
    for k in [k for k in (*required, *optional) if k in heads]:
        k_shape, dtype = heads[k]
        if dtype.kind not in "biuf":
            raise _fail(path, f"array {k!r} has dtype {dtype}; expected numbers")
        want = {"grid_xs": (cols,), "grid_ys": (rows,), "elements": (4 * n, 4),
                "hanging": (n, 3)}.get(k)
        if want is None and k_shape != (n,):
            raise _fail(path, f"array {k!r} has shape {k_shape} but 'x' has {n} entries; its "
                              "arrays disagree (damaged or edited file)")
        if want is not None and (len(k_shape) != len(want) or any(
                a > b for a, b in zip(k_shape, want)) or k_shape[1:] != want[1:]):
            raise _fail(path, f"array {k!r} has shape {k_shape}, impossible for {n} nodes on "
                              f"a {rows} x {cols} image (damaged or edited file)")
    total = sum(_nbytes(heads[k]) for k in (*required, *optional) if k in heads)
    if "roi_packed" in heads:
        need = (rows * cols + 7) // 8
        if heads["roi_packed"][0] != (need,) or heads["roi_packed"][1] != np.uint8:
            raise _fail(path, f"its ROI holds {heads['roi_packed'][0]} {heads['roi_packed'][1]} "
                              f"but image_shape {rows} x {cols} in its header needs ({need},) "
                              "uint8 (bit-packed); the header and the ROI disagree")
        total += _nbytes(heads["roi_packed"]) + rows * cols
    memory = available_memory()
    if memory is not None and total > memory:
        raise _fail(path, f"its arrays would need {total / 2**30:.1f} GiB, more than the "
                          f"memory available now ({memory / 2**30:.1f} GiB); the file is "
                          "damaged, or too large for this computer")


def _check_values(path: Path, arrays: dict, shape: tuple[int, int]) -> None:
    """Indices and coordinates that would break later code (or mislead)."""
    rows, cols = shape
    x, y = arrays["x"], arrays["y"]
    n = x.size
    if n and not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))
                  and x.min() >= 0 and y.min() >= 0 and x.max() <= cols - 1
                  and y.max() <= rows - 1):
        raise _fail(path, f"its node coordinates (x {np.nanmin(x):g} to {np.nanmax(x):g}, y "
                          f"{np.nanmin(y):g} to {np.nanmax(y):g}) lie outside the {rows} x "
                          f"{cols} image of its header")
    for idx, lattice in (("grid_ix", "grid_xs"), ("grid_iy", "grid_ys")):
        ix = arrays[idx]
        if ix.size and (ix.min() < -1 or ix.max() >= arrays[lattice].size):
            raise _fail(path, f"array {idx!r} points outside the {arrays[lattice].size} "
                              f"entries of {lattice!r}")
    for k in ("elements", "hanging"):
        e = arrays.get(k)
        if e is not None and e.size and (e.min() < 0 or e.max() >= n):
            raise _fail(path, f"array {k!r} refers to nodes outside the {n} of the result")
    problem = check_invariants(arrays)
    if problem:
        raise _fail(path, problem)


#: per-node values a trusted node must have finite
_FINITE_WHEN_VALID = ("u", "v", "dudx", "dudy", "dvdx", "dvdy", "zncc")


def check_invariants(arrays: dict) -> str | None:
    """What breaks a result's invariants (a trusted node has finite values
    and reason 0; ``valid`` holds only 0 and 1), in words; None when sound.
    An edited file must not make untrusted values pass as trusted."""
    valid = np.asarray(arrays["valid"])
    if valid.dtype != bool:
        if valid.size and not np.isin(valid, (0, 1)).all():
            return "its 'valid' array holds values other than 0 and 1 (damaged or edited file)"
        valid = valid.astype(bool)
    reason = np.asarray(arrays["reason"])
    bad = np.nonzero(valid & (reason != 0))[0]
    if bad.size:
        return (f"{bad.size} node(s) are marked valid but carry a failure reason (node "
                f"{bad[0]}: reason {int(reason[bad[0]])}); a valid node has reason 0 "
                "(damaged or edited file)")
    for k in _FINITE_WHEN_VALID:
        values = arrays.get(k)
        if values is None:
            continue
        bad = np.nonzero(valid & ~np.isfinite(np.asarray(values, float)))[0]
        if bad.size:
            return (f"{bad.size} node(s) are marked valid but their {k!r} is not a finite "
                    f"number (node {bad[0]}: {values[bad[0]]}); a valid node has finite "
                    "values (damaged or edited file)")
    return None


def _load(path: Path, names) -> dict:
    out, k = {}, None
    try:
        with np.load(path, allow_pickle=False) as z:
            for k in names:
                out[k] = z[k]
    except (ValueError, OSError, EOFError, zlib.error, zipfile.BadZipFile,
            NotImplementedError, RuntimeError) as exc:
        raise _fail(path, f"array {k!r} is damaged ({exc})") from None
    except MemoryError:
        raise _fail(path, f"array {k!r} does not fit in the memory available now") from None
    return out


def read_result_npz(path, fmt: str, required, optional) -> tuple[dict, dict]:
    """The header and arrays of a result ``.npz`` after every check.

    ``fmt`` is the header's expected ``format``; ``required`` and ``optional``
    name the per-node (and mesh) arrays. Returns ``(header, arrays)``: the
    header with ``image_shape`` a tuple, ``params`` a DICParams and ``meta`` a
    dict; ``arrays`` holds the required arrays, the optional ones present and
    ``roi`` (bool image) when the file stores a bit-packed ROI.
    """
    path = Path(os.fspath(path))
    heads = npz_headers(path)
    header = _read_header(path, heads, fmt)
    shape = header["image_shape"]
    _check_layout(path, heads, shape, required, optional)
    names = [k for k in (*required, *optional, "roi_packed") if k in heads]
    arrays = _load(path, names)
    _check_values(path, arrays, shape)
    packed = arrays.pop("roi_packed", None)
    if packed is not None:
        bits = np.unpackbits(packed, count=shape[0] * shape[1])
        arrays["roi"] = bits.reshape(shape).astype(bool)
    return header, arrays
