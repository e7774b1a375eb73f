"""VTK unstructured grid (.vtu/.pvd) export and reader."""

from __future__ import annotations

import base64
import re
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from ..core.files import AtomicFiles, numbered_path, target_path
from ..core.results import DICResult
from ..core.units import Units
from .columns import UNTRUSTED_RULE, frame_columns, software_name
from .runs import Frame, collect_frames


# =================================================================== VTK
def result_cells(res: DICResult) -> np.ndarray:
    """Q4 cells (E, 4) of a result, corner order (x0,y0) (x1,y0) (x1,y1) (x0,y1).

    The result's own mesh (``res.elements``, AL-DIC and quadtree) when it has
    one, else one cell per lattice square whose four nodes exist and whose
    rectangle lies inside the ROI (cells never bridge holes or cracks).
    """
    if res.elements is not None and len(res.elements):
        return np.asarray(res.elements, np.int64)
    from ..dic.global_solve import uniform_mesh
    from ..dic.mesh import NodeGrid

    on = np.asarray(res.grid_ix) >= 0
    if not on.all():  # off-lattice nodes without elements: no mesh to draw
        return np.empty((0, 4), np.int64)
    grid = NodeGrid(res.x.astype(np.int64), res.y.astype(np.int64), res.grid_ix, res.grid_iy,
                    res.grid_xs, res.grid_ys)
    roi = res.roi if res.roi is not None else np.ones(res.image_shape, bool)
    return np.asarray(uniform_mesh(grid, np.asarray(roi, bool)).elements, np.int64)


def _xml_comment(text: str) -> str:
    """``text`` made safe inside ``<!-- -->``: no ``--`` (which XML forbids in
    comments, and which ``-->`` would end it with) and no control characters."""
    text = re.sub(r"[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]", "?", text)
    while "--" in text:
        text = text.replace("--", "- -")
    return text


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
    unit_note = (f"napari-aldic VTU export ({software_name()}), frame {fr.index}. Coordinates and "
                 f"displacement in {units.unit} (pixel size {units.pixel_size:g} {units.unit}); "
                 "x = image column, y = image row (downwards), z = 0. Strains dimensionless, "
                 "rotation in rad. Untrusted nodes: " + UNTRUSTED_RULE)
    if units.has_time:
        unit_note += (f"; velocity in {units.velocity_unit}, strain rates in "
                      f"{units.rate_unit}, time in {units.time_unit}")
    out = ['<?xml version="1.0"?>\n', f"<!-- {_xml_comment(unit_note)}. -->\n",
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


def export_vtu(data, path, *, units=None, strain=True, frames=None,
               encoding: str = "binary", nan_value: float | None = None) -> list[Path]:
    """Write VTK XML UnstructuredGrid files (``.vtu``) of Q4 cells with point data.

    One result writes ``path``. Several frames write ``STEM_frame#####.vtu``
    per frame and a ParaView collection ``STEM.pvd`` (time = frame time, or
    frame number without a frame interval). Points are the nodes in the
    physical unit (z = 0); point data: ``displacement`` (3-vector),
    ``velocity`` (with a frame interval), ``u``, ``v``, ``magnitude``,
    ``vx``, ``vy``, strains and rates (when computed), ``strain_valid``,
    ``valid``, ``reason``, ``zncc``, ``u_attempt``, ``v_attempt``. Measured
    values are NaN at untrusted nodes (the ``*_attempt`` arrays keep the
    solver's value there; see
    :data:`~napari_aldic.engine.io.columns.UNTRUSTED_RULE`). ``encoding``: ``"binary"`` (base64,
    exact, default) or ``"ascii"``. VTK cannot parse NaN in ASCII: with
    ``"ascii"``, arrays holding NaN (untrusted nodes, no velocity at frame 0)
    stay base64 unless ``nan_value`` gives a number to write instead. Returns
    the paths written (the ``.pvd`` last).
    """
    if encoding not in ("binary", "ascii", "base64"):
        raise ValueError(f"encoding={encoding!r} must be 'binary' (base64) or 'ascii'")
    encoding = "binary" if encoding == "base64" else encoding
    path = target_path(path, (".vtu",))
    fr_list, units, info = collect_frames(data, frames=frames, strain=strain, units=units)
    written = []
    if len(fr_list) == 1:
        targets = [path]
    else:
        targets = [numbered_path(path, fr.index) for fr in fr_list]
    with AtomicFiles() as files:  # the frame files and their .pvd appear together
        for fr, target in zip(fr_list, targets):
            text = _vtu_text(fr, units, encoding, info, nan_value)
            with files.write(target) as tmp, open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
            written.append(target)
        if len(fr_list) > 1:
            written.append(_write_pvd(files, path, fr_list, targets, units))
    return written


def _write_pvd(files, path: Path, fr_list, targets, units) -> Path:
    """The ParaView collection of the frame files ``targets``."""
    pvd = path.with_suffix(".pvd")
    lines = ['<?xml version="1.0"?>\n',
             '<VTKFile type="Collection" version="1.0" byte_order="LittleEndian">\n',
             "  <Collection>\n"]
    for fr, target in zip(fr_list, targets):
        t = units.time(fr.index) if units.has_time else fr.index
        lines.append(f'    <DataSet timestep="{t!r}" group="" part="0" '
                     f'file={quoteattr(target.name)}/>\n')
    lines.append("  </Collection>\n</VTKFile>\n")
    with files.write(pvd) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write("".join(lines))
    return pvd


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


