"""Run folders of ``track``: what identifies an analysis, and the checks that
keep two analyses from mixing in one folder.

A run folder holds ``sequence.json`` (the manifest), one ``frame_#####.npz``
per finished frame, the ROI(s) once as ``roi_<digest>.npz`` and, while a
run writes it, the lock ``.napari-aldic.lock``. The manifest records
everything that defines the results (:data:`IDENTITY`): parameters (seeds
included), reference mode, ``update_every``, the frame list, the ROI and
per-frame ROIs (SHA-256 of the masks), the refinement (a brush region by
its digest), the extra frame metadata, and the stack's identity (the
analysed frame files' names, sizes and modification times, and a content
digest of the first and last analysed frame). A rerun resumes only when all
of them are equal; otherwise :class:`RunFolderError` names what changed.

Manifests of earlier versions (no ``format_version``) did not record the
ROI, the refinement or the stack, so nothing proves that a rerun is the same
analysis: they are refused for resuming (their results stay readable with
``load_run`` and ``export``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..core.files import (
    RunFolderError,
    array_digest,
    atomic_write,
    clean_temporaries,
    explain_os_error,
    folder_lock,
    parse_json,
    read_json_file,
)
from ..core.npzfile import npz_headers
from ..core.version import __version__
from ..dic.quadtree import resolve_refinement

MANIFEST = "sequence.json"
#: the key of a frame result's meta holding the digest of the image it was computed
#: from (frame k's pixels, read once), checked when a run resumes
IMAGE_DIGEST = "image_sha256"
FORMAT = "napari-aldic-run"
FORMAT_VERSION = 2
#: manifest entries that define a run, in the order differences are reported
IDENTITY = ("params", "reference", "update_every", "frames", "roi", "rois", "refine",
            "meta", "stack")
_WHAT = {"reference": "the reference mode", "update_every": "update_every",
         "frames": "the analysed frames", "meta": "the metadata stored with each frame "
         "(e.g. units)"}


# ----------------------------------------------------------------- records
def roi_record(mask: np.ndarray, digest: str) -> dict:
    """How the manifest identifies a ROI: its digest and size."""
    return {"sha256": digest, "pixels": int(np.count_nonzero(mask)),
            "shape": list(mask.shape)}


def refine_record(refine) -> dict | None:
    """The refinement given to ``track`` (None: ``params.refine`` applies), with
    a painted brush region identified by its digest."""
    ref = resolve_refinement(refine)
    if ref is None:
        return None
    out = {}
    for f in dataclasses.fields(ref):
        value = getattr(ref, f.name)
        if f.name == "brush" and value is not None:
            brush = np.asarray(value, bool)
            value = {"sha256": array_digest(brush), "pixels": int(brush.sum())}
        out[f.name] = value
    return _plain(out)


def stack_record(src, idx: list[int]) -> dict:
    """The stack's identity: frame size, a content digest of the first and the
    last analysed frame, and name, size and modification time of the files
    the analysed frames come from (none for arrays in memory)."""
    first, last = np.asarray(src[idx[0]]), np.asarray(src[idx[-1]])
    files = []
    for p in _frame_files(src, idx):
        st = os.stat(p)
        files.append({"name": os.path.basename(p), "size": st.st_size,
                      "mtime_ns": st.st_mtime_ns})
    return {"frame_shape": list(first.shape), "dtype": first.dtype.str,
            "first": array_digest(first), "last": array_digest(last), "files": files}


def _frame_files(src, idx: list[int]) -> list[str]:
    """The files holding the analysed frames: the TIFF stack, else one file
    per frame (a folder or a list of images); none for an array."""
    if src.name is not None and os.path.isfile(src.name):
        return [src.name]
    names = [src.frame_name(k) for k in idx]
    return names if all(os.path.isfile(n) for n in names) else []


def _plain(value):
    """``value`` as JSON gives it back (tuples become lists)."""
    return json.loads(json.dumps(value))


def run_id(info: dict) -> str:
    """A short digest of a run's identity, stored in every frame it writes."""
    text = json.dumps({k: info.get(k) for k in IDENTITY}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# ----------------------------------------------------------------- the folder
@contextmanager
def run_folder(out_dir, info: dict) -> Iterator[Path]:
    """Lock ``out_dir`` (created if needed) for the ``with`` block, remove
    temporaries of killed runs, and check its manifest against ``info`` (or
    write it to a new folder)."""
    out = Path(os.fspath(out_dir)).expanduser()
    if out.exists() and not out.is_dir():
        raise RunFolderError(f"cannot use {out} as a run folder: it is a file", out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise explain_os_error(exc, out) from None
    with folder_lock(out):
        clean_temporaries(out)
        check_or_create(out, _plain(info))
        yield out


def check_or_create(out: Path, info: dict) -> None:
    """Write the manifest of a new run folder, or check that the folder's
    manifest describes the same analysis as ``info`` (raises otherwise)."""
    manifest = out / MANIFEST
    if not os.path.lexists(manifest):
        results = sorted(p.name for p in out.glob("*.npz"))
        if results:
            raise RunFolderError(
                f"{out} holds result files ({', '.join(results[:3])}"
                f"{', ...' if len(results) > 3 else ''}) but no {MANIFEST}: results of "
                "another analysis. Choose an empty folder", out)
        write_manifest(out, info)
        return
    try:
        old = read_json_file(manifest, "run manifest")
    except (OSError, ValueError) as exc:
        raise RunFolderError(f"cannot read the run manifest {manifest}: {exc}. Choose another "
                             "folder (or delete the folder's contents)", out) from None
    if not isinstance(old, dict) or ("format" in old and old.get("format") != FORMAT):
        raise RunFolderError(f"{manifest} is not a napari-aldic run manifest; choose an "
                             "empty folder", out)
    version = old.get("format_version")
    if version is None:
        raise RunFolderError(
            f"{manifest} was written by an earlier napari-aldic version, which did not "
            "record the ROI, the refinement or the image stack: nothing shows that this run "
            "is the same analysis, so it is not resumed. Its results stay readable (load_run, "
            "'napari-aldic export'); analyse into an empty folder", out)
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise RunFolderError(f"{manifest} has format version {version!r}, newer than this "
                             f"napari-aldic ({__version__}) reads; update napari-aldic or "
                             "choose another folder", out)
    changed = differences(old, info)
    if changed:
        raise RunFolderError(
            f"{out} holds results of a different analysis: {'; '.join(changed)}. Choose an "
            "empty folder, or rerun with the same inputs and settings to resume", out)


def write_manifest(out: Path, info: dict) -> str:
    """Write (or replace, atomically) the manifest of run folder ``out`` for
    the identity ``info``; returns its run id. A growing run (``watch``)
    rewrites it as frames are added."""
    info = _plain(info)
    rid = run_id(info)
    doc = {"format": FORMAT, "format_version": FORMAT_VERSION, "software": __version__,
           **info, "run_id": rid}
    with atomic_write(out / MANIFEST) as tmp:
        tmp.write_text(json.dumps(doc, indent=1))
    return rid


# ----------------------------------------------------------------- differences
def differences(old: dict, new: dict) -> list[str]:
    """What differs between two run identities, in words."""
    out = []
    for key in IDENTITY:
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if key == "params":
            out.append(_params_diff(a or {}, b or {}))
        elif key == "stack":
            out.extend(_stack_diff(a or {}, b or {}))
        elif key == "roi":
            out.append(f"the ROI changed ({_roi_words(a)} recorded, {_roi_words(b)} now)")
        elif key == "rois":
            out.append(_rois_diff(a, b))
        elif key == "refine":
            out.append(_refine_diff(a, b))
        else:
            out.append(f"{_WHAT[key]} changed ({_short(a)} recorded, {_short(b)} now)")
    return out


def _short(value, limit: int = 80) -> str:
    text = json.dumps(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _roi_words(rec) -> str:
    if not rec:
        return "none"
    return f"{rec.get('pixels', 0):,} px, sha256 {str(rec.get('sha256'))[:12]}"


def _params_diff(a: dict, b: dict) -> str:
    keys = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    pairs = ", ".join(f"{k} {_short(a.get(k), 30)} -> {_short(b.get(k), 30)}" for k in keys)
    return f"the parameters changed ({pairs})"


def _rois_diff(a, b) -> str:
    if not a or not b:
        return ("per-frame ROIs " + ("were given" if a else "were not given") +
                " for the recorded run" + (" but not now" if a else " but are now"))
    bad = [k for k in sorted(set(a) | set(b), key=int) if a.get(k) != b.get(k)]
    return f"the per-frame ROIs changed (reference frame(s) {', '.join(bad[:8])})"


def _refine_diff(a, b) -> str:
    if a and b and {k: v for k, v in a.items() if k != "brush"} == \
            {k: v for k, v in b.items() if k != "brush"}:
        return (f"the painted refinement region changed ({_roi_words(a.get('brush'))} "
                f"recorded, {_roi_words(b.get('brush'))} now)")
    return f"the refinement changed ({_short(a)} recorded, {_short(b)} now)"


def _stack_diff(a: dict, b: dict) -> list[str]:
    out = []
    if a.get("frame_shape") != b.get("frame_shape") or a.get("dtype") != b.get("dtype"):
        out.append(f"the image stack changed (frames of shape {a.get('frame_shape')} "
                   f"{a.get('dtype')} recorded, {b.get('frame_shape')} {b.get('dtype')} now)")
    fa, fb = a.get("files") or [], b.get("files") or []
    if [f["name"] for f in fa] != [f["name"] for f in fb]:
        gone = [f["name"] for f in fa if f["name"] not in {g["name"] for g in fb}]
        new = [f["name"] for f in fb if f["name"] not in {g["name"] for g in fa}]
        out.append("the image stack changed (other frame files: "
                   + (f"{', '.join(gone[:3])} recorded" if gone else "")
                   + (", " if gone and new else "")
                   + (f"{', '.join(new[:3])} now" if new else "the order differs") + ")")
    else:
        changed = [(x, y) for x, y in zip(fa, fb) if x != y]
        for x, y in changed[:3]:
            how = (f"size {x['size']:,} -> {y['size']:,} bytes" if x["size"] != y["size"]
                   else "modification time changed")
            out.append(f"the image file {y['name']} changed since the run started ({how})")
        if len(changed) > 3:
            out.append(f"{len(changed) - 3} more image files changed")
    for end in ("first", "last"):
        if a.get(end) != b.get(end) and not out:
            out.append(f"the image stack changed (the {end} analysed frame holds other pixel "
                       "values)")
    return out


def record_digests(out: Path, digests: dict) -> None:
    """Keep the digest of every analysed frame's image (frame number -> SHA-256,
    as :data:`IMAGE_DIGEST` in each frame's result file) in the manifest too:
    rewritten once when a run ends, not per frame (each frame's file holds
    its own, so a killed run loses none)."""
    manifest = out / MANIFEST
    doc = read_json_file(manifest, "run manifest")
    doc["frame_sha256"] = {str(k): digests[k] for k in sorted(digests)}
    with atomic_write(manifest) as tmp:
        tmp.write_text(json.dumps(doc, indent=1))


# ----------------------------------------------------------------- frame files
def frame_file_meta(path: Path) -> dict:
    """The ``meta`` of a finished frame's result file, after checking every
    member's CRC (a bit flipped on disk is found when resuming, not by a
    later export). Raises ``ValueError`` saying what is wrong (the caller
    names the file)."""
    npz_headers(path)  # refuses a FIFO, a truncated or foreign file, naming it
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
        if bad is not None:
            raise ValueError(f"its member {bad} fails its CRC check")
        with np.load(path, allow_pickle=False) as z:
            doc = parse_json(str(z["header"]), f"the header of {path}")
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, zlib.error,
            NotImplementedError) as exc:
        raise ValueError(f"it is damaged ({exc})") from None
    meta = doc.get("meta") if isinstance(doc, dict) else None
    return meta if isinstance(meta, dict) else {}
