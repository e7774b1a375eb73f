"""Live probes of a watch: one CSV row per frame as it is measured.

The rows are those of ``napari-aldic probe`` (:func:`~napari_aldic.engine.probes.
measure_probes`, :func:`~napari_aldic.engine.probes.probe_csv_lines`): the
CSV is the same file, grown a line at a time (``tail -f`` works). With a load
file that the testing machine is still writing, the file is read again when
it changes (its complete lines only), and a frame's row waits until the load
record reaches that frame -- by frame number or by time, as ``attach_load``
synchronises -- or until ``grace`` seconds have passed (then written with
the load missing). When the watch ends, the CSV and its ``.json`` sidecar
are written once more from the whole run folder, as ``napari-aldic probe``
would write them.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.results import DICResult
from ..probes import (
    DEFAULT_FIELDS,
    MISSING,
    Column,
    ProbeSet,
    attach_load,
    export_probes_csv,
    measure_probes,
    probe_csv_lines,
    read_load_csv,
)

__all__ = ["LiveProbes"]


@dataclass
class _LoadOptions:
    """The testing machine's load file and how it is synchronised (as
    :func:`~napari_aldic.engine.probes.attach_load`)."""

    path: Path
    area_mm2: float
    load_column: str | None = None
    sync: str | None = None
    fps: float | None = None
    offset: float = 0.0


@dataclass
class LiveProbes:
    """Probe rows of a watch appended to ``csv`` (see the module text).

    ``load`` is the load file, with ``area_mm2`` (the cross-section, for the
    stress), ``load_column``, ``sync``, ``fps`` and ``offset`` as for
    :func:`~napari_aldic.engine.probes.attach_load`; ``units``, ``fields``,
    ``strain`` as for :func:`~napari_aldic.engine.probes.measure_probes`.
    """

    probes: ProbeSet
    csv: Path
    load: object = None
    area_mm2: float | None = None
    load_column: str | None = None
    sync: str | None = None
    fps: float | None = None
    offset: float = 0.0
    units: object = None
    fields: tuple = DEFAULT_FIELDS
    strain: object = None
    grace: float = 3.0
    #: rows waiting for the load: (frame, result, time measured, load file stamp tried)
    pending: list = field(default_factory=list)
    written: list = field(default_factory=list)  # frames with a row in the CSV
    _record: object = None
    _stamp: tuple | None = None
    _header: str | None = None

    def __post_init__(self):
        self.csv = Path(self.csv).expanduser()
        if self.load is not None:
            if self.area_mm2 is None:
                raise ValueError("a load file needs area_mm2 (the cross-section in mm²) "
                                 "for the stress")
            self.load = _LoadOptions(Path(self.load).expanduser(), float(self.area_mm2),
                                     self.load_column, self.sync, self.fps, self.offset)

    def start(self, run_folder) -> None:
        """Write the CSV of the frames already in ``run_folder`` (a resumed
        watch), or an empty one (header only once the first row comes)."""
        self.csv.parent.mkdir(parents=True, exist_ok=True)
        self._reload()
        try:
            table = self._table(run_folder)
        except (ValueError, FileNotFoundError):  # no frame yet
            self.csv.unlink(missing_ok=True)
            return
        lines = probe_csv_lines(table)
        self._header = lines[0]
        export_probes_csv(table, self.csv)
        self.written = [int(k) for k in table.frames]

    def add(self, k: int, res: DICResult) -> None:
        """Frame ``k`` was measured: its row is written now or when the load reaches it."""
        self.pending.append((int(k), res, time.monotonic(), None))
        self.tick()

    def tick(self) -> None:
        """Read a changed load file again and write the rows that are ready
        (a waiting row is measured again only when the load file changed)."""
        self._reload()
        while self.pending:
            k, res, t, tried = self.pending[0]
            late = time.monotonic() - t > self.grace
            if not late and tried is not None and tried == self._stamp:
                return  # nothing new since this row last waited
            table = self._table(res)
            if self.load is not None and not late and _load_missing(table):
                self.pending[0] = (k, res, t, self._stamp)
                return  # the load record has not reached this frame yet
            self._append(probe_csv_lines(table))
            self.written.append(k)
            self.pending.pop(0)

    def close(self, run_folder) -> None:
        """The watch ended: rows still waiting, then the whole CSV (and its
        sidecar) written from ``run_folder`` as ``napari-aldic probe`` does."""
        self.grace = 0.0
        self.tick()
        try:
            export_probes_csv(self._table(run_folder), self.csv)
        except (ValueError, FileNotFoundError):
            pass  # nothing measured

    # ------------------------------------------------------------ helpers
    def _table(self, data):
        kw = {"fields": self.fields} if self.fields else {}
        table = measure_probes(data, self.probes, strain=self.strain, units=self.units, **kw)
        if self.load is not None and self._record is not None:
            attach_load(table, self._record, area_mm2=self.load.area_mm2,
                        sync=self.load.sync, fps=self.load.fps, offset=self.load.offset)
        elif self.load is not None:  # no readable load record yet: the columns, empty
            n = len(table.frames)
            why = [f"no load record read from {self.load.path} yet"] * n
            for name, unit in (("load_N", "N"), ("stress_MPa", "MPa")):
                table.add(Column(name, "load", np.full(n, np.nan), unit,
                                 np.full(n, MISSING, np.int8), list(why), "load"))
        return table

    def _append(self, lines: list[str]) -> None:
        """The last row of ``lines`` appended (with the header on a new file)."""
        new = not self.csv.exists() or self.csv.stat().st_size == 0
        if not new and self._header is not None and lines[0] != self._header:
            raise ValueError(f"{self.csv}: the probe columns changed during the watch")
        text = ("\n".join([lines[0], lines[-1]]) if new else lines[-1]) + "\n"
        with open(self.csv, "a", encoding="utf-8") as fh:
            fh.write(text)  # one write per row: a reader sees whole lines
            fh.flush()
        self._header = lines[0]

    def _reload(self) -> None:
        """Read the load file again when its size or time changed (its
        complete lines only: the machine may be writing the last one)."""
        if self.load is None:
            return
        path = Path(self.load.path).expanduser()
        try:
            st = path.stat()
        except OSError:
            return  # not there yet
        stamp = (st.st_size, st.st_mtime_ns)
        if stamp == self._stamp:
            return
        text = path.read_bytes()
        text = text[:text.rfind(b"\n") + 1]
        fd, tmp = tempfile.mkstemp(suffix=path.suffix or ".csv")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(text)
            record = read_load_csv(tmp, load_column=self.load.load_column)
        except ValueError:
            return  # too short yet, or being rewritten: read it at the next change
        finally:
            os.unlink(tmp)
        record.source = str(path)
        self._record, self._stamp = record, stamp


def _load_missing(table) -> bool:
    """Whether the last frame's load is missing (or no load is attached yet)."""
    return int(table.columns["load_N"].status[-1]) == MISSING
