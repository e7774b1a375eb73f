"""Per-frame probe values with status and reason, and their CSV export.

A :class:`ProbeTable` has one row per frame and one :class:`Column` per
quantity (``line1_strain``, ``point1_u``, ``area1_exx_mean``, ``load_N`` ...).
Every value carries a status -- ``ok``, ``degraded`` or ``missing`` -- and the
reason when it is not ok; a missing value is NaN (an empty CSV cell).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.files import atomic_write, target_path
from ..core.units import Units
from ..io.columns import software_name
from .geometry import ProbeSet
from .sampling import MISSING, OK, STATUS_NAMES

__all__ = ["Column", "ProbeTable", "export_probes_csv", "probe_csv_lines"]


@dataclass
class Column:
    """One quantity over the frames.

    ``group`` is the probe it belongs to (``line1``, ``point2``, ``area1``,
    ``load``); ``status`` holds codes 0 ok, 1 degraded, 2 missing.
    """

    name: str
    group: str
    values: np.ndarray
    unit: str
    status: np.ndarray
    reasons: list
    description: str = ""

    def __post_init__(self):
        self.values = np.asarray(self.values, float)
        self.status = np.asarray(self.status, np.int8)
        # a value that is not finite is never reported as ok
        bad = ~np.isfinite(self.values) & (self.status != MISSING)
        if bad.any():
            self.status = np.where(bad, MISSING, self.status).astype(np.int8)
            self.reasons = [r or "not computable" if b else r for r, b in zip(self.reasons, bad)]
        self.values = np.where(self.status == MISSING, np.nan, self.values)

    @property
    def status_text(self) -> list[str]:
        return [STATUS_NAMES[int(s)] for s in self.status]


@dataclass
class ProbeTable:
    """Probe values over the frames of a run.

    Attributes
    ----------
    frames : (n,) int
        Frame numbers (frame 0, the reference, first).
    columns : dict name -> Column
        In the order they were added.
    units : Units
        The run's units: lengths in ``units.unit``.
    probes : ProbeSet
    info : dict
        Source, strain settings, load file and synchronisation.
    """

    frames: np.ndarray
    columns: dict = field(default_factory=dict)
    units: Units = field(default_factory=Units)
    probes: ProbeSet = field(default_factory=ProbeSet)
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        self.frames = np.asarray(self.frames, np.int64)

    def __len__(self) -> int:
        return int(self.frames.size)

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    def __getitem__(self, name: str) -> np.ndarray:
        """The values of column ``name`` (NaN where missing)."""
        if name not in self.columns:
            raise KeyError(f"no probe column {name!r}; columns: {', '.join(self.columns)}")
        return self.columns[name].values

    def add(self, column: Column) -> None:
        if column.values.shape != self.frames.shape:
            raise ValueError(f"column {column.name}: {column.values.size} values for "
                             f"{self.frames.size} frames")
        self.columns[column.name] = column

    @property
    def times(self) -> np.ndarray | None:
        """Time of each frame in ``units.time_unit`` (None without a frame interval)."""
        return None if not self.units.has_time else self.frames * self.units.frame_interval

    def groups(self) -> dict[str, list[str]]:
        """Column names of each probe, in order."""
        out: dict[str, list[str]] = {}
        for c in self.columns.values():
            out.setdefault(c.group, []).append(c.name)
        return out

    def group_status(self, group: str) -> tuple[np.ndarray, list[str]]:
        """Worst status of a probe's columns per frame, and the reasons (column
        names in brackets when the columns disagree)."""
        cols = [self.columns[n] for n in self.groups()[group]]
        status = np.max([c.status for c in cols], axis=0).astype(np.int8)
        reasons = []
        for i in range(self.frames.size):
            texts = {c.reasons[i] for c in cols if c.status[i] != OK and c.reasons[i]}
            if len(texts) > 1 or (texts and any(c.status[i] == OK for c in cols)):
                parts = {}
                for c in cols:
                    if c.status[i] != OK and c.reasons[i]:
                        parts.setdefault(c.reasons[i], []).append(c.name)
                reasons.append("; ".join(f"{t} [{', '.join(n)}]" for t, n in parts.items()))
            else:
                reasons.append(next(iter(texts), ""))
        return status, reasons

    def status_summary(self, max_frames: int = 6) -> list[str]:
        """One line per probe that is not ok at every frame: its worst status, the
        frames (``max_frames`` at most) and the first reason."""
        out = []
        for group in self.groups():
            status, reasons = self.group_status(group)
            bad = np.nonzero(status > OK)[0]
            if not bad.size:
                continue
            frames = ", ".join(str(int(self.frames[i])) for i in bad[:max_frames])
            more = " ..." if bad.size > max_frames else ""
            why = next((reasons[i] for i in bad if reasons[i]), "")
            out.append(f"{group}: {STATUS_NAMES[int(status.max())]} at frame(s) "
                       f"{frames}{more}: {why}")
        return out

    def units_of(self) -> dict[str, str]:
        """Unit of every column (``""`` dimensionless)."""
        return {n: c.unit for n, c in self.columns.items()}

    def to_dict(self) -> dict:
        """Plain JSON: the values, statuses, units, probes and info."""
        return {"frames": self.frames.tolist(), "units": self.units.to_dict(),
                "probes": self.probes.to_dict(),
                "columns": {n: {"group": c.group, "unit": c.unit,
                                "values": [None if not np.isfinite(v) else float(v)
                                           for v in c.values],
                                "status": c.status_text, "reasons": list(c.reasons)}
                            for n, c in self.columns.items()},
                "info": _plain(self.info)}


def _plain(obj):
    """``obj`` with NumPy scalars/arrays turned into JSON types."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return str(obj)


def _cell(v: float) -> str:
    return "" if not np.isfinite(v) else f"{v:.10g}"


def _quoted(text: str) -> str:
    return '"' + text.replace('"', '""') + '"' if any(ch in text for ch in ',"\n') else text


def export_probes_csv(table: ProbeTable, path, *, sidecar: bool = True) -> Path:
    """Write ``table``: one row per frame, one column per quantity.

    The first line is the header of plain column names -- ``frame``, ``time``
    (with a frame interval), then per probe its quantities followed by
    ``<probe>_status`` (ok/degraded/missing) and ``<probe>_reason``; with load
    data ``load_N``, ``stress_MPa``, ``load_status``, ``load_reason``. A missing
    value is an empty cell. The units of every column, the probe definitions and
    the settings go to ``<name>.json`` beside the CSV (``sidecar=False``: none),
    so the CSV itself stays one header line and one row per frame.
    """
    path = target_path(path, (".csv", ".txt"))
    lines = probe_csv_lines(table)
    with atomic_write(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    if sidecar:
        units = {"frame": "", **({"time": table.units.time_unit}
                                 if table.times is not None else {}), **table.units_of()}
        meta = {"software": software_name(), "csv": path.name, "units": units,
                "length_unit": table.units.unit, "settings": table.units.to_dict(),
                "status_words": {"ok": "trusted", "degraded": "computed, read with care "
                                 "(see the reason)", "missing": "no value (empty cell)"},
                "probes": table.probes.to_dict(), "info": _plain(table.info)}
        with atomic_write(path.with_suffix(".json")) as tmp:
            tmp.write_text(json.dumps(meta, indent=1, ensure_ascii=False), encoding="utf-8")
    return path


def probe_csv_lines(table: ProbeTable) -> list[str]:
    """The lines of :func:`export_probes_csv`'s CSV: the header, then one row
    per frame (a live watch appends rows one by one)."""
    groups = table.groups()
    header = ["frame"] + (["time"] if table.times is not None else [])
    for g, names in groups.items():
        header += names + [f"{g}_status", f"{g}_reason"]
    status = {g: table.group_status(g) for g in groups}
    lines = [",".join(header)]
    for i, k in enumerate(table.frames):
        row = [str(int(k))]
        if table.times is not None:
            row.append(_cell(table.times[i]))
        for g, names in groups.items():
            row += [_cell(table.columns[n].values[i]) for n in names]
            row += [STATUS_NAMES[int(status[g][0][i])], _quoted(status[g][1][i])]
        lines.append(",".join(row))
    return lines
