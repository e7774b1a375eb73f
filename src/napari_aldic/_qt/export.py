"""The Export panel: every file the engine writes, from the results in the viewer.

Results reopen in napari (``.npz``: a file for a pair, a folder of frames for a
sequence); the engine's exports (CSV, MATLAB, VTU, DaVis text, PNG, GIF, MP4,
PDF report, see ``docs/exports.md``) are written with the units of the Units
panel and the strain of the run. The button exports in a worker thread (a
report or a video takes seconds); :meth:`ExportPanel.export` does the same at
once, for scripts and tests.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from magicgui.widgets import ComboBox, FloatSpinBox, Label, PushButton
from psygnal import Signal

from .._writer import save_analysis
from ..engine import export_result
from ..i18n import tr, tr_noop
from .controls import Panel

__all__ = ["ExportPanel", "FORMATS", "FIELDS"]

#: format -> (choice text, file suffix, file-dialog filter)
FORMATS = {
    "npz": (tr_noop("Results (.npz; reopen in napari)"), ".npz",
            tr_noop("napari-aldic results (*.npz)")),
    "csv": (tr_noop("CSV table, one row per node (.csv)"), ".csv", tr_noop("CSV (*.csv)")),
    "mat": (tr_noop("MATLAB (.mat)"), ".mat", tr_noop("MATLAB (*.mat)")),
    "vtu": (tr_noop("ParaView / VTK mesh (.vtu)"), ".vtu",
            tr_noop("VTK unstructured grid (*.vtu)")),
    "davis": (tr_noop("DaVis vectors for DefDAP, pixels (.txt)"), ".txt",
              tr_noop("DaVis text (*.txt)")),
    "png": (tr_noop("PNG picture of a field (.png)"), ".png", tr_noop("PNG (*.png)")),
    "gif": (tr_noop("Animated GIF of a field (.gif)"), ".gif", tr_noop("GIF (*.gif)")),
    "mp4": (tr_noop("MP4 video of a field (.mp4)"), ".mp4", tr_noop("MP4 video (*.mp4)")),
    "pdf": (tr_noop("PDF report (.pdf)"), ".pdf", tr_noop("PDF (*.pdf)")),
}
#: fields of the pictures (the engine's names) and their choice texts
FIELDS = {"u": "u", "v": "v", "magnitude": "|u|", "exx": "exx", "eyy": "eyy", "exy": "exy",
          "von_mises": tr_noop("von Mises"), "e1": "e1", "e2": "e2",
          "max_shear": tr_noop("max shear"), "rotation": tr_noop("rotation"), "zncc": "ZNCC"}
_PICTURES = ("png", "gif", "mp4")


class ExportPanel(Panel):
    """Format, field, frames, frame rate and the Export button.

    Parameters
    ----------
    analysis : callable() -> Analysis or None
        The analysis shown in the viewer.
    units : callable() -> Units
        The units of the Units panel (``ValueError`` when they are not valid).
    current_frame : callable() -> int or None
        The stack frame the viewer shows.
    log : callable(str)
    probes : callable() -> ProbeTable or None, optional
        The probes measured on the analysis: the PDF report gets their page.

    Signals
    -------
    exported(list)
        Paths written by the button's export.
    """

    exported = Signal(list)

    def __init__(self, analysis: Callable[[], Any], units: Callable[[], Any],
                 current_frame: Callable[[], int | None], log: Callable[[str], None],
                 probes: Callable[[], Any] | None = None):
        self._analysis, self._units, self._probes = analysis, units, probes
        self._current_frame, self._log = current_frame, log
        self._worker = None
        self._folder: Path | None = None
        super().__init__()

    def _setup_ui(self) -> None:
        self.format = ComboBox(label=tr("Format"), value="npz",
                               choices=[(tr(text), key) for key, (text, _, _) in FORMATS.items()])
        self.field = ComboBox(label=tr("Field"), value="u",
                              choices=[(tr(text), key) for key, text in FIELDS.items()],
                              tooltip=tr("The field drawn in PNG, GIF and MP4 exports."))
        self.frames = ComboBox(label=tr("Frames"), value="all",
                               choices=[(tr("all computed frames"), "all"),
                                        (tr("the frame shown"), "shown")],
                               tooltip=tr("Every computed frame, or the one the frame slider "
                                       "shows."))
        self.fps = FloatSpinBox(label=tr("Frames per second"), value=4.0, min=0.1, max=60.0,
                                step=0.5, tooltip=tr("GIF and MP4 speed."))
        self.units_note = Label(value="")
        self.export_button = PushButton(text=tr("Export…"), enabled=False,
                                        tooltip=tr("Choose a file and write the results in the "
                                                "chosen format."))
        self.extend([self.format, self.field, self.frames, self.fps, self.units_note,
                     self.export_button])
        from qtpy.QtWidgets import QSizePolicy

        self.units_note.native.setWordWrap(True)
        self.units_note.native.setSizePolicy(QSizePolicy.Policy.Preferred,
                                             QSizePolicy.Policy.Minimum)
        self.units_note.native.setMinimumWidth(120)
        self._on_format()

    def _setup_callbacks(self) -> None:
        self.format.changed.connect(self._on_format)
        self.export_button.changed.connect(self._on_export_clicked)

    def _on_format(self, *_) -> None:
        fmt = self.format.value
        # the whole choice on hover too (a narrow dock may cut it)
        self.format.tooltip = self.format.native.currentText() + "\n" + tr(
            "Results reopen in napari (File > Open); the others are the engine's exports, "
            "described in docs/exports.md.")
        self.field.enabled = fmt in _PICTURES
        self.fps.enabled = fmt in ("gif", "mp4")
        self.frames.enabled = fmt != "npz"
        self.refresh()

    def refresh(self) -> None:
        """Enable Export when there are results; say in which units they go out."""
        a = self._analysis()
        self.export_button.enabled = a is not None and self._worker is None
        try:
            u = self._units()
        except ValueError as exc:
            self.units_note.value = tr("Units: {exc}").format(exc=exc)
            return
        fmt = self.format.value
        if fmt == "davis":
            text = tr("Values in pixels (DefDAP applies its own scale).")
        else:
            if u.unit != "px":
                text = tr("Lengths in {unit} (pixel size {pixel_size:g} {unit})").format(
                    pixel_size=u.pixel_size, unit=u.unit)
            else:
                text = tr("Lengths in {unit}").format(unit=u.unit)
            text += (tr(", time in {time_unit}.").format(time_unit=u.time_unit) if u.has_time
                     else tr("; frame numbers."))
        self.units_note.value = text

    # ------------------------------------------------------------ exporting
    def export(self, path, fmt: str | None = None, field: str | None = None,
               frames: str | None = None, probes: Any = None) -> list[Path]:
        """Write the results shown to ``path`` in format ``fmt`` (default: the
        panel's); returns the paths written. Raises ``ValueError`` without
        results or with invalid units, and the engine's errors. A PDF report has
        a page of the probes (``probes``, a ProbeTable; default: those measured now)."""
        analysis = self._analysis()
        if analysis is None:
            raise ValueError(tr("there are no results to export: run an analysis first"))
        fmt = fmt or self.format.value
        if fmt not in FORMATS:
            raise ValueError(tr("unknown export format {fmt!r}; choose one of {list}").format(
                                    fmt=fmt, list=list(FORMATS)))
        units = self._units()
        if fmt == "npz":
            return [Path(p) for p in save_analysis(analysis, path, units)]
        pairs = [(r, s) for r, s in zip(analysis.results, analysis.strains) if r is not None]
        results, strains = [r for r, _ in pairs], [s for _, s in pairs]
        options: dict[str, Any] = {"frames": self._frame_choice(frames)}
        if fmt != "davis":
            options["units"] = units
            options["strain"] = strains if all(s is not None for s in strains) else \
                {"window": analysis.strain.window, "method": analysis.strain.method,
                 "measure": analysis.strain.measure}
        if fmt in _PICTURES:
            options["field"] = field or self.field.value
        if fmt in ("gif", "mp4"):
            options["fps"] = float(self.fps.value)
        if fmt == "pdf":
            probes = probes if probes is not None else self.probe_table()
            if probes is not None:
                options["probes"] = probes
        out = export_result(results, path, to=fmt, **options)
        return [Path(p) for p in out] if isinstance(out, (list, tuple)) else [Path(out)]

    def probe_table(self):
        """The probes measured on the analysis now (None: none, or they cannot be)."""
        try:
            return self._probes() if self._probes is not None else None
        except (ValueError, TypeError) as exc:
            self._log(tr("the report has no probe page: {exc}").format(exc=exc))
            return None

    def _frame_choice(self, frames: str | None) -> list[int] | None:
        """The frame numbers to export (``None``: all)."""
        if (frames or self.frames.value) != "shown":
            return None
        k = self._current_frame()
        analysis = self._analysis()
        done = [f for f, r in zip(analysis.frames, analysis.results) if r is not None]
        if k not in done:
            raise ValueError(tr("frame {k} has no result; computed frames: {done}").format(
                                    k=k, done=done))
        return [int(k)]

    def _on_export_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        fmt = self.format.value
        _, suffix, filt = FORMATS[fmt]
        analysis = self._analysis()
        stem = Path(str(getattr(analysis, "source", "") or "dic")).stem or "dic"
        folder = self._folder or Path.cwd()
        path, _ = QFileDialog.getSaveFileName(self.native, tr("Export DIC results"),
                                              str(folder / f"{stem}_dic{suffix}"),
                                              tr(filt) + ";;" + tr("All files (*)"))
        if path:
            self.export_in_background(path, fmt)

    def export_in_background(self, path, fmt: str | None = None) -> None:
        """:meth:`export` in a worker thread; the log says what was written."""
        from napari.qt.threading import create_worker
        from superqt.utils import FunctionWorker

        fmt = fmt or self.format.value
        field, frames = self.field.value, self.frames.value
        self._folder = Path(path).parent
        self._log(tr("exporting {what} to {path} ...").format(what=tr(FORMATS[fmt][0]),
                                                                    path=path))
        probes = self.probe_table() if fmt == "pdf" else None  # read here, not in the worker
        worker = create_worker(self.export, path, fmt, field, frames, probes,
                               _worker_class=FunctionWorker, _ignore_errors=True)
        worker.returned.connect(self._on_exported)
        worker.errored.connect(self._on_failed)
        worker.finished.connect(self._on_finished)
        self._worker = worker
        self.export_button.enabled = False
        worker.start()

    def _on_exported(self, paths: list) -> None:
        shown = ", ".join(str(p) for p in paths[:3]) + (" ..." if len(paths) > 3 else "")
        self._log(tr("exported {n_paths} file(s): {shown}").format(
                         n_paths=len(paths), shown=shown))
        self.exported.emit(list(paths))

    def _on_failed(self, exc: BaseException) -> None:
        from napari.utils.notifications import show_error

        msg = str(exc) or exc.__class__.__name__
        self._log(tr("ERROR exporting: {msg}").format(msg=msg))
        show_error(tr("napari-aldic: could not export: {msg}").format(msg=msg))

    def _on_finished(self) -> None:
        self._worker = None
        self.refresh()
