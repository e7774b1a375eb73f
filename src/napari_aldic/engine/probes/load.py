"""Testing-machine data: read a load CSV, synchronise it with the frames, stress.

:func:`read_load_csv` reads the common dialects of testing-machine exports:

* separator comma, semicolon or tab (found from the data rows);
* decimal comma (with a semicolon or tab separator);
* title lines above the header; a units row below it (``(kN)``, ``[s]``, ``N``);
* the load unit from the units row, the header (``Force (kN)``, ``Load [N]``,
  ``Force in kN``) or ``unit=``; kN, N, mN, MN, daN, lbf and kip become newtons.
  Without any unit the load is taken in N.

:func:`load_at_frames` gives the load at each frame, either by a frame column of
the file (``sync="frame"``) or by time, ``t = frame / fps + offset`` against the
file's time column (``sync="time"``). Values between samples are interpolated
linearly; a frame outside the record gets no load (never extrapolated).
Engineering stress is ``load / area`` (N / mm² = MPa).
"""

from __future__ import annotations

import codecs
import csv
import errno
import io
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.files import MAX_TEXT_BYTES, open_regular
from .sampling import MISSING, OK
from .table import Column, ProbeTable

__all__ = ["LoadRecord", "read_load_csv", "load_at_frames", "attach_load", "LOAD_UNITS"]

#: load unit -> newtons (exact spelling first, then case-insensitively)
LOAD_UNITS = {"N": 1.0, "kN": 1e3, "KN": 1e3, "mN": 1e-3, "MN": 1e6, "daN": 10.0,
              "lbf": 4.4482216152605, "kip": 4448.2216152605, "kgf": 9.80665}
TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
_KEYWORDS = {"frame": ("frame", "image", "img", "picture", "bild", "photo"),
             "time": ("time", "zeit", "temps", "tiempo"),
             "load": ("load", "force", "kraft", "charge", "fuerza")}
_NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
_BRACKETED = re.compile(r"^\s*[\(\[](.*)[\)\]]\s*$")


@dataclass
class LoadRecord:
    """Load samples of a testing machine (load in newtons).

    ``time_s`` (seconds) and ``frame`` are None when the file has no such column.
    """

    load_N: np.ndarray
    time_s: np.ndarray | None
    frame: np.ndarray | None
    source: str = ""
    unit: str = "N"
    columns: dict = field(default_factory=dict)
    delimiter: str = ","
    decimal: str = "."
    title: str = ""

    def __len__(self) -> int:
        return int(self.load_N.size)

    def describe(self) -> str:
        what = ", ".join(f"{k} = '{v}'" for k, v in self.columns.items() if v)
        return (f"{len(self)} load samples from {Path(self.source).name or 'a table'} "
                f"({what}; load read in {self.unit})")


def _read_text(path: Path) -> str:
    """The file's text: UTF-16 or UTF-32 by its byte-order mark (spreadsheets
    save "Unicode text" so), else UTF-8, else Latin-1."""
    with open_regular(path, "load file") as fh:
        raw = fh.read(MAX_TEXT_BYTES + 1)
    if len(raw) > MAX_TEXT_BYTES:
        raise ValueError(f"{path}: larger than {MAX_TEXT_BYTES >> 20} MB; not a load table")
    for bom, enc in ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"),
                     (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16")):
        if raw.startswith(bom):
            try:
                return raw.decode(enc)
            except UnicodeDecodeError as exc:
                raise ValueError(f"{path}: not readable {enc.upper()} text ({exc.reason})") \
                    from None
    if b"\0" in raw[:4096]:
        raise ValueError(f"{path}: binary data (zero bytes), not a text table; save it as "
                         "CSV (UTF-8)")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _split(line: str, delim: str) -> list[str]:
    return [c.strip() for c in next(csv.reader(io.StringIO(line), delimiter=delim))]


def _is_number(cell: str) -> bool:
    return bool(_NUMBER.match(cell))


def _numeric(cells: list[str]) -> bool:
    filled = [c for c in cells if c]
    return len(filled) >= 1 and all(_is_number(c) for c in filled)


def _delimiter(lines: list[str]) -> str:
    """The separator that splits the last (data) lines into the same number (>= 2)
    of numeric fields; tab and semicolon before comma (a decimal comma splits too)."""
    tail = lines[-min(len(lines), 20):]
    for delim in ("\t", ";", ","):
        cells = [_split(ln, delim) for ln in tail]
        n = len(cells[-1])
        run = 0
        for row in reversed(cells):  # the numeric rows at the end of the file
            if len(row) != n or not _numeric(row):
                break
            run += 1
        if n >= 2 and run >= min(2, len(tail)):
            return delim
    raise ValueError("cannot find the column separator (comma, semicolon or tab) of the "
                     "data rows, or the last rows are not numbers")


def _unit_row(cells: list[str]) -> bool:
    """A row of units under the header: every filled cell bracketed or a known unit."""
    filled = [c for c in cells if c]
    known = {u.lower() for u in (*LOAD_UNITS, *TIME_UNITS)} | {"-", "mm", "m", "um", "µm",
                                                               "%", "mpa", "1", "#"}
    return bool(filled) and all(_BRACKETED.match(c) or c.lower() in known for c in filled)


def _header_unit(name: str) -> tuple[str, str]:
    """``("Force", "kN")`` from ``Force (kN)``, ``Force [kN]``, ``Force in kN``."""
    m = re.match(r"^(.*?)[\s_]*[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$", name)
    if m:
        return m.group(1).strip(), m.group(2)
    m = re.match(r"^(.*\S)\s+in\s+(\S+)$", name)
    if m:
        return m.group(1).strip(), m.group(2)
    return name.strip(), ""


def _find_column(names: list[str], kind: str, given: str | None, path: Path) -> int | None:
    if given is not None:
        for i, n in enumerate(names):
            if n == given or _header_unit(n)[0] == given:
                return i
        raise ValueError(f"{path}: no column {given!r}; columns: {', '.join(names)}")
    for i, n in enumerate(names):
        words = re.findall(r"[a-zäöü]+", _header_unit(n)[0].lower())
        # endswith: German compounds put the keyword last (Standardkraft, Prüfzeit)
        if any(w.startswith(k) or w.endswith(k) for w in words for k in _KEYWORDS[kind]) or \
                (kind == "load" and words in (["f"], ["p"])) or (kind == "time" and words == ["t"]):
            return i
    return None


def _names_columns(cells: list[str]) -> bool:
    """Whether a row names a load, time or frame column (a header row)."""
    return any(_find_column(cells, kind, None, Path()) is not None for kind in _KEYWORDS)


def _factor(unit: str, table: dict, what: str, path: Path) -> float:
    u = _BRACKETED.sub(r"\1", unit).strip()
    if u in table:
        return table[u]
    lower = {k.lower(): v for k, v in table.items()}
    if u.lower() in lower and u.lower() not in ("mn",):  # mN and MN differ by 1e9
        return lower[u.lower()]
    raise ValueError(f"{path}: unknown {what} unit {unit!r}; use one of {', '.join(table)}")


def _layout(rows: list[list[str]], path: Path) -> tuple[int, int | None, int]:
    """(header row, units row or None, first data row) of the split rows."""
    start = len(rows)
    while start > 0 and _numeric(rows[start - 1]):
        start -= 1
    if len(rows) - start < 2:
        raise ValueError(f"{path}: fewer than two rows of numbers at the end of the file")
    if start == 0:
        raise ValueError(f"{path}: no header row (column names) above the numbers")
    width = len(rows[-1])
    first = next((i for i in range(start) if len(rows[i]) == width
                  and _names_columns(rows[i])), None)
    if first is not None and first < start - 2:
        _check_between(rows, first, start, path)
    if start >= 2 and (_unit_row(rows[start - 1]) or (
            _names_columns(rows[start - 2]) and not _names_columns(rows[start - 1]))):
        return start - 2, start - 1, start
    return start - 1, None, start


def _check_between(rows: list[list[str]], header: int, start: int, path: Path) -> None:
    """Rows between the header row and the numbers at the end that are not
    numbers: a text cell, ``inf``, or the header repeated (two tables pasted
    together) is named, not taken as a second header."""
    for i in range(header + 1, start):
        row = rows[i]
        if i == header + 1 and _unit_row(row):
            continue
        if row == rows[header]:
            raise ValueError(f"{path}: row {i + 1} repeats the header row (two tables pasted "
                             "together?); keep one header")
        bad = next((c for c in row if c and not _is_number(c)), None)
        if bad is not None:
            word = "a finite number" if bad.lower().lstrip("+-") in _NOT_FINITE else "a number"
            raise ValueError(f"{path}: row {i + 1}: {bad[:40]!r} is not {word}")


_NOT_FINITE = {"inf", "infinity", "nan", "1.#inf", "1.#ind"}


def read_load_csv(path, *, load_column: str | None = None, time_column: str | None = None,
                  frame_column: str | None = None, unit: str | None = None) -> LoadRecord:
    """Read a testing machine's CSV (see the module text for the dialects).

    ``load_column``, ``time_column``, ``frame_column`` name the columns (default:
    found by name: load/force, time, frame/image); ``unit`` overrides the load unit
    found in the file. Raises ``ValueError`` naming the file and the problem.
    """
    path = Path(path).expanduser()
    if not os.path.lexists(path):
        raise FileNotFoundError(errno.ENOENT, f"no load file at {path}", str(path))
    lines = [ln for ln in _read_text(path).splitlines() if ln.strip()]
    if len(lines) < 3:
        raise ValueError(f"{path}: too short for a load table (header and two rows)")
    try:
        delim = _delimiter(lines)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    rows = [_split(ln, delim) for ln in lines]
    h, urow, start = _layout(rows, path)
    names = rows[h]
    data = rows[start:]
    decimal = "," if delim != "," and any(_DECIMAL_COMMA.match(c) for r in data for c in r) \
        else "."
    cols = {k: _find_column(names, k, g, path) for k, g in
            (("load", load_column), ("time", time_column), ("frame", frame_column))}
    if cols["load"] is None:
        raise ValueError(f"{path}: no load column (a name with load/force); columns: "
                         f"{', '.join(names)}. Name it with load_column=")
    if cols["time"] is None and cols["frame"] is None:
        raise ValueError(f"{path}: neither a time nor a frame column; columns: "
                         f"{', '.join(names)}")

    def column(i: int) -> np.ndarray:
        out = []
        for r in data:
            c = r[i] if i < len(r) else ""
            out.append(float(c.replace(",", ".")) if c and (decimal == "," or "," not in c)
                       else np.nan)
        return np.asarray(out, float)

    def unit_of(i: int) -> str:
        if urow is not None and i < len(rows[urow]) and rows[urow][i]:
            return _BRACKETED.sub(r"\1", rows[urow][i]).strip()
        return _header_unit(names[i])[1]

    lu = unit or unit_of(cols["load"]) or "N"
    load = column(cols["load"]) * _factor(lu, LOAD_UNITS, "load", path)
    time = frame = None
    if cols["time"] is not None:
        time = column(cols["time"]) * _factor(unit_of(cols["time"]) or "s", TIME_UNITS, "time",
                                              path)
    if cols["frame"] is not None:
        frame = column(cols["frame"])
    keep = np.isfinite(load) & np.all([np.isfinite(a) for a in (time, frame) if a is not None],
                                      axis=0)
    if keep.sum() < 2:
        raise ValueError(f"{path}: fewer than two rows with a load value")
    title = " | ".join(lines[:h])
    return LoadRecord(load[keep], None if time is None else time[keep],
                      None if frame is None else frame[keep], str(path), _BRACKETED.sub(
                          r"\1", lu).strip(),
                      {k: (names[i] if i is not None else None) for k, i in cols.items()},
                      delim, decimal, title)


def _interp_inside(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, what: str, unit: str):
    """Linear interpolation at ``x``; NaN (missing, with the reason) outside ``xp``."""
    order = np.argsort(xp, kind="stable")
    xp, fp = xp[order], fp[order]
    lo, hi = xp[0], xp[-1]
    tol = 1e-9 * max(1.0, abs(hi - lo))
    inside = (x >= lo - tol) & (x <= hi + tol)
    vals = np.where(inside, np.interp(x, xp, fp), np.nan)
    reasons = ["" if ok else f"{what} {v:g}{unit} is outside the load record "
               f"({lo:g}{unit} to {hi:g}{unit}); no extrapolation" for v, ok in zip(x, inside)]
    return vals, np.where(inside, OK, MISSING).astype(np.int8), reasons


def load_at_frames(record: LoadRecord, frames, *, sync: str | None = None,
                   fps: float | None = None, offset: float = 0.0):
    """Load (N) at each frame number: ``(values, status, reasons)``.

    ``sync="frame"``: by the file's frame column (several samples of one frame
    are averaged); ``sync="time"``: frame k at ``k / fps + offset`` seconds on the
    file's time column. Default: by frame when the file has a frame column.
    """
    frames = np.asarray(frames, float)
    if sync is None:
        sync = "frame" if record.frame is not None else "time"
    if sync == "frame":
        if record.frame is None:
            raise ValueError(f"{record.source}: no frame column to synchronise by frame; "
                             "use sync='time' with fps (and offset)")
        ks, inv = np.unique(record.frame, return_inverse=True)
        mean = np.bincount(inv, weights=record.load_N) / np.bincount(inv)
        return _interp_inside(frames, ks, mean, "frame", "")
    if sync != "time":
        raise ValueError(f"sync={sync!r} must be 'frame' or 'time'")
    if record.time_s is None:
        raise ValueError(f"{record.source}: no time column to synchronise by time; use "
                         "sync='frame'")
    if fps is None or not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"synchronising by time needs the camera's frame rate fps > 0 "
                         f"(got {fps!r})")
    if not np.isfinite(offset):
        raise ValueError(f"offset={offset!r} must be a finite number of seconds")
    if np.any(np.diff(record.time_s) < 0):
        bad = int(np.nonzero(np.diff(record.time_s) < 0)[0][0]) + 2
        raise ValueError(f"{record.source}: the time column goes backwards at data row {bad}")
    return _interp_inside(frames / fps + offset, record.time_s, record.load_N, "time", " s")


def attach_load(table: ProbeTable, record: LoadRecord, *, area_mm2: float,
                sync: str | None = None, fps: float | None = None,
                offset: float = 0.0) -> ProbeTable:
    """Add ``load_N`` and ``stress_MPa`` (= load / ``area_mm2``) to ``table``."""
    try:
        area = float(area_mm2)
    except (TypeError, ValueError):
        raise ValueError(f"area_mm2={area_mm2!r} must be the cross-section in mm²") from None
    if not (np.isfinite(area) and area > 0):
        raise ValueError(f"area_mm2={area_mm2!r} must be a positive cross-section in mm²")
    vals, status, reasons = load_at_frames(record, table.frames, sync=sync, fps=fps,
                                           offset=offset)
    table.add(Column("load_N", "load", vals, "N", status, reasons,
                     f"load from {Path(record.source).name}"))
    table.add(Column("stress_MPa", "load", vals / area, "MPa", status, list(reasons),
                     f"engineering stress = load / {area:g} mm²"))
    table.info["load"] = {"file": record.source, "unit_read": record.unit,
                          "columns": record.columns, "sync": sync or (
                              "frame" if record.frame is not None else "time"),
                          "fps": fps, "offset_s": offset, "area_mm2": area}
    return table
