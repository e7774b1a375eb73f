"""Loading results for exports: result files, .mat files, run folders, frame sets."""

from __future__ import annotations

import json
import os
import re
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import parse_json, read_json_file
from ..core.npzfile import check_invariants, npz_headers
from ..core.params import DICParams
from ..core.results import DICResult, LazyFrames, SequenceResult, load_result
from ..core.settings import STRAIN_DEFAULTS
from ..core.units import Units
from .stack import natural_key

MAT_FORMAT = "napari-aldic-mat"
MAT_FORMAT_VERSION = 1
STRAIN_NAMES = ("exx", "eyy", "exy", "e1", "e2", "max_shear", "von_mises", "rotation")
RATE_NAMES = ("exx", "eyy", "exy")


# =================================================================== inputs
@dataclass
class Frame:
    """One frame of an export: its number, result and (optional) strain.

    ``prev`` is the previous frame of the sequence (for velocities and
    strain rates); ``None`` means the reference frame 0 (zero field).
    """

    index: int
    result: DICResult
    strain: Any = None
    prev: Frame | None = None


class LazyFrame(Frame):
    """A :class:`Frame` of a run read back from its folder: its result is read
    from its file when used (the run keeps only the last few frames read, see
    :class:`~napari_aldic.engine.core.results.LazyFrames`) and its strain is
    computed when used (the last few kept), so an export goes through
    thousands of frames with memory flat in their number."""

    def __init__(self, index: int, load, prev: Frame | None = None):
        self.index, self.prev = int(index), prev
        self._load = load  # () -> DICResult
        self._pinned = None  # a result set by assignment
        self._strain_set, self._strain_value = False, None  # a strain set by assignment
        self._given = self._compute = None  # () -> strain given; result -> strain
        self._strains: OrderedDict = OrderedDict()

    @property
    def result(self) -> DICResult:
        return self._pinned if self._pinned is not None else self._load()

    @result.setter
    def result(self, value: DICResult) -> None:
        self._pinned = value

    @property
    def strain(self):
        if self._strain_set:
            return self._strain_value
        if self._given is None and self._compute is None:
            return None
        cache = self._strains  # shared by the frames of one collect_frames call
        if id(self) in cache:
            cache.move_to_end(id(self))
            return cache[id(self)]
        s = self._given() if self._given is not None else None
        if s is None and self._compute is not None:
            s = self._compute(self.result)
        cache[id(self)] = s
        while len(cache) > _STRAINS_KEPT:
            cache.popitem(last=False)
        return s

    @strain.setter
    def strain(self, value) -> None:
        self._strain_set, self._strain_value = True, value

    def __repr__(self) -> str:
        return f"LazyFrame(index={self.index})"


#: strain results a collection of lazy frames keeps (a frame and the one before it)
_STRAINS_KEPT = 3


def _frame_of(meta: dict | None, default: int) -> int:
    meta = meta or {}
    for k in (meta.get("frame"), (meta.get("inputs") or {}).get("frame")):
        if isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            return int(k)
    return default


def _result_of(r) -> DICResult:
    """A result of :func:`_as_results`' pairs: itself, or read when asked for."""
    return r if isinstance(r, DICResult) else r()


def load_run(folder):
    """Read the results of a run folder as a ``SequenceResult``.

    ``folder`` is a run folder of ``track`` or ``napari-aldic run``
    (``sequence.json`` and ``frame_#####.npz``; the frames share the
    folder's one ROI array) or a folder of result ``.npz`` files (e.g. the
    ``frame###.npz`` of older ``napari-aldic run`` versions). Frames are
    ordered by their frame number (stored in each result, else the digits of
    the file name). Frames not on disk (not computed yet) are ``None``.

    The frames are read when used (``seq[k]``, iterating, an export), not
    all at once: ``seq.frames`` is a
    :class:`~napari_aldic.engine.core.results.LazyFrames`. Every file's
    structure is checked here (an empty, truncated or foreign file is
    refused now); its arrays are checked when its frame is read.
    """
    folder = Path(os.fspath(folder)).expanduser()
    if not folder.is_dir():
        raise FileNotFoundError(f"no run folder at {folder}")
    manifest = folder / "sequence.json"
    if os.path.lexists(manifest):
        info = read_json_file(manifest, "run manifest")
        idx = _manifest_frames(manifest, info)
        paths = [folder / f"frame_{k:05d}.npz" for k in idx]
        paths = [p if p.exists() else None for p in paths]
        for p in paths:
            if p is not None:
                npz_headers(p)  # a damaged file is refused now, not midway through an export
        frames = LazyFrames(paths)
        if not any(frames.present):
            raise ValueError(f"{folder} holds no frame results yet (frame_#####.npz)")
        try:
            params = DICParams.from_dict(info["params"]) if info.get("params") else None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"cannot read the run manifest {manifest}: its parameters are "
                             f"invalid ({exc})") from None
        params = params or next(f for f in frames if f is not None).params
        meta = {"frames": idx, "source": info.get("source"),
                "update_every": info.get("update_every"), "folder": str(folder)}
        return SequenceResult(frames, params, info.get("reference", "accumulative"), meta)
    return _result_folder(folder)


def _manifest_frames(manifest: Path, info) -> list[int]:
    """The frame numbers of a run manifest, checked (a hand-edited manifest
    is named, not half read)."""
    frames = info.get("frames") if isinstance(info, dict) else None
    if not (isinstance(frames, list) and frames and all(
            isinstance(k, int) and not isinstance(k, bool) and 0 <= k < 10**8 for k in frames)
            and frames == sorted(set(frames))):
        what = "not a JSON object" if not isinstance(info, dict) else \
            f"its 'frames' entry is {str(info.get('frames'))[:60]!r}"
        raise ValueError(f"cannot read the run manifest {manifest}: {what}; expected an "
                         "object whose 'frames' is an increasing list of frame numbers "
                         "(a damaged or hand-edited file)")
    for key, kind in (("params", dict), ("reference", str)):
        if info.get(key) is not None and not isinstance(info[key], kind):
            raise ValueError(f"cannot read the run manifest {manifest}: its {key!r} entry "
                             f"is a {type(info[key]).__name__} (a damaged or hand-edited "
                             "file)")
    return frames


def _result_folder(folder: Path) -> SequenceResult:
    """:func:`load_run` of a folder of result ``.npz`` files (no manifest)."""
    files = sorted(folder.glob("*.npz"), key=lambda p: natural_key(p.name))
    if not files:
        raise FileNotFoundError(f"{folder} holds no result files (.npz) and no sequence.json")
    found = {}
    for pos, p in enumerate(files):
        meta, params = _result_header(p)
        digits = re.findall(r"\d+", p.stem)
        k = _frame_of(meta, int(digits[-1]) if digits else pos + 1)
        if k in found:
            raise ValueError(f"{folder}: two result files for frame {k} ({found[k][0].name}, "
                             f"{p.name}); keep one run per folder")
        found[k] = (p, params)
    idx = sorted(found)
    first = found[idx[0]][1]
    if idx[0] != 0:
        idx = [0] + idx
    frames = LazyFrames([found[k][0] if k in found else None for k in idx])
    meta = {"frames": idx, "source": str(folder), "folder": str(folder)}
    return SequenceResult(frames, first, "accumulative", meta)


def _result_header(path: Path) -> tuple[dict, DICParams]:
    """``meta`` and ``params`` of a result file from its JSON header alone (no
    array is decompressed). A file whose header is not sound is read whole,
    so that the reader's error names the problem."""
    try:
        shape, dtype = npz_headers(path)["header"]
        if shape == () and dtype.kind == "U" and dtype.itemsize <= _MAX_HEADER_BYTES:
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(str(z["header"]))
            if isinstance(header, dict) and isinstance(header.get("meta", {}), dict):
                return header.get("meta") or {}, DICParams.from_dict(header.get("params") or {})
    except (KeyError, TypeError, ValueError, OSError, RecursionError, NotImplementedError):
        pass
    res = load_result(path)  # raises the reader's error for a file that is not a result
    return res.meta, res.params


#: largest JSON header read to order the frames of a folder (bytes)
_MAX_HEADER_BYTES = 64 << 20


def _as_results(data) -> tuple[list[tuple[int, Any]], dict]:
    """(frame number, result) pairs and info about the source; the result of
    a lazy sequence is a function that reads it (see :func:`_result_of`)."""
    if isinstance(data, (str, os.PathLike)):
        p = Path(os.fspath(data)).expanduser()
        if p.is_dir():
            return _as_results(load_run(p))
        if not p.exists():
            raise FileNotFoundError(f"no result file or run folder at {p}")
        if p.suffix.lower() == ".mat":
            return _as_results(load_mat(p))
        res = load_result(p)
        return [(_frame_of(res.meta, 1), res)], {"source": str(p)}
    if isinstance(data, DICResult):
        return [(_frame_of(data.meta, 1), data)], {}
    if isinstance(data, Frame):
        return [(data.index, data.result)], {}
    if hasattr(data, "frames") and hasattr(data, "params"):  # SequenceResult
        meta = getattr(data, "meta", {}) or {}
        idx = meta.get("frames")
        if not idx or len(idx) != len(data.frames):
            idx = list(range(len(data.frames)))
        present = getattr(data.frames, "present", None)
        if present is not None:  # LazyFrames: each frame read when used
            pairs = [(int(k), partial(data.frames.__getitem__, i))
                     for i, (k, ok) in enumerate(zip(idx, present)) if ok]
        else:
            pairs = [(int(k), r) for k, r in zip(idx, data.frames) if r is not None]
        info = {"source": meta.get("source"), "folder": meta.get("folder"),
                "reference": getattr(data, "reference", None)}
        if not pairs:
            raise ValueError("the sequence holds no computed frame")
        return pairs, info
    if isinstance(data, (list, tuple)):
        pairs = []
        files = LazyFrames([Path(os.fspath(it)).expanduser()
                            if isinstance(it, (str, os.PathLike)) else None for it in data])
        for pos, item in enumerate(data):
            if item is None:
                continue
            if isinstance(item, Frame):
                pairs.append((item.index, item.result))
            elif isinstance(item, (str, os.PathLike)):
                # the frame number from the file's JSON header: the arrays are
                # read when the frame is used (exports go one frame at a time)
                meta, _ = _result_header(files.paths[pos])
                pairs.append((_frame_of(meta, pos), partial(files.__getitem__, pos)))
            elif isinstance(item, DICResult):
                pairs.append((_frame_of(item.meta, pos), item))
            else:
                raise TypeError(f"item {pos} is a {type(item).__name__}, not a DICResult")
        if not pairs:
            raise ValueError("no result to export (empty list)")
        return pairs, {}
    raise TypeError(f"cannot export a {type(data).__name__}: give a DICResult, a "
                    "SequenceResult, a list of results, a result file or a run folder")


def _strain_for(res: DICResult, strain, i: int):
    from ..dic.strain import StrainResult, compute_strain

    if strain is None or strain is False:
        return None
    if strain is True:
        return compute_strain(res, **STRAIN_DEFAULTS)
    if isinstance(strain, dict):
        return compute_strain(res, **{**STRAIN_DEFAULTS, **strain})
    if isinstance(strain, StrainResult):
        return strain
    if isinstance(strain, (list, tuple)):
        return strain[i]
    raise TypeError("strain must be True, False, a dict of compute_strain options, a "
                    "StrainResult or a list of them")


def collect_frames(data, *, frames: Iterable[int] | None = None, strain=True,
                   units=None) -> tuple[list[Frame], Units, dict]:
    """Normalise ``data`` into frames, units and a description.

    Parameters
    ----------
    data : DICResult, SequenceResult, list of DICResult, or a path
    frames : iterable of int, optional
        Frame numbers to keep (default all). Previous frames are still used
        for velocities and strain rates.
    strain : bool, dict, StrainResult or list of StrainResult
        ``True`` computes strain with
        :data:`~napari_aldic.engine.core.settings.STRAIN_DEFAULTS`; a dict
        overrides them (``window``, ``method``, ``measure``); ``False``
        exports no strain.
    units : Units or dict, optional
        Defaults to the units stored in the first result's
        ``meta["units"]``, else pixels without a frame interval.

    Returns
    -------
    (frames, units, info)
        The frames of a run folder (or of a ``SequenceResult`` read back
        with :func:`load_run`) are :class:`LazyFrame`: each reads its
        result and computes its strain when used.
    """
    if isinstance(data, FrameSet):  # already collected: keep the strain computed
        pairs = [(f.index, partial(getattr, f, "result") if isinstance(f, LazyFrame)
                  else f.result) for f in data]
        info = dict(data.info)
        given = {f.index: partial(getattr, f, "strain") if isinstance(f, LazyFrame)
                 else f.strain for f in data}
        units = data.units if units is None else units
    else:
        pairs, info = _as_results(data)
        given = {}
    pairs.sort(key=lambda kr: kr[0])
    ks = [k for k, _ in pairs]
    if len(set(ks)) != len(ks):
        raise ValueError(f"two results share a frame number ({ks}); give each result a "
                         "distinct meta['frame']")
    if isinstance(units, dict):
        units = Units.from_dict(units)
    if units is None:
        units = Units.from_meta(_result_of(pairs[0][1]).meta) or Units()
    if not isinstance(units, Units):
        raise TypeError("units must be a Units object or a dictionary of its fields")
    if isinstance(strain, (list, tuple)) and len(strain) != len(pairs):
        raise ValueError(f"{len(strain)} strain results for {len(pairs)} frames")
    all_frames = [Frame(k, r) if isinstance(r, DICResult) else LazyFrame(k, r)
                  for k, r in pairs]
    for a, b in zip(all_frames, all_frames[1:]):
        b.prev = a
    keep = all_frames
    if frames is not None:
        want = [int(k) for k in frames]
        missing = [k for k in want if k not in ks]
        if missing:
            raise ValueError(f"frame(s) {missing} not in the result; available: {ks}")
        keep = [f for f in all_frames if f.index in want]
    need = set(id(f) for f in keep)
    if units.has_time:  # strain rates need the previous frame's strain too
        need |= {id(f.prev) for f in keep if f.prev is not None}
    if strain is not None and strain is not False:
        _attach_strain(all_frames, need, strain, given)
    first = keep[0].result
    s = next((f.strain for f in keep if f.strain is not None), None)
    info = {**info, "params": first.params, "image_shape": tuple(first.image_shape),
            "strain": None if s is None else {"measure": s.measure, "method": s.method,
                                              "window": s.window, "vsg_px": s.vsg},
            "frames_all": ks}
    return FrameSet(keep, units, info), units, info


def _attach_strain(all_frames: list[Frame], need: set, strain, given: dict) -> None:
    """The strain of every frame: the one ``given`` (a value, or a function
    for a lazy frame), else computed for the frames in ``need`` -- at once
    for results in memory, when used for a :class:`LazyFrame`."""
    shared: OrderedDict = OrderedDict()
    for i, f in enumerate(all_frames):
        g = given.get(f.index)
        if isinstance(f, LazyFrame):
            f._given = g if callable(g) else None
            if g is not None and not callable(g):
                f.strain = g
            f._compute = partial(_strain_for, strain=strain, i=i) if id(f) in need else None
            f._strains = shared
            continue
        f.strain = g() if callable(g) else g
        if id(f) in need and f.strain is None:
            f.strain = _strain_for(f.result, strain, i)


class FrameSet(list):
    """Frames returned by :func:`collect_frames`, with their ``units`` and
    ``info``; passing it to an export reuses the strain already computed."""

    def __init__(self, frames=(), units: Units | None = None, info: dict | None = None):
        super().__init__(frames)
        self.units = units
        self.info = info or {}


#: fields of every element of the ``frames`` struct array that load_mat needs
_MAT_NODE_FIELDS = ("x_px", "y_px", "u_px", "v_px", "dudx", "dudy", "dvdx", "dvdy", "valid",
                    "zncc", "reason", "iterations", "grid_ix", "grid_iy")
_MAT_FIELDS = _MAT_NODE_FIELDS + ("grid_xs", "grid_ys", "u_local", "v_local", "elements",
                                  "hanging", "meta_json")


def _check_mat(d: dict, path: Path) -> None:
    """Refuse a napari-aldic .mat that lacks what :func:`load_mat` reads."""
    missing = [k for k in ("params_json", "image_shape", "frames") if k not in d]
    if missing:
        raise ValueError(f"{path} has no {', '.join(repr(k) for k in missing)} variable(s): "
                         "not a complete napari-aldic .mat export")
    if np.ravel(d["image_shape"]).size != 2:
        raise ValueError(f"{path}: image_shape must hold two numbers (rows, cols)")
    st = d["frames"]
    names = st.dtype.names or ()
    if not names or st.ndim != 2 or st.shape[0] != 1 or st.size == 0:
        raise ValueError(f"{path}: 'frames' is not a 1 x F struct array of frames")
    for j in range(st.shape[1]):
        lost = [k for k in _MAT_FIELDS if k not in names]
        if lost:
            raise ValueError(f"{path}: frames({j + 1}) has no field {lost[0]!r}"
                             + (f" (nor {lost[1:]})" if len(lost) > 1 else ""))
        el = st[0, j]
        sizes = {k: np.size(el[k]) for k in _MAT_NODE_FIELDS}
        if len(set(sizes.values())) != 1:
            raise ValueError(f"{path}: the per-node fields of frames({j + 1}) differ in length "
                             f"({sizes}); the file is damaged or edited")


def load_mat(path) -> list[DICResult]:
    """Rebuild the results stored in a ``.mat`` written by :func:`export_mat`
    (every ``DICResult`` field, in pixels, exactly as saved)."""
    import scipy.io as sio

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no MATLAB file at {path}")
    try:
        d = sio.loadmat(path, squeeze_me=False, struct_as_record=True)
    except Exception as exc:  # scipy raises several types for a file it cannot parse
        raise ValueError(f"cannot read {path}: not a MATLAB file, or damaged ({exc})") from None
    fmt = d.get("format")
    if fmt is None or np.size(fmt) == 0 or str(np.ravel(fmt)[0]) != MAT_FORMAT:
        raise ValueError(f"{path} is not a napari-aldic .mat export")
    _check_mat(d, path)
    try:
        params = DICParams.from_dict(parse_json(str(np.ravel(d["params_json"])[0]),
                                                f"{path}: params_json"))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cannot read {path}: its params_json is invalid ({exc})") from None
    shape = tuple(int(s) for s in np.ravel(d["image_shape"]))
    roi = d["roi"].astype(bool) if "roi" in d else None
    st = d["frames"]
    out = []

    def vec(el, k, dtype=float):
        return np.asarray(el[k], dtype).reshape(-1)

    for j in range(st.shape[1]):
        el = st[0, j]
        elements = np.asarray(el["elements"], np.int64).reshape(-1, 4)
        hanging = np.asarray(el["hanging"], np.int64).reshape(-1, 3)
        ul = vec(el, "u_local")
        vl = vec(el, "v_local")
        meta = parse_json(str(np.ravel(el["meta_json"])[0]), f"{path}: frames({j + 1}).meta_json")
        problem = check_invariants({k: vec(el, k) for k in ("valid", "reason", "dudx", "dudy",
                                                            "dvdx", "dvdy", "zncc")}
                                   | {"u": vec(el, "u_px"), "v": vec(el, "v_px")})
        if problem:
            raise ValueError(f"cannot read {path}: frames({j + 1}): {problem}")
        out.append(DICResult(
            x=vec(el, "x_px"), y=vec(el, "y_px"), u=vec(el, "u_px"), v=vec(el, "v_px"),
            dudx=vec(el, "dudx"), dudy=vec(el, "dudy"), dvdx=vec(el, "dvdx"),
            dvdy=vec(el, "dvdy"), valid=vec(el, "valid", np.uint8).astype(bool),
            zncc=vec(el, "zncc"), reason=vec(el, "reason", np.int8),
            iterations=vec(el, "iterations", np.int32), grid_ix=vec(el, "grid_ix", np.int64),
            grid_iy=vec(el, "grid_iy", np.int64), grid_xs=vec(el, "grid_xs", np.int64),
            grid_ys=vec(el, "grid_ys", np.int64), image_shape=shape, params=params, meta=meta,
            u_local=ul if ul.size else None, v_local=vl if vl.size else None,
            elements=elements if elements.size else None,
            hanging=hanging if hanging.size else None, roi=roi))
    return out


