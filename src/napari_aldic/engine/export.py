"""Exports of DIC results: MATLAB, CSV, VTK (.vtu), DaVis-style text, images, video.

Every function takes a result in any of these forms (``data``):

* one :class:`~napari_aldic.engine.results.DICResult` (an image pair);
* a :class:`~napari_aldic.engine.sequence.SequenceResult` from ``track``, or a
  list of ``DICResult`` (``None`` entries, frames not computed, are skipped);
* a path: a result ``.npz``, a ``.mat`` written by :func:`export_mat`, or a
  run folder (``sequence.json`` + ``frame_#####.npz`` written by
  ``track(out_dir=...)``, or the ``frame###.npz`` files of ``napari-aldic run``).

Units (:class:`~napari_aldic.engine.units.Units`: pixel size with its unit,
frame interval with its unit) are applied the same way by every export; see
``docs/exports.md`` for every file layout, field name and unit.

Every file is written under a temporary name in the target folder and renamed
when complete, so an interrupted or failed export (full disk, no permission)
never leaves a half-written file under the final name; such failures raise
:class:`ExportError` naming the file and what to do.
"""

from __future__ import annotations

import base64
import errno
import json
import os
import re
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from .params import DICParams
from .reasons import Reason
from .results import DICResult, load_result
from .units import Units

__all__ = [
    "ExportError",
    "EncoderNotFoundError",
    "Frame",
    "FrameSet",
    "collect_frames",
    "frame_columns",
    "load_run",
    "atomic_write",
    "export_result",
    "export_mat",
    "load_mat",
    "export_csv",
    "read_csv",
    "export_vtu",
    "read_vtu",
    "export_davis",
    "export_png",
    "export_gif",
    "export_mp4",
    "field_figure",
    "save_params",
    "load_params",
    "load_settings",
    "FIELDS",
    "STRAIN_DEFAULTS",
]

MAT_FORMAT = "napari-aldic-mat"
MAT_FORMAT_VERSION = 1
SETTINGS_FORMAT = "napari-aldic-settings"
#: strain settings used when an export computes strain itself (``strain=True``)
STRAIN_DEFAULTS = {"window": 5, "method": "plane_fit", "measure": "green_lagrange"}
_STRAIN_NAMES = ("exx", "eyy", "exy", "e1", "e2", "max_shear", "von_mises", "rotation")
_RATE_NAMES = ("exx", "eyy", "exy")


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


def _explain(exc: OSError, path: Path) -> ExportError:
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


def _target(path, suffixes: Sequence[str]) -> Path:
    """The output path (``suffixes[0]`` appended when the name has none of
    them), after checking that its folder exists and is writable."""
    path = Path(os.fspath(path)).expanduser()
    if path.suffix.lower() not in suffixes:
        path = path.with_name(path.name + suffixes[0])
    _check_folder(path)
    return path


def _check_folder(path: Path) -> None:
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
    _check_folder(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    except OSError as exc:
        raise _explain(exc, path) from None
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
        raise _explain(exc, path) from exc
    except BaseException:
        _remove(tmp)
        raise


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
    prev: "Frame | None" = None


def _frame_of(res: DICResult, default: int) -> int:
    meta = res.meta or {}
    for k in (meta.get("frame"), (meta.get("inputs") or {}).get("frame")):
        if isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            return int(k)
    return default


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def load_run(folder):
    """Read the results of a run folder as a ``SequenceResult``.

    ``folder`` is an ``out_dir`` of ``track`` (``sequence.json`` and
    ``frame_#####.npz``) or a folder of result ``.npz`` files (e.g. the
    ``frame###.npz`` of ``napari-aldic run``). Frames are ordered by their
    frame number (stored in each result, else the digits of the file name).
    Frames not on disk, such as the reference frame 0 that ``track`` does
    not write, are ``None``.
    """
    from .sequence import SequenceResult

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
    files = sorted(folder.glob("*.npz"), key=lambda p: _natural_key(p.name))
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
        info = {"source": meta.get("source"), "reference": getattr(data, "reference", None)}
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
    from .strain import StrainResult, compute_strain

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
        ``True`` computes strain with :data:`STRAIN_DEFAULTS`; a dict
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


# =================================================================== columns
#: field name -> (title, kind); kind picks the unit: length, velocity, rate, strain, ...
FIELDS: dict[str, tuple[str, str]] = {
    "u": ("u (x displacement)", "length"),
    "v": ("v (y displacement)", "length"),
    "magnitude": ("|u| (displacement magnitude)", "length"),
    "vx": ("x velocity", "velocity"),
    "vy": ("y velocity", "velocity"),
    "exx": ("strain exx", "strain"),
    "eyy": ("strain eyy", "strain"),
    "exy": ("strain exy (tensor shear)", "strain"),
    "e1": ("major principal strain e1", "strain"),
    "e2": ("minor principal strain e2", "strain"),
    "max_shear": ("maximum shear strain", "strain"),
    "von_mises": ("equivalent (von Mises) strain", "strain"),
    "rotation": ("rotation", "angle"),
    "exx_rate": ("strain rate d(exx)/dt", "rate"),
    "eyy_rate": ("strain rate d(eyy)/dt", "rate"),
    "exy_rate": ("strain rate d(exy)/dt", "rate"),
    "zncc": ("ZNCC (correlation quality)", "none"),
}


def _unit_of(kind: str, units: Units) -> str:
    return {"length": units.unit, "velocity": units.velocity_unit, "rate": units.rate_unit,
            "angle": "rad", "px": "px", "time": units.time_unit}.get(kind, "")


def _same_nodes(a: DICResult, b: DICResult) -> bool:
    return a.x.shape == b.x.shape and np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)


def frame_columns(fr: Frame, units: Units) -> dict[str, tuple[np.ndarray, str]]:
    """Per-node columns of one frame: ``name -> (values, unit)``.

    Lengths are in ``units.unit`` (``x_px``/``y_px`` stay in pixels);
    velocities and strain rates appear only with a frame interval; they are
    backward differences to the previous frame (frame 0 = zero field), NaN
    at frame 0 and where the previous frame has other nodes.
    """
    res, ps = fr.result, units.pixel_size
    n = len(res)
    L = units.unit
    cols: dict[str, tuple[np.ndarray, str]] = {
        "node": (np.arange(n), ""),
        "x_px": (np.asarray(res.x, float), "px"),
        "y_px": (np.asarray(res.y, float), "px"),
        "x": (res.x * ps, L),
        "y": (res.y * ps, L),
        "u": (res.u * ps, L),
        "v": (res.v * ps, L),
        "magnitude": (np.hypot(res.u, res.v) * ps, L),
    }
    dt_frames = None
    prev_u = prev_v = None
    prev_strain = None
    if units.has_time:
        p = fr.prev
        if fr.index > 0 and (p is None or _same_nodes(p.result, res)):
            dt_frames = fr.index - (0 if p is None else p.index)
            if p is None:
                prev_u = prev_v = np.zeros(n)
            else:
                prev_u, prev_v = p.result.u, p.result.v
                prev_strain = p.strain
        dt = None if dt_frames is None else dt_frames * units.frame_interval
        if dt is None:
            vx = vy = np.full(n, np.nan)
        else:
            vx, vy = (res.u - prev_u) * ps / dt, (res.v - prev_v) * ps / dt
        cols["vx"] = (vx, units.velocity_unit)
        cols["vy"] = (vy, units.velocity_unit)
    s = fr.strain
    if s is not None:
        for name in _STRAIN_NAMES:
            cols[name] = (np.asarray(getattr(s, name), float), "rad" if name == "rotation" else "")
        if units.has_time:
            for name in _RATE_NAMES:
                if dt_frames is None:
                    rate = np.full(n, np.nan)
                else:
                    if fr.prev is None:
                        before = np.zeros(n)
                    elif prev_strain is not None:
                        before = np.asarray(getattr(prev_strain, name), float)
                    else:
                        before = np.full(n, np.nan)
                    rate = (getattr(s, name) - before) / (dt_frames * units.frame_interval)
                cols[f"{name}_rate"] = (rate, units.rate_unit)
        cols["strain_valid"] = (np.asarray(s.valid, bool), "")
    cols["valid"] = (np.asarray(res.valid, bool), "")
    cols["reason"] = (np.asarray(res.reason, np.int64), "")
    cols["zncc"] = (np.asarray(res.zncc, float), "")
    return cols


def _reason_lines() -> list[str]:
    return [f"{int(r)}={Reason.describe(int(r))}" for r in Reason]


def _software() -> str:
    from .. import __version__

    return f"napari-aldic {__version__}"


# =================================================================== CSV
def export_csv(data, path, *, units=None, strain=True, frames=None) -> Path:
    """Write one row per node per frame to a CSV file.

    Columns: ``frame``, ``time [time_unit]`` (with a frame interval),
    ``node``, ``x_px [px]``, ``y_px [px]``, ``x``, ``y``, ``u``, ``v``,
    ``magnitude`` (all ``[unit]``), ``vx``, ``vy`` (``[unit/time_unit]``, with
    a frame interval), ``exx``, ``eyy``, ``exy``, ``e1``, ``e2``,
    ``max_shear``, ``von_mises``, ``rotation [rad]`` (with strain),
    ``exx_rate``, ``eyy_rate``, ``exy_rate`` (``[1/time_unit]``), then
    ``strain_valid``, ``valid``, ``reason``, ``zncc``. Header lines start with
    ``#``: software, source, units (one JSON line), strain settings and the
    reason codes. Read it back with :func:`read_csv`.
    """
    path = _target(path, (".csv", ".txt"))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    with atomic_write(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        first = frame_columns(fr_list[0], units)
        names = ["frame"] + (["time"] if units.has_time else []) + list(first)
        unit_map = {"frame": ""}
        if units.has_time:
            unit_map["time"] = units.time_unit
        unit_map.update({k: u for k, (_, u) in first.items()})
        fh.write(f"# {_software()} result export (CSV): one row per node per frame\n")
        if info.get("source"):
            fh.write(f"# source: {info['source']}\n")
        fh.write(f"# settings: {json.dumps(units.to_dict())}\n")
        fh.write(f"# units: {json.dumps(unit_map, ensure_ascii=False)}\n")
        if info["strain"]:
            s = info["strain"]
            fh.write(f"# strain: {s['measure']} by {s['method']}, window {s['window']} nodes, "
                     f"VSG {s['vsg_px']:g} px; dimensionless (exy is the tensor shear)\n")
        fh.write(f"# image_shape: {list(info['image_shape'])}; coordinates: x = column, "
                 "y = row (downwards), pixel centres at integers\n")
        fh.write("# reason codes: " + "; ".join(_reason_lines()) + "\n")
        header = [f"{k} [{unit_map[k]}]" if unit_map[k] else k for k in names]
        fh.write(",".join(header) + "\n")
        for fr in fr_list:
            cols = frame_columns(fr, units)
            if list(cols) != list(first):
                raise ValueError("frames differ in their columns (strain computed for some "
                                 "only); export them separately")
            n = len(fr.result)
            block = [np.full(n, fr.index, float)]
            if units.has_time:
                block.append(np.full(n, units.time(fr.index), float))
            block += [np.asarray(v, float) for v, _ in cols.values()]
            fmt = ["%d"] + (["%.10g"] if units.has_time else []) + [
                "%d" if k in ("node", "valid", "reason", "strain_valid") else "%.10g"
                for k in cols]
            np.savetxt(fh, np.column_stack(block), fmt=fmt, delimiter=",")
    return path


def read_csv(path) -> dict[str, Any]:
    """Read a CSV written by :func:`export_csv`.

    Returns ``{"columns": {name: array}, "units": {name: unit},
    "settings": Units, "header": {key: text}}``; column names are given
    without their ``[unit]`` suffix.
    """
    path = Path(path)
    header: dict[str, str] = {}
    with open(path, encoding="utf-8") as fh:
        line = fh.readline()
        while line.startswith("#"):
            body = line[1:].strip()
            if ":" in body:
                key, _, val = body.partition(":")
                header[key.strip()] = val.strip()
            line = fh.readline()
        names_raw = line.rstrip("\n").split(",")
        data = np.loadtxt(fh, delimiter=",", ndmin=2)
    names, units = [], {}
    for raw in names_raw:
        m = re.fullmatch(r"\s*(.+?)\s*(?:\[(.*)\])?\s*", raw)
        name, unit = m.group(1), m.group(2) or ""
        names.append(name)
        units[name] = unit
    if "units" in header:
        units.update(json.loads(header["units"]))
    cols = {}
    for i, name in enumerate(names):
        col = data[:, i] if data.size else np.empty(0)
        if name in ("frame", "node", "reason"):
            col = col.astype(np.int64)
        elif name in ("valid", "strain_valid"):
            col = col.astype(bool)
        cols[name] = col
    settings = Units.from_dict(json.loads(header["settings"])) if "settings" in header \
        else Units()
    return {"columns": cols, "units": units, "settings": settings, "header": header}


# =================================================================== MATLAB
_MAT_RESULT_FIELDS = ("x_px", "y_px", "u_px", "v_px", "dudx", "dudy", "dvdx", "dvdy", "valid",
                      "zncc", "reason", "iterations", "grid_ix", "grid_iy")


def _mat_frame(fr: Frame, units: Units) -> dict[str, Any]:
    res = fr.result
    cols = frame_columns(fr, units)
    d: dict[str, Any] = {
        "frame": int(fr.index),
        "time": float(units.time(fr.index)) if units.has_time else np.nan,
        "x_px": np.asarray(res.x, float), "y_px": np.asarray(res.y, float),
        "u_px": np.asarray(res.u, float), "v_px": np.asarray(res.v, float),
    }
    for k in ("x", "y", "u", "v", "magnitude"):
        d[k] = cols[k][0]
    for k in ("vx", "vy"):
        d[k] = cols[k][0] if k in cols else np.empty((0, 1))
    for k in ("dudx", "dudy", "dvdx", "dvdy", "zncc"):
        d[k] = np.asarray(getattr(res, k), float)
    d["valid"] = np.asarray(res.valid, np.uint8)
    d["reason"] = np.asarray(res.reason, np.int8)
    d["iterations"] = np.asarray(res.iterations, np.int32)
    d["grid_ix"] = np.asarray(res.grid_ix, np.int64)
    d["grid_iy"] = np.asarray(res.grid_iy, np.int64)
    d["grid_xs"] = np.asarray(res.grid_xs, np.int64)
    d["grid_ys"] = np.asarray(res.grid_ys, np.int64)
    for k in _STRAIN_NAMES + tuple(f"{n}_rate" for n in _RATE_NAMES) + ("strain_valid",):
        if k in cols:
            v = cols[k][0]
            d[k] = v.astype(np.uint8) if v.dtype == bool else v
        else:
            d[k] = np.empty((0, 1))
    for k in ("u_local", "v_local"):
        v = getattr(res, k)
        d[k] = np.empty((0, 1)) if v is None else np.asarray(v, float)
    el = res.elements
    d["elements"] = np.empty((0, 4), np.int64) if el is None else np.asarray(el, np.int64)
    d["faces"] = d["elements"] + 1  # 1-based, for MATLAB's patch()
    hg = res.hanging
    d["hanging"] = np.empty((0, 3), np.int64) if hg is None else np.asarray(hg, np.int64)
    d["meta_json"] = json.dumps(res.meta, default=str)
    return d


def export_mat(data, path, *, units=None, strain=True, frames=None) -> Path:
    """Write a MATLAB ``.mat`` file (v5, compressed) readable by ``load`` and
    ``scipy.io.loadmat``.

    Top-level variables: ``format``, ``format_version``, ``software``,
    ``pixel_size``, ``unit``, ``frame_interval`` (NaN if unknown),
    ``time_unit``, ``frame`` (1 x F), ``time`` (1 x F), ``image_shape``,
    ``params_json`` and ``params`` (struct), ``strain_settings`` (struct),
    ``reason_codes`` (cell), ``roi`` (uint8, rows x cols, when stored), and
    ``frames``: a 1 x F struct array, one element per frame, with the fields
    listed in ``docs/exports.md``. When every frame has the same nodes, the
    per-node fields are also stacked as F x N matrices at top level
    (``u``, ``v``, ``exx``, ... with ``x``, ``y`` as N x 1). Indices
    (``grid_ix``, ``elements``, ``hanging``) are 0-based; ``faces`` is
    ``elements + 1`` for MATLAB. Read it back with :func:`load_mat`.
    """
    import scipy.io as sio

    path = _target(path, (".mat",))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    per = [_mat_frame(fr, units) for fr in fr_list]
    names = list(per[0])
    st = np.empty((1, len(per)), dtype=[(k, object) for k in names])
    for j, d in enumerate(per):
        st[0, j] = tuple(d[k] for k in names)
    params = info["params"]
    out: dict[str, Any] = {
        "format": MAT_FORMAT,
        "format_version": MAT_FORMAT_VERSION,
        "software": _software(),
        "pixel_size": units.pixel_size,
        "unit": units.unit,
        "frame_interval": np.nan if units.frame_interval is None else units.frame_interval,
        "time_unit": units.time_unit,
        "frame": np.array([[fr.index for fr in fr_list]], float),
        "time": np.array([[units.time(fr.index) if units.has_time else np.nan
                           for fr in fr_list]], float),
        "image_shape": np.array([list(info["image_shape"])], float),
        "params_json": json.dumps(params.to_dict()),
        "params": {k: (np.nan if v is None else (np.array(v, float) if k == "seeds" else v))
                   for k, v in params.to_dict().items()},
        "strain_settings": info["strain"] or {},
        "reason_codes": np.array([f"{int(r)}: {Reason.describe(int(r))}" for r in Reason],
                                 dtype=object),
        "source": info.get("source") or "",
        "frames": st,
    }
    roi = fr_list[0].result.roi
    if roi is not None:
        out["roi"] = np.asarray(roi, np.uint8)
    if all(_same_nodes(fr.result, fr_list[0].result) for fr in fr_list):
        out["x"] = per[0]["x"]
        out["y"] = per[0]["y"]
        out["x_px"] = per[0]["x_px"]
        out["y_px"] = per[0]["y_px"]
        for k in names:
            v = per[0][k]
            if k in ("x", "y", "x_px", "y_px") or not isinstance(v, np.ndarray) or \
                    v.ndim != 1 or v.shape[0] != len(fr_list[0].result) or k in ("grid_ix",
                                                                                 "grid_iy"):
                continue
            out[k] = np.stack([d[k] for d in per])
    with atomic_write(path) as tmp, open(tmp, "wb") as fh:
        sio.savemat(fh, out, do_compression=True, oned_as="column")
    return path


def load_mat(path) -> list[DICResult]:
    """Rebuild the results stored in a ``.mat`` written by :func:`export_mat`
    (every ``DICResult`` field, in pixels, exactly as saved)."""
    import scipy.io as sio

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no MATLAB file at {path}")
    d = sio.loadmat(path, squeeze_me=False, struct_as_record=True)
    fmt = d.get("format")
    if fmt is None or str(np.ravel(fmt)[0]) != MAT_FORMAT:
        raise ValueError(f"{path} is not a napari-aldic .mat export")
    params = DICParams.from_dict(json.loads(str(np.ravel(d["params_json"])[0])))
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


# =================================================================== VTK
def result_cells(res: DICResult) -> np.ndarray:
    """Q4 cells (E, 4) of a result, corner order (x0,y0) (x1,y0) (x1,y1) (x0,y1).

    The result's own mesh (``res.elements``, AL-DIC and quadtree) when it has
    one, else one cell per lattice square whose four nodes exist and whose
    rectangle lies inside the ROI (cells never bridge holes or cracks).
    """
    if res.elements is not None and len(res.elements):
        return np.asarray(res.elements, np.int64)
    from .global_solve import uniform_mesh
    from .mesh import NodeGrid

    on = np.asarray(res.grid_ix) >= 0
    if not on.all():  # off-lattice nodes without elements: no mesh to draw
        return np.empty((0, 4), np.int64)
    grid = NodeGrid(res.x.astype(np.int64), res.y.astype(np.int64), res.grid_ix, res.grid_iy,
                    res.grid_xs, res.grid_ys)
    roi = res.roi if res.roi is not None else np.ones(res.image_shape, bool)
    return np.asarray(uniform_mesh(grid, np.asarray(roi, bool)).elements, np.int64)


_VTK_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.float32): "Float32",
              np.dtype(np.int64): "Int64", np.dtype(np.int32): "Int32",
              np.dtype(np.int8): "Int8", np.dtype(np.uint8): "UInt8"}


def _vtk_array(name: str | None, arr: np.ndarray, encoding: str, ncomp: int = 1,
               indent: str = "        ", nan_value: float | None = None) -> str:
    arr = np.ascontiguousarray(arr)
    if arr.dtype == bool:
        arr = arr.astype(np.uint8)
    if arr.dtype not in _VTK_TYPES:
        arr = arr.astype(np.float64)
    typ = _VTK_TYPES[arr.dtype]
    attrs = f'type="{typ}"' + (f' Name="{name}"' if name else "")
    if ncomp > 1:
        attrs += f' NumberOfComponents="{ncomp}"'
    if encoding == "ascii" and arr.dtype.kind == "f" and not np.isfinite(arr).all():
        # VTK's ASCII parser cannot read NaN: substitute, or keep this array exact in base64
        if nan_value is None:
            encoding = "binary"
        else:
            arr = np.where(np.isfinite(arr), arr, float(nan_value))
    if encoding == "ascii":
        flat = arr.ravel()
        if arr.dtype.kind == "f":
            body = " ".join(repr(float(v)) for v in flat)
        else:
            body = " ".join(str(int(v)) for v in flat)
        return f'{indent}<DataArray {attrs} format="ascii">{body}</DataArray>\n'
    raw = arr.astype(arr.dtype.newbyteorder("<"), copy=False).tobytes()
    head = np.uint32(len(raw)).astype("<u4").tobytes()
    body = base64.b64encode(head).decode() + base64.b64encode(raw).decode()
    return f'{indent}<DataArray {attrs} format="binary">{body}</DataArray>\n'


def _vtu_text(fr: Frame, units: Units, encoding: str, info: dict,
              nan_value: float | None = None) -> str:
    res = fr.result
    cols = frame_columns(fr, units)
    n = len(res)
    cells = result_cells(res)
    pts = np.column_stack([cols["x"][0], cols["y"][0], np.zeros(n)])
    disp = np.column_stack([cols["u"][0], cols["v"][0], np.zeros(n)])
    unit_note = (f"napari-aldic VTU export ({_software()}), frame {fr.index}. Coordinates and "
                 f"displacement in {units.unit} (pixel size {units.pixel_size:g} {units.unit}); "
                 "x = image column, y = image row (downwards), z = 0. Strains dimensionless, "
                 "rotation in rad")
    if units.has_time:
        unit_note += (f"; velocity in {units.velocity_unit}, strain rates in "
                      f"{units.rate_unit}, time in {units.time_unit}")
    out = ['<?xml version="1.0"?>\n', f"<!-- {unit_note}. -->\n",
           '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
           'header_type="UInt32">\n', "  <UnstructuredGrid>\n", "    <FieldData>\n"]
    field = [("frame", np.array([fr.index], np.int64)),
             ("pixel_size", np.array([units.pixel_size]))]
    if units.has_time:
        field.append(("TimeValue", np.array([units.time(fr.index)], float)))
    for name, arr in field:
        out.append(_vtk_array(name, arr, encoding, indent="      ").replace(
            "<DataArray ", '<DataArray NumberOfTuples="1" ', 1))
    out.append("    </FieldData>\n")
    out.append(f'    <Piece NumberOfPoints="{n}" NumberOfCells="{len(cells)}">\n')
    out.append('      <PointData Scalars="u" Vectors="displacement">\n')
    out.append(_vtk_array("displacement", disp, encoding, 3, nan_value=nan_value))
    if "vx" in cols:
        out.append(_vtk_array("velocity", np.column_stack([cols["vx"][0], cols["vy"][0],
                                                           np.zeros(n)]), encoding, 3,
                              nan_value=nan_value))
    skip = {"node", "x", "y", "x_px", "y_px"}
    for name, (vals, _) in cols.items():
        if name in skip:
            continue
        if name == "reason":
            vals = vals.astype(np.int8)
        out.append(_vtk_array(name, vals, encoding, nan_value=nan_value))
    out.append("      </PointData>\n")
    out.append("      <Points>\n")
    out.append(_vtk_array("Points", pts, encoding, 3))
    out.append("      </Points>\n      <Cells>\n")
    out.append(_vtk_array("connectivity", cells.ravel().astype(np.int64), encoding))
    out.append(_vtk_array("offsets", (4 * np.arange(1, len(cells) + 1)).astype(np.int64),
                          encoding))
    out.append(_vtk_array("types", np.full(len(cells), 9, np.uint8), encoding))  # VTK_QUAD
    out.append("      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n")
    return "".join(out)


def _frame_path(path: Path, k: int) -> Path:
    return path.with_name(f"{path.stem}_frame{k:05d}{path.suffix}")


def export_vtu(data, path, *, units=None, strain=True, frames=None,
               encoding: str = "binary", nan_value: float | None = None) -> list[Path]:
    """Write VTK XML UnstructuredGrid files (``.vtu``) of Q4 cells with point data.

    One result writes ``path``. Several frames write ``STEM_frame#####.vtu``
    per frame and a ParaView collection ``STEM.pvd`` (time = frame time, or
    frame number without a frame interval). Points are the nodes in the
    physical unit (z = 0); point data: ``displacement`` (3-vector),
    ``velocity`` (with a frame interval), ``u``, ``v``, ``magnitude``,
    ``vx``, ``vy``, strains and rates (when computed), ``strain_valid``,
    ``valid``, ``reason``, ``zncc``. ``encoding``: ``"binary"`` (base64,
    exact, default) or ``"ascii"``. VTK cannot parse NaN in ASCII: with
    ``"ascii"``, arrays holding NaN (untrusted nodes, no velocity at frame 0)
    stay base64 unless ``nan_value`` gives a number to write instead. Returns
    the paths written (the ``.pvd`` last).
    """
    if encoding not in ("binary", "ascii", "base64"):
        raise ValueError(f"encoding={encoding!r} must be 'binary' (base64) or 'ascii'")
    encoding = "binary" if encoding == "base64" else encoding
    path = _target(path, (".vtu",))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    written = []
    if len(fr_list) == 1:
        targets = [path]
    else:
        targets = [_frame_path(path, fr.index) for fr in fr_list]
    for fr, target in zip(fr_list, targets):
        text = _vtu_text(fr, units, encoding, info, nan_value)
        with atomic_write(target) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        written.append(target)
    if len(fr_list) > 1:
        pvd = path.with_suffix(".pvd")
        lines = ['<?xml version="1.0"?>\n',
                 '<VTKFile type="Collection" version="1.0" byte_order="LittleEndian">\n',
                 "  <Collection>\n"]
        for fr, target in zip(fr_list, targets):
            t = units.time(fr.index) if units.has_time else fr.index
            lines.append(f'    <DataSet timestep="{t!r}" group="" part="0" '
                         f'file="{target.name}"/>\n')
        lines.append("  </Collection>\n</VTKFile>\n")
        with atomic_write(pvd) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write("".join(lines))
        written.append(pvd)
    return written


def read_vtu(path) -> dict[str, Any]:
    """Parse a ``.vtu`` written by :func:`export_vtu` (ASCII or base64).

    Returns ``{"points": (n, 3), "cells": (m, 4), "types": (m,),
    "point_data": {name: array}, "field_data": {name: array}}``.
    """
    import xml.etree.ElementTree as ET

    root = ET.parse(path).getroot()
    order = "<" if root.get("byte_order", "LittleEndian") == "LittleEndian" else ">"
    dtypes = {v: np.dtype(k).newbyteorder(order) for k, v in _VTK_TYPES.items()}

    def parse(da) -> np.ndarray:
        dt = dtypes[da.get("type")]
        ncomp = int(da.get("NumberOfComponents", "1"))
        text = (da.text or "").strip()
        if da.get("format") == "ascii":
            arr = np.array([float(t) for t in text.split()], float).astype(dt)
        else:
            head_len = 8  # base64 of a 4-byte UInt32 header
            nbytes = int(np.frombuffer(base64.b64decode(text[:head_len]), "<u4")[0])
            raw = base64.b64decode(text[head_len:])
            arr = np.frombuffer(raw[:nbytes], dt)
        return arr.reshape(-1, ncomp) if ncomp > 1 else arr

    piece = root.find("UnstructuredGrid/Piece")
    pts = parse(piece.find("Points/DataArray"))
    cells = {da.get("Name"): parse(da) for da in piece.find("Cells")}
    pd = {da.get("Name"): parse(da) for da in piece.find("PointData")}
    fd_el = root.find("UnstructuredGrid/FieldData")
    fd = {} if fd_el is None else {da.get("Name"): parse(da) for da in fd_el}
    n_cells = int(piece.get("NumberOfCells"))
    conn = cells["connectivity"].reshape(n_cells, 4) if n_cells else np.empty((0, 4), int)
    return {"points": pts, "cells": conn, "types": cells["types"], "point_data": pd,
            "field_data": fd, "n_points": int(piece.get("NumberOfPoints")),
            "n_cells": n_cells}


# =================================================================== DaVis / DefDAP
def export_davis(data, path, *, frames=None) -> list[Path]:
    """Write DaVis-style 2D-vector text files, the HRDIC input DefDAP reads.

    One file per frame (``STEM_frame#####.txt`` for several frames): a first
    line ``#DaVis 8.4.0 2D-vector STEP ROWS COLS "position" "pixel" ...``
    then tab-separated ``x y u v`` rows in pixels over the full node lattice,
    rows of constant y with x increasing (the lattice order DefDAP expects);
    untrusted or missing nodes hold ``nan``. Only lattice results can be
    written (quadtree nodes off the lattice are skipped). Values stay in
    pixels: DefDAP applies its own scale.
    """
    path = _target(path, (".txt",))
    fr_list, units, info = collect_frames(data, frames=frames, strain=False)
    targets = [path] if len(fr_list) == 1 else [_frame_path(path, fr.index) for fr in fr_list]
    written = []
    for fr, target in zip(fr_list, targets):
        res = fr.result
        xs = np.asarray(res.grid_xs, float)
        ys = np.asarray(res.grid_ys, float)
        step = int(res.params.step)
        U = res.to_grid("u")
        V = res.to_grid("v")
        X, Y = np.meshgrid(xs, ys)
        table = np.column_stack([X.ravel(), Y.ravel(), U.ravel(), V.ravel()])
        head = (f'#DaVis 8.4.0 2D-vector {step} {ys.size} {xs.size} "position" "pixel" '
                '"position" "pixel" "displacement" "pixel" "displacement" "pixel"\n')
        with atomic_write(target) as tmp, open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write(head)
            np.savetxt(fh, table, fmt=["%.6f", "%.6f", "%.8g", "%.8g"], delimiter="\t")
        written.append(target)
    return written


# =================================================================== figures
def _field_label(name: str, units: Units, info: dict | None = None) -> str:
    if name not in FIELDS:
        raise ValueError(f"unknown field {name!r}; choose one of {sorted(FIELDS)}")
    title, kind = FIELDS[name]
    unit = _unit_of(kind, units)
    if kind == "strain":
        s = (info or {}).get("strain") or {}
        measure = s.get("measure", "").replace("_", "-")
        return f"{name} ({measure}, dimensionless)" if measure else f"{name} (dimensionless)"
    if kind == "rate":
        return f"{name} ({unit})"
    return f"{name} ({unit})" if unit else name


def _field_values(fr: Frame, name: str, units: Units) -> np.ndarray:
    cols = frame_columns(fr, units)
    if name not in cols:
        if FIELDS.get(name, ("", ""))[1] in ("strain", "angle", "rate") and fr.strain is None:
            raise ValueError(f"field {name!r} needs strain: export with strain=True")
        if name in ("vx", "vy") or name.endswith("_rate"):
            raise ValueError(f"field {name!r} needs a frame interval (units.frame_interval)")
        raise ValueError(f"unknown field {name!r}; choose one of {sorted(FIELDS)}")
    vals = np.asarray(cols[name][0], float).copy()
    ok = np.asarray(fr.result.valid, bool)
    if fr.strain is not None and FIELDS[name][1] in ("strain", "angle", "rate"):
        ok = ok & np.asarray(fr.strain.valid, bool)
    vals[~ok] = np.nan
    return vals


def _limits(name: str, values: list[np.ndarray], clim=None):
    """(cmap name, vmin, vmax) shared by all frames of an export."""
    kind = FIELDS[name][1]
    allv = np.concatenate([np.ravel(v) for v in values]) if values else np.empty(0)
    fin = allv[np.isfinite(allv)]
    if clim is not None:
        lo, hi = float(clim[0]), float(clim[1])
    elif fin.size:
        lo, hi = (float(np.percentile(fin, 0.5)), float(np.percentile(fin, 99.5)))
    else:
        lo, hi = 0.0, 1.0
    if name == "zncc":
        return "viridis", (min(lo, 0.99) if clim is None else lo), (1.0 if clim is None else hi)
    signed = kind in ("length", "velocity", "strain", "angle", "rate") and name not in (
        "magnitude", "von_mises", "max_shear")
    if signed and lo < 0 < hi:
        if clim is None:
            lim = max(abs(lo), abs(hi))
            lo, hi = -lim, lim
        return "RdBu_r", lo, hi
    if hi <= lo:
        span = abs(lo) * 0.01 or 1e-6
        lo, hi = lo - span, hi + span
    return "viridis", lo, hi


def _triangulation(res: DICResult, units: Units, values: np.ndarray):
    """matplotlib Triangulation of the result's Q4 cells (2 triangles each),
    triangles with an untrusted or NaN corner masked; None without cells."""
    from matplotlib.tri import Triangulation

    cells = result_cells(res)
    if cells.shape[0] == 0:
        return None
    tris = np.concatenate([cells[:, [0, 1, 2]], cells[:, [0, 2, 3]]])
    tri = Triangulation(res.x * units.pixel_size, res.y * units.pixel_size, tris)
    bad = ~np.isfinite(values)
    tri.set_mask(bad[tris].any(axis=1))
    return tri


def _draw_field(ax, fr: Frame, name: str, units: Units, cmap, vmin, vmax, image=None,
                mark_flagged: bool = True):
    """Draw one field of one frame on ``ax``; returns the colour mappable."""
    import matplotlib

    res, ps = fr.result, units.pixel_size
    rows, cols = (int(s) for s in res.image_shape)
    vals = _field_values(fr, name, units)
    ax.set_facecolor("0.88")
    if image is not None:
        ax.imshow(np.asarray(image), cmap="gray",
                  extent=(-0.5 * ps, (cols - 0.5) * ps, (rows - 0.5) * ps, -0.5 * ps),
                  interpolation="nearest")
    cm = matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap
    tri = _triangulation(res, units, vals)
    if tri is not None and not tri.mask.all():
        shown = np.where(np.isfinite(vals), vals, 0.0)
        im = ax.tripcolor(tri, shown, shading="gouraud", cmap=cm, vmin=vmin, vmax=vmax,
                          rasterized=True)
    else:
        ok = np.isfinite(vals)
        im = ax.scatter(res.x[ok] * ps, res.y[ok] * ps, c=vals[ok], cmap=cm, vmin=vmin,
                        vmax=vmax, s=12, marker="s")
        if not ok.any():
            im = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(vmin, vmax),
                                              cmap=cm)
    bad = ~np.asarray(res.valid, bool)
    if mark_flagged and bad.any():
        ax.plot(res.x[bad] * ps, res.y[bad] * ps, linestyle="none", marker="x", markersize=3,
                color="k", alpha=0.5)
    ax.set_xlim(-0.5 * ps, (cols - 0.5) * ps)
    ax.set_ylim((rows - 0.5) * ps, -0.5 * ps)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({units.unit})")
    ax.set_ylabel(f"y ({units.unit})")
    return im


def _frame_title(fr: Frame, units: Units) -> str:
    t = f"frame {fr.index}"
    if units.has_time:
        t += f", t = {units.time(fr.index):g} {units.time_unit}"
    return t


def _figsize(shape, width: float = 6.4) -> tuple[float, float]:
    rows, cols = shape
    ax_w = width - 1.8  # room for the colour bar
    ax_h = max(2.0, min(8.0, ax_w * rows / max(cols, 1)))
    return width, ax_h + 1.1


def field_figure(data, field: str = "u", *, frame: int | None = None, units=None,
                 strain=True, image=None, cmap=None, clim=None, title: str | None = None,
                 _prepared=None):
    """A matplotlib Figure of one field of one frame, with a labelled colour bar.

    ``frame`` is a frame number (default: the last). Untrusted nodes are left
    blank and marked with x. Built on ``matplotlib.figure.Figure`` (no pyplot,
    no GUI backend).
    """
    from matplotlib.figure import Figure

    if _prepared is None:
        fr_list, units, info = collect_frames(
            data, frames=None if frame is None else [frame], strain=strain, units=units)
        fr = fr_list[-1]
        cm, lo, hi = _limits(field, [_field_values(fr, field, units)], clim)
    else:
        fr, units, info, cm, lo, hi = _prepared
    fig = Figure(figsize=_figsize(fr.result.image_shape), dpi=100, layout="constrained")
    ax = fig.add_subplot()
    im = _draw_field(ax, fr, field, units, cmap or cm, lo, hi, image=image)
    fig.colorbar(im, ax=ax, label=_field_label(field, units, info), shrink=0.9)
    ax.set_title(title or f"{FIELDS[field][0]} - {_frame_title(fr, units)}", fontsize=10)
    return fig


def _prepare_series(data, field, frames, units, strain, clim):
    if field not in FIELDS:
        raise ValueError(f"unknown field {field!r}; choose one of {sorted(FIELDS)}")
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    values = [_field_values(fr, field, units) for fr in fr_list]
    cm, lo, hi = _limits(field, values, clim)
    return fr_list, units, info, cm, lo, hi


def _render_rgb(fig, dpi: int) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(dpi)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def export_png(data, path, field: str = "u", *, frames=None, units=None, strain=True,
               image=None, cmap=None, clim=None, dpi: int = 150) -> list[Path]:
    """PNG image(s) of one field with a colour bar labelled with its unit.

    One frame writes ``path``; several write ``STEM_frame#####.png`` each,
    all with the same colour limits (``clim`` or robust limits over the
    frames). Returns the paths written.
    """
    path = _target(path, (".png",))
    fr_list, units, info, cm, lo, hi = _prepare_series(data, field, frames, units, strain, clim)
    targets = [path] if len(fr_list) == 1 else [_frame_path(path, fr.index) for fr in fr_list]
    written = []
    for fr, target in zip(fr_list, targets):
        fig = field_figure(None, field, image=image, cmap=cmap,
                           _prepared=(fr, units, info, cm, lo, hi))
        with atomic_write(target) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
        written.append(target)
    return written


def _frames_rgb(fr_list, field, units, info, cm, lo, hi, image, cmap, dpi):
    for fr in fr_list:
        fig = field_figure(None, field, image=image, cmap=cmap,
                           _prepared=(fr, units, info, cm, lo, hi))
        yield _render_rgb(fig, dpi)


def export_gif(data, path, field: str = "u", *, frames=None, units=None, strain=True,
               fps: float = 4.0, image=None, cmap=None, clim=None, dpi: int = 100,
               loop: int = 0) -> Path:
    """Animated GIF of one field over the frames (Pillow), fixed colour limits.

    One GIF frame per result frame, ``1/fps`` seconds each; ``loop=0``
    repeats forever.
    """
    from PIL import Image

    if not fps > 0:
        raise ValueError(f"fps={fps!r} must be > 0")
    path = _target(path, (".gif",))
    fr_list, units, info, cm, lo, hi = _prepare_series(data, field, frames, units, strain, clim)
    images = [Image.fromarray(rgb).quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                                            dither=Image.Dither.NONE)
              for rgb in _frames_rgb(fr_list, field, units, info, cm, lo, hi, image, cmap, dpi)]
    with atomic_write(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(round(1000 / fps)), loop=loop, optimize=False,
                       disposal=1)
    return path


def _ffmpeg():
    """The ``imageio_ffmpeg`` module with a working ffmpeg, or a clear error."""
    hint = ("MP4 export needs the ffmpeg encoder from the 'imageio-ffmpeg' package: install "
            "it with  pip install imageio-ffmpeg  (or  pip install 'napari-aldic[video]'). "
            "Animated GIF export works without it (use the .gif format)")
    try:
        import imageio_ffmpeg
    except ImportError:
        raise EncoderNotFoundError(hint) from None
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except Exception as exc:  # RuntimeError when no binary is found
        raise EncoderNotFoundError(f"{hint} ({exc})") from None
    return imageio_ffmpeg


def export_mp4(data, path, field: str = "u", *, frames=None, units=None, strain=True,
               fps: float = 4.0, image=None, cmap=None, clim=None, dpi: int = 100,
               quality: float = 8) -> Path:
    """MP4 video (H.264 via ``imageio-ffmpeg``) of one field over the frames.

    Raises :class:`EncoderNotFoundError` with install advice when ffmpeg is
    missing (GIF export still works then).
    """
    if not fps > 0:
        raise ValueError(f"fps={fps!r} must be > 0")
    path = _target(path, (".mp4",))
    ffmpeg = _ffmpeg()
    fr_list, units, info, cm, lo, hi = _prepare_series(data, field, frames, units, strain, clim)
    rgbs = list(_frames_rgb(fr_list, field, units, info, cm, lo, hi, image, cmap, dpi))
    h, w = rgbs[0].shape[:2]
    H, W = -(-h // 16) * 16, -(-w // 16) * 16  # pad to whole macro blocks (no rescaling)
    with atomic_write(path) as tmp:
        writer = ffmpeg.write_frames(str(tmp), (W, H), fps=fps, codec="libx264",
                                     quality=quality, macro_block_size=1,
                                     ffmpeg_log_level="error",
                                     output_params=["-f", "mp4"])
        try:
            writer.send(None)
            for rgb in rgbs:
                frame = np.full((H, W, 3), 255, np.uint8)
                frame[:h, :w] = rgb
                writer.send(np.ascontiguousarray(frame))
        except BaseException:
            try:
                writer.close()
            except Exception:
                pass
            raise
        try:
            writer.close()  # waits for ffmpeg to finish the file
        except RuntimeError as exc:
            raise ExportError(f"cannot write {path}: the video encoder failed ({exc}). "
                              "Check the free disk space, or export a GIF instead",
                              path) from exc
    return path


# =================================================================== parameters
def save_params(path, params: DICParams, *, units=None, strain=None,
                tracking: dict | None = None) -> Path:
    """Write the complete analysis settings as readable JSON.

    The file holds ``{"format": "napari-aldic-settings", "software": ...,
    "params": {DICParams fields}, "units": {...}, "strain": {...},
    "tracking": {...}}`` (the last three when given).
    ``napari-aldic run --params FILE`` and :func:`load_params` read it.
    """
    if not isinstance(params, DICParams):
        raise TypeError("params must be a DICParams")
    path = _target(path, (".json",))
    doc: dict[str, Any] = {"format": SETTINGS_FORMAT, "format_version": 1,
                           "software": _software(), "params": params.to_dict()}
    if units is not None:
        doc["units"] = (units if isinstance(units, Units) else Units.from_dict(units)).to_dict()
    if strain is not None:
        doc["strain"] = {**STRAIN_DEFAULTS, **(strain if isinstance(strain, dict) else {})}
    if tracking is not None:
        doc["tracking"] = dict(tracking)
    text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
    with atomic_write(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
    return path


def load_settings(path) -> dict[str, Any]:
    """Read settings written by :func:`save_params` (or a plain JSON object of
    DICParams fields). Returns ``{"params": DICParams, "units": Units or None,
    "strain": dict or None, "tracking": dict or None}``."""
    path = Path(os.fspath(path)).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"no parameter file at {path}")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"parameter file {path} is not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"parameter file {path} must hold a JSON object")
    if doc.get("format") == SETTINGS_FORMAT or "params" in doc and isinstance(doc["params"],
                                                                             dict):
        known = {"format", "format_version", "software", "params", "units", "strain",
                 "tracking"}
        unknown = sorted(set(doc) - known)
        if unknown:
            raise ValueError(f"parameter file {path}: unknown section(s) {unknown}; valid "
                             f"sections are {sorted(known)}")
        try:
            params = DICParams.from_dict(doc.get("params") or {})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"parameter file {path}: {exc}") from None
        units = Units.from_dict(doc["units"]) if doc.get("units") else None
        return {"params": params, "units": units, "strain": doc.get("strain"),
                "tracking": doc.get("tracking")}
    try:
        params = DICParams.from_dict(doc)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"parameter file {path}: {exc}") from None
    return {"params": params, "units": None, "strain": None, "tracking": None}


def load_params(path) -> DICParams:
    """The :class:`DICParams` of a settings file (see :func:`load_settings`)."""
    return load_settings(path)["params"]


# =================================================================== dispatch
_BY_SUFFIX = {".mat": "mat", ".csv": "csv", ".png": "png", ".gif": "gif", ".mp4": "mp4",
              ".pdf": "pdf", ".vtu": "vtu", ".txt": "davis"}


def export_result(data, path, to: str | None = None, **options):
    """Export ``data`` in the format named by ``to`` or by the suffix of
    ``path``: ``mat``, ``csv``, ``png``, ``gif``, ``mp4``, ``pdf`` (report),
    ``vtu`` or ``davis`` (``.txt``). ``options`` go to the writer."""
    fmt = to or _BY_SUFFIX.get(Path(os.fspath(path)).suffix.lower())
    if fmt is None:
        raise ValueError(f"cannot tell the export format of {path}; name it with to= one of "
                         f"{sorted(set(_BY_SUFFIX.values()))}")
    if fmt == "pdf":
        from .report import export_report

        return export_report(data, path, **options)
    writers = {"mat": export_mat, "csv": export_csv, "png": export_png, "gif": export_gif,
               "mp4": export_mp4, "vtu": export_vtu, "davis": export_davis}
    if fmt not in writers:
        raise ValueError(f"unknown export format {fmt!r}; choose one of "
                         f"{sorted(writers) + ['pdf']}")
    return writers[fmt](data, path, **options)
