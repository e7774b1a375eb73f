"""Loading results for exports: result files, .mat files, run folders, frame sets."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.params import DICParams
from ..core.results import DICResult, SequenceResult, load_result
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


def _frame_of(res: DICResult, default: int) -> int:
    meta = res.meta or {}
    for k in (meta.get("frame"), (meta.get("inputs") or {}).get("frame")):
        if isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            return int(k)
    return default


def load_run(folder):
    """Read the results of a run folder as a ``SequenceResult``.

    ``folder`` is a run folder of ``track`` or ``napari-aldic run``
    (``sequence.json`` and ``frame_#####.npz``; the frames share the
    folder's one ROI array) or a folder of result ``.npz`` files (e.g. the
    ``frame###.npz`` of older ``napari-aldic run`` versions). Frames are
    ordered by their frame number (stored in each result, else the digits of
    the file name). Frames not on disk (not computed yet) are ``None``.
    """
    folder = Path(os.fspath(folder)).expanduser()
    if not folder.is_dir():
        raise FileNotFoundError(f"no run folder at {folder}")
    manifest = folder / "sequence.json"
    if manifest.exists():
        try:
            info = json.loads(manifest.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"cannot read {manifest}: {exc}") from None
        idx = [int(k) for k in info.get("frames") or []]
        frames = []
        for k in idx:
            p = folder / f"frame_{k:05d}.npz"
            frames.append(load_result(p) if p.exists() else None)
        if not any(f is not None for f in frames):
            raise ValueError(f"{folder} holds no frame results yet (frame_#####.npz)")
        params = DICParams.from_dict(info["params"]) if info.get("params") else \
            next(f for f in frames if f is not None).params
        meta = {"frames": idx, "source": info.get("source"),
                "update_every": info.get("update_every"), "folder": str(folder)}
        return SequenceResult(frames, params, info.get("reference", "accumulative"), meta)
    files = sorted(folder.glob("*.npz"), key=lambda p: natural_key(p.name))
    if not files:
        raise FileNotFoundError(f"{folder} holds no result files (.npz) and no sequence.json")
    found = {}
    for pos, p in enumerate(files):
        res = load_result(p)
        digits = re.findall(r"\d+", p.stem)
        k = _frame_of(res, int(digits[-1]) if digits else pos + 1)
        if k in found:
            raise ValueError(f"{folder}: two result files for frame {k} ({found[k][0].name}, "
                             f"{p.name}); keep one run per folder")
        found[k] = (p, res)
    idx = sorted(found)
    if idx[0] != 0:
        idx = [0] + idx
    frames = [found[k][1] if k in found else None for k in idx]
    first = next(f for f in frames if f is not None)
    meta = {"frames": idx, "source": str(folder), "folder": str(folder)}
    return SequenceResult(frames, first.params, "accumulative", meta)


def _as_results(data) -> tuple[list[tuple[int, DICResult]], dict]:
    """(frame number, result) pairs and info about the source."""
    if isinstance(data, (str, os.PathLike)):
        p = Path(os.fspath(data)).expanduser()
        if p.is_dir():
            return _as_results(load_run(p))
        if not p.exists():
            raise FileNotFoundError(f"no result file or run folder at {p}")
        if p.suffix.lower() == ".mat":
            return _as_results(load_mat(p))
        res = load_result(p)
        return [(_frame_of(res, 1), res)], {"source": str(p)}
    if isinstance(data, DICResult):
        return [(_frame_of(data, 1), data)], {}
    if isinstance(data, Frame):
        return [(data.index, data.result)], {}
    if hasattr(data, "frames") and hasattr(data, "params"):  # SequenceResult
        meta = getattr(data, "meta", {}) or {}
        idx = meta.get("frames")
        if not idx or len(idx) != len(data.frames):
            idx = list(range(len(data.frames)))
        pairs = [(int(k), r) for k, r in zip(idx, data.frames) if r is not None]
        info = {"source": meta.get("source"), "folder": meta.get("folder"),
                "reference": getattr(data, "reference", None)}
        if not pairs:
            raise ValueError("the sequence holds no computed frame")
        return pairs, info
    if isinstance(data, (list, tuple)):
        pairs = []
        for pos, item in enumerate(data):
            if item is None:
                continue
            if isinstance(item, Frame):
                pairs.append((item.index, item.result))
            elif isinstance(item, (str, os.PathLike)):
                res = load_result(item)
                pairs.append((_frame_of(res, pos), res))
            elif isinstance(item, DICResult):
                pairs.append((_frame_of(item, pos), item))
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
    """
    if isinstance(data, FrameSet):  # already collected: keep the strain computed
        pairs = [(f.index, f.result) for f in data]
        info = dict(data.info)
        given = {f.index: f.strain for f in data}
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
        units = Units.from_meta(pairs[0][1].meta) or Units()
    if not isinstance(units, Units):
        raise TypeError("units must be a Units object or a dictionary of its fields")
    if isinstance(strain, (list, tuple)) and len(strain) != len(pairs):
        raise ValueError(f"{len(strain)} strain results for {len(pairs)} frames")
    all_frames = [Frame(k, r) for k, r in pairs]
    for a, b in zip(all_frames, all_frames[1:]):
        b.prev = a
    if strain is not None and strain is not False:
        for f in all_frames:
            f.strain = given.get(f.index)
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
        for i, f in enumerate(all_frames):
            if id(f) in need and f.strain is None:
                f.strain = _strain_for(f.result, strain, i)
    first = keep[0].result
    s = next((f.strain for f in keep if f.strain is not None), None)
    info = {**info, "params": first.params, "image_shape": tuple(first.image_shape),
            "strain": None if s is None else {"measure": s.measure, "method": s.method,
                                              "window": s.window, "vsg_px": s.vsg},
            "frames_all": ks}
    return FrameSet(keep, units, info), units, info


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
        params = DICParams.from_dict(json.loads(str(np.ravel(d["params_json"])[0])))
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
        meta = json.loads(str(np.ravel(el["meta_json"])[0]))
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


