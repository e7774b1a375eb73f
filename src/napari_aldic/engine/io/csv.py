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
    :data:`~napari_aldic.engine.io.columns.UNTRUSTED_RULE`). Header lines start
    with ``#``: software, source, units (one JSON line), strain settings, the
    untrusted-node rule and the reason codes. Read it back with :func:`read_csv`.
    """
    path = target_path(path, (".csv", ".txt"))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    with atomic_write(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        first = frame_columns(fr_list[0], units)
        names = ["frame"] + (["time"] if units.has_time else []) + list(first)
        unit_map = {"frame": ""}
        if units.has_time:
            unit_map["time"] = units.time_unit
        unit_map.update({k: u for k, (_, u) in first.items()})
        fh.write(f"# {software_name()} result export (CSV): one row per node per frame\n")
        if info.get("source"):
            fh.write(f"# source: {_one_line(info['source'])}\n")
        fh.write(f"# settings: {json.dumps(units.to_dict())}\n")
        fh.write(f"# units: {json.dumps(unit_map, ensure_ascii=False)}\n")
        if info["strain"]:
            s = info["strain"]
            fh.write(f"# strain: {s['measure']} by {s['method']}, window {s['window']} nodes, "
                     f"VSG {s['vsg_px']:g} px; dimensionless (exy is the tensor shear)\n")
        fh.write(f"# image_shape: {list(info['image_shape'])}; coordinates: x = column, "
                 "y = row (downwards), pixel centres at integers\n")
        fh.write(f"# untrusted nodes: {UNTRUSTED_RULE}\n")
        fh.write("# reason codes: " + "; ".join(reason_lines()) + "\n")
        # units are the user's text: one line per cell, quoted by the csv module
        # where needed (the exact units are in the "# units:" JSON line)
        header = [f"{k} [{' '.join(unit_map[k].split())}]" if unit_map[k] else k
                  for k in names]
        csv.writer(fh, lineterminator="\n").writerow(header)
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


def _one_line(text) -> str:
    """``text`` for a ``#`` header line: line breaks written as ``\\n``."""
    return str(text).replace("\r", "\\r").replace("\n", "\\n")


def read_csv(path) -> dict[str, Any]:
    """Read a CSV written by :func:`export_csv`.

    Returns ``{"columns": {name: array}, "units": {name: unit},
    "settings": Units, "header": {key: text}}``; column names are given
    without their ``[unit]`` suffix.
    """
    path = regular_file(path, "CSV file")  # a named pipe would block the read
    header: dict[str, str] = {}
    with open(path, encoding="utf-8") as fh:
        line = fh.readline()
        while line.startswith("#"):
            body = line[1:].strip()
            if ":" in body:
                key, _, val = body.partition(":")
                header[key.strip()] = val.strip()
            line = fh.readline()
        names_raw = next(csv.reader([line]))
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


