"""CSV export and reader."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import atomic_write, regular_file, target_path
from ..core.units import Units
from .columns import UNTRUSTED_RULE, frame_columns, reason_lines, software_name
from .runs import collect_frames


# =================================================================== CSV
def export_csv(data, path, *, units=None, strain=True, frames=None) -> Path:
    """Write one row per node per frame to a CSV file.

    Columns: ``frame``, ``time [time_unit]`` (with a frame interval),
    ``node``, ``x_px [px]``, ``y_px [px]``, ``x``, ``y``, ``u``, ``v``,
    ``magnitude`` (all ``[unit]``), ``vx``, ``vy`` (``[unit/time_unit]``, with
    a frame interval), ``exx``, ``eyy``, ``exy``, ``e1``, ``e2``,
    ``max_shear``, ``von_mises``, ``rotation [rad]`` (with strain),
    ``exx_rate``, ``eyy_rate``, ``exy_rate`` (``[1/time_unit]``), then
    ``strain_valid``, ``valid``, ``reason``, ``zncc``, ``u_attempt``,
    ``v_attempt``. Measured values are NaN where the node is not trusted; the
    ``*_attempt`` columns keep the solver's value there (see
    :data:`~napari_aldic.engine.io.columns.UNTRUSTED_RULE`). The CSV is a
    plain table (one header line of ``name [unit]``; dimensionless quantities
    ``[1]``; ``sssig [GL^2]``, ``mig [GL/px]`` in grey levels) that
    ``pandas.read_csv`` and spreadsheets open as it is; what describes it --
    software, source, the exact units, strain settings, the untrusted-node
    rule, the reason codes -- goes to ``NAME.json`` beside it (as for the
    probe tables). Read both back with :func:`read_csv`.
    """
    path = target_path(path, (".csv", ".txt"))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    first = frame_columns(fr_list[0], units)
    names = ["frame"] + (["time"] if units.has_time else []) + list(first)
    unit_map = {"frame": ""}
    if units.has_time:
        unit_map["time"] = units.time_unit
    unit_map.update({k: u or ("" if k in _COUNTS else "1") for k, (_, u) in first.items()})
    with atomic_write(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        # units are the user's text: one line per cell, quoted by the csv module
        # where needed (the exact units are in the JSON sidecar)
        header = [f"{k} [{' '.join(unit_map[k].split())}]" if unit_map[k] else k
                  for k in names]
        csv.writer(fh, lineterminator="\n").writerow(header)
        for fr in fr_list:
            _write_frame(fh, fr, units, first)
    with atomic_write(path.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(_sidecar(path, info, units, unit_map, header), indent=1,
                                  ensure_ascii=False), encoding="utf-8")
    return path


#: columns that count or flag rather than measure: no unit in the header
_COUNTS = ("frame", "node", "valid", "reason", "strain_valid")


def _write_frame(fh, fr, units, first: dict) -> None:
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
        "%d" if k in _COUNTS else "%.10g" for k in cols]
    np.savetxt(fh, np.column_stack(block), fmt=fmt, delimiter=",")


def _sidecar(path: Path, info: dict, units: Units, unit_map: dict, header: list) -> dict:
    """What the CSV's ``NAME.json`` says about it (the CSV itself stays a plain table)."""
    meta = {"software": software_name(), "csv": path.name,
            "content": "result export: one row per node per frame",
            "source": None if not info.get("source") else str(info["source"]),
            "settings": units.to_dict(), "units": unit_map, "header": header,
            "image_shape": list(info["image_shape"]),
            "coordinates": "x = column, y = row (downwards), pixel centres at integers",
            "untrusted_nodes": UNTRUSTED_RULE, "reason_codes": reason_lines()}
    if info["strain"]:
        s = info["strain"]
        meta["strain"] = (f"{s['measure']} by {s['method']}, window {s['window']} nodes, "
                          f"VSG {s['vsg_px']:g} px; dimensionless (exy is the tensor shear)")
    return meta


def read_csv(path) -> dict[str, Any]:
    """Read a CSV written by :func:`export_csv` (with its ``NAME.json``
    sidecar when present; files of 0.1 with ``#`` header lines too).

    Returns ``{"columns": {name: array}, "units": {name: unit},
    "settings": Units, "header": {key: text}}``; column names are given
    without their ``[unit]`` suffix. A plain ``pandas.read_csv(path)`` reads
    the same table (column names with their units).
    """
    path = regular_file(path, "CSV file")  # a named pipe would block the read
    header: dict[str, Any] = {}
    with open(path, encoding="utf-8") as fh:
        line = fh.readline()
        while line.startswith("#"):  # 0.1 files: metadata in comment lines
            body = line[1:].strip()
            if ":" in body:
                key, _, val = body.partition(":")
                header[key.strip()] = val.strip()
            line = fh.readline()
        names_raw = next(csv.reader([line]))
        data = np.loadtxt(fh, delimiter=",", ndmin=2)
    side = path.with_suffix(".json")
    meta = json.loads(side.read_text(encoding="utf-8")) if side.is_file() else {}
    if meta.get("csv") not in (None, path.name):
        meta = {}  # a JSON file of something else
    names, units = [], {}
    for raw in names_raw:
        m = re.fullmatch(r"\s*(.+?)\s*(?:\[(.*)\])?\s*", raw)
        name, unit = m.group(1), m.group(2) or ""
        names.append(name)
        units[name] = unit
    if "units" in header:
        units.update(json.loads(header["units"]))
    units.update(meta.get("units", {}))
    cols = {}
    for i, name in enumerate(names):
        col = data[:, i] if data.size else np.empty(0)
        if name in ("frame", "node", "reason"):
            col = col.astype(np.int64)
        elif name in ("valid", "strain_valid"):
            col = col.astype(bool)
        cols[name] = col
    if "settings" in meta:
        settings = Units.from_dict(meta["settings"])
    elif "settings" in header:
        settings = Units.from_dict(json.loads(header["settings"]))
    else:
        settings = Units()
    header.update({k: v for k, v in meta.items() if k not in ("units", "settings")})
    for key, old in (("untrusted_nodes", "untrusted nodes"), ("reason_codes", "reason codes")):
        if key in meta:  # the names of the 0.1 header lines
            header[old] = meta[key] if isinstance(meta[key], str) else "; ".join(meta[key])
    return {"columns": cols, "units": units, "settings": settings, "header": header}
