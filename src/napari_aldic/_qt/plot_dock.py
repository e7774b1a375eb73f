"""The probe plot dock: curves of probes over the frames and the stress-strain curve.

Probes (Shapes: line = gauge, rectangle/ellipse/polygon = area; Points) are measured on
the analysis behind the ``DIC ...`` layers, again when a probe or the results change.
Clicking the plot moves the frame slider; a machine CSV adds the stress-strain curve.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from qtpy.QtCore import QTimer
from qtpy.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QPushButton,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from ..engine.probes import (
    LINE_QUANTITIES,
    attach_load,
    draw_probe_curves,
    draw_stress_strain,
    export_probe_plot,
    export_probes_csv,
    read_load_csv,
)
from ..i18n import tr, tr_noop
from .gauges import chosen_gauge, deformed_hint, fill_gauges, probe_messages, said, translate_axes
from .language import apply_ui_language, combo_of, follow_language, plot_fonts, retranslate_tree
from .plot_parts import PlotCanvas, StatusText, WrappedLabel, report_saved, scrolled
from .probes import (
    PROBE_POINTS,
    PROBE_SHAPES,
    find_analysis,
    is_probe_candidate,
    measure_analysis,
    probes_from_layers,
)
from .project import PROBE_KEY
from .project_results import LOAD_OPTIONS, keep_load, kept_load

__all__ = ["ProbePlotDock"]

NONE = tr_noop("(none)")
FIELDS = ("u", "v", "magnitude", "exx", "eyy", "exy", "von_mises")
DOCK_STYLE = {"font.size": 7.5, "axes.titlesize": 8, "axes.labelsize": 7.5,
              "legend.fontsize": 6.5, "xtick.labelsize": 7, "ytick.labelsize": 7}


class ProbePlotDock(QWidget):
    """Probe curves over the frames (napari dock widget)."""

    def __init__(self, napari_viewer):
        apply_ui_language()  # before any text is made
        super().__init__()
        self._viewer = napari_viewer
        self.view, self.table = None, None  # ResultView of the analysis, ProbeTable measured
        self.load_record = None
        self.message = ""
        self._hooks: list = []  # (emitter, callback) of the watched layers
        self.axes: dict = {}  # "lines", "spatial", "stress" -> the matplotlib axes shown
        self._ss_column = ""  # the strain of the stress-strain curve
        # a dragged probe fires many events: measure once
        self._timer = QTimer(self, singleShot=True, interval=150)
        self._timer.timeout.connect(self.recompute)
        self._setup_ui()  # and a new language said at once ("(none)", status, plot anew):
        follow_language(self, lambda dock, rt: (retranslate_tree(dock, rt),
                                                dock._on_layers_changed()))
        layers = napari_viewer.layers
        layers.events.inserted.connect(self._on_layers_changed)
        layers.events.removed.connect(self._on_layers_changed)
        napari_viewer.dims.events.current_step.connect(self._on_frame)
        self.destroyed.connect(lambda *_: self._unhook_all(layers, napari_viewer.dims))
        self._on_layers_changed()

    # ------------------------------------------------------------ UI
    def _setup_ui(self) -> None:
        self.shapes_combo, self.points_combo = QComboBox(), QComboBox()
        self.add_button = QPushButton(tr("Add probe layers"))
        self.quantity_combo, self.field_combo = QComboBox(), QComboBox()
        self.quantity_combo.addItems(list(LINE_QUANTITIES))
        self.field_combo.addItems(list(FIELDS))
        form = QFormLayout()
        form.addRow(tr("Gauges, areas (Shapes)"), self.shapes_combo)
        form.addRow(tr("Point probes (Points)"), self.points_combo)
        form.addRow("", self.add_button)
        form.addRow(tr("Line gauges show"), self.quantity_combo)
        form.addRow(tr("Points, areas show"), self.field_combo)
        self.load_button = QPushButton(tr("Load CSV..."))
        self.load_label = WrappedLabel(tr("no load data"))
        self.load_label.setWordWrap(True)  # a long file description never widens the dock
        self.load_label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        self.load_label.setMinimumWidth(40)  # not the width of its longest word (a file name)
        self.area_spin = QDoubleSpinBox(decimals=3, minimum=0.001, maximum=1e7, value=10.0,
                                        suffix=" mm²")
        self.sync_combo = combo_of([(tr("frame"), "frame"), (tr("time"), "time")])
        self.fps_spin = QDoubleSpinBox(decimals=4, minimum=0.0001, maximum=1e6, value=1.0)
        self.offset_spin = QDoubleSpinBox(decimals=4, minimum=-1e6, maximum=1e6, value=0.0,
                                          suffix=" s")
        self.gauge_combo = QComboBox()  # the gauge of the stress-strain curve
        load_form = QFormLayout()
        load_form.addRow(self.load_button, self.load_label)
        load_form.addRow(tr("Cross-section"), self.area_spin)
        load_form.addRow(tr("Synchronise by"), self.sync_combo)
        load_form.addRow(tr("Camera fps"), self.fps_spin)
        load_form.addRow(tr("Time of frame 0"), self.offset_spin)
        load_form.addRow(tr("Gauge"), self.gauge_combo)
        load_box = QGroupBox(tr("Testing machine (stress-strain)"))
        load_box.setLayout(load_form)
        self.figure = Figure(figsize=(4.5, 4.0), layout="constrained")
        self.canvas = PlotCanvas(self.figure)
        self.canvas.setMinimumHeight(140)  # the DIC dock above keeps rows (1600 x 1000)
        self.status_label = StatusText()  # its own scrolling box under the plot (trap 7)
        self.save_csv_button, self.save_plot_button = QPushButton(tr("Save CSV...")), \
            QPushButton(tr("Save plot..."))
        buttons = QHBoxLayout()
        _ = [buttons.addWidget(b) for b in (self.save_csv_button, self.save_plot_button)]
        inner = QWidget()
        lay = QVBoxLayout(inner)
        lay.addLayout(form)
        lay.addWidget(load_box)
        lay.addWidget(self.canvas, 1)
        lay.addWidget(self.status_label)
        lay.addLayout(buttons)
        outer = QVBoxLayout(self)  # a low window scrolls the dock: nothing drawn over another
        outer.setContentsMargins(0, 0, 0, 0)
        outer.addWidget(scrolled(inner))
        for combo in (self.shapes_combo, self.points_combo):
            combo.currentTextChanged.connect(self._on_probe_layers_chosen)
        for combo in (self.quantity_combo, self.field_combo, self.gauge_combo):
            combo.currentTextChanged.connect(lambda *_: self.redraw())
        for w in (self.area_spin, self.fps_spin, self.offset_spin):
            w.valueChanged.connect(self.schedule)
        self.sync_combo.currentTextChanged.connect(self.schedule)
        self.add_button.clicked.connect(self.add_probe_layers)
        self.load_button.clicked.connect(self._ask_load)
        self.save_csv_button.clicked.connect(lambda: self._ask_save(tr("Save probe values"),
                                                                    tr("CSV (*.csv)")))
        self.save_plot_button.clicked.connect(lambda: self._ask_save(
            tr("Save probe plot"), "PNG (*.png);;PDF (*.pdf)", self.save_plot))
        self.canvas.mpl_connect("button_press_event", self._on_click)

    # ------------------------------------------------------------ layers
    def _layer(self, combo: QComboBox):
        name = combo.currentText()
        layers = self._viewer.layers
        return layers[name] if name != tr(NONE) and name in layers else None

    @property
    def shapes_layer(self):
        return self._layer(self.shapes_combo)

    @property
    def points_layer(self):
        return self._layer(self.points_combo)

    def _fill(self, combo: QComboBox, kind: str) -> None:
        names = [lay.name for lay in self._viewer.layers
                 if is_probe_candidate(lay) and lay.__class__.__name__ == kind]
        keep = combo.currentText()
        combo.blockSignals(True)
        combo.clear()
        combo.addItems([tr(NONE), *names])
        preferred = PROBE_SHAPES if kind == "Shapes" else PROBE_POINTS
        pick = keep if keep in names else (preferred if preferred in names else tr(NONE))
        combo.setCurrentText(pick)
        combo.blockSignals(False)

    def _on_layers_changed(self, *_) -> None:
        self._fill(self.shapes_combo, "Shapes")
        self._fill(self.points_combo, "Points")
        self._rehook()
        self.schedule()

    def _on_probe_layers_chosen(self, *_) -> None:
        # a layer chosen here measures: mark it so the main widget never takes it as ROI
        # or seeds and project files keep it as a probe
        for lay in (self.shapes_layer, self.points_layer):
            if lay is not None and PROBE_KEY not in lay.metadata:
                lay.metadata = {**lay.metadata, PROBE_KEY: True}
        self._rehook()
        self.schedule()

    def set_probe_layers(self, shapes=None, points=None) -> None:
        """Use these layers (or None) as the probes."""
        self.shapes_combo.setCurrentText(shapes.name if shapes is not None else tr(NONE))
        self.points_combo.setCurrentText(points.name if points is not None else tr(NONE))

    def add_probe_layers(self) -> None:
        """Add empty probe layers (a Shapes layer in line mode, a Points layer)."""
        v = self._viewer
        if PROBE_POINTS not in v.layers:
            v.add_points(np.zeros((0, 2)), name=PROBE_POINTS, size=8, face_color="cyan",
                         metadata={PROBE_KEY: True})
        if PROBE_SHAPES not in v.layers:
            # marked as probes: never offered as ROI/seeds, saved with the project
            shapes = v.add_shapes(name=PROBE_SHAPES, edge_color="yellow", edge_width=2,
                                  face_color="transparent", metadata={PROBE_KEY: True})
            shapes.mode = "add_line"
        self.set_probe_layers(v.layers[PROBE_SHAPES], v.layers[PROBE_POINTS])

    def _unhook_all(self, layers=None, dims=None) -> None:
        for emitter, cb in self._hooks:
            emitter.disconnect(cb)
        self._hooks = []
        if layers is not None:
            layers.events.inserted.disconnect(self._on_layers_changed)
            layers.events.removed.disconnect(self._on_layers_changed)
            dims.events.current_step.disconnect(self._on_frame)

    def _rehook(self) -> None:
        """Watch the probe layers and the result layers for changes."""
        self._unhook_all()
        watched = [lay for lay in self._viewer.layers if str(lay.name).startswith("DIC ")]
        watched += [lay for lay in (self.shapes_layer, self.points_layer) if lay is not None]
        for lay in watched:
            for ev in ("data", "metadata"):
                emitter = getattr(lay.events, ev, None)
                if emitter is not None:
                    emitter.connect(self.schedule)
                    self._hooks.append((emitter, self.schedule))

    # ------------------------------------------------------------ measuring
    def schedule(self, *_) -> None:
        """Measure again shortly (events of a dragged probe come in bursts)."""
        self._timer.start()

    def recompute(self) -> None:
        """Measure the probes on the analysis in the viewer and redraw."""
        kept = kept_load(self.shapes_layer) if self.load_record is None else None
        if kept and self.load_csv(kept["path"], **{k: kept.get(k) for k in LOAD_OPTIONS}):
            return  # a project's load file, read again (it measured)
        self.view = find_analysis(self._viewer.layers)
        self.table, notes = None, []
        if self.view is None:
            self.message = tr("No result layers: run an analysis or open a result.")
        else:
            try:
                probes, notes = probes_from_layers(self.shapes_layer, self.points_layer,
                                                   self.view)
                if len(probes):
                    self.table = measure_analysis(self.view, probes)
                    self._attach_load()
                    self.message = "\n".join(probe_messages(self.table)) or tr(
                        "{n} frames, every probe value trusted.").format(n=len(self.table))
                    notes += deformed_hint(self.view)
                else:
                    self.message = tr("Draw probes: a line (gauge) or a rectangle/ellipse/"
                                      "polygon (area) in a Shapes layer, points in a Points "
                                      "layer ('Add probe layers').")
            except (ValueError, TypeError) as exc:
                self.message = tr("Cannot measure the probes: {exc}").format(exc=exc)
        self.status_label.setText("\n".join([self.message, *notes]))
        fill_gauges(self.gauge_combo, self.table)
        self.redraw()

    def _attach_load(self) -> None:
        if self.load_record is None or self.table is None:
            return
        sync = self.sync_combo.currentData()
        keep_load(self.shapes_layer, {"path": str(self.load_record.source), "sync": sync,
                                      "area_mm2": self.area_spin.value(), "fps":
                                      self.fps_spin.value(), "offset": self.offset_spin.value()})
        try:
            attach_load(self.table, self.load_record, area_mm2=self.area_spin.value(),
                        sync=sync, fps=self.fps_spin.value(), offset=self.offset_spin.value())
        except ValueError as exc:
            self.load_label.setText(tr("load not used: {exc}").format(exc=exc))

    def load_csv(self, path, *, area_mm2: float | None = None, sync: str | None = None,
                 fps: float | None = None, offset: float | None = None) -> bool:
        """Read a testing-machine CSV (and set the synchronisation); False on an error."""
        for w, v in ((self.area_spin, area_mm2), (self.fps_spin, fps),
                     (self.offset_spin, offset)):
            if v is not None:
                w.setValue(float(v))
        try:
            self.load_record = read_load_csv(path)
        except (ValueError, OSError) as exc:
            self.load_record = None
            self.load_label.setText(tr("error: {exc}").format(exc=exc))
            return False
        sync = sync or ("frame" if self.load_record.frame is not None else "time")
        self.sync_combo.setCurrentIndex(max(0, self.sync_combo.findData(sync)))
        self.load_label.setText(said(self.load_record.describe()))  # the engine's English
        self.load_label.setToolTip(f"{self.load_record.source}\n{self.load_label.text()}")
        self.recompute()
        return True

    # ------------------------------------------------------------ plotting
    def curve_columns(self) -> tuple[list[str], list[str]]:
        """(line gauge columns, point/area columns) shown."""
        if self.table is None:
            return [], []
        q, f = self.quantity_combo.currentText(), self.field_combo.currentText()
        cols = self.table.columns
        lines = [n for n in cols if n.startswith("line") and n.endswith(f"_{q}")
                 and n.split("_", 1)[1] == q]
        spatial = [n for n in cols if n.startswith("point") and n.split("_", 1)[1] == f]
        spatial += [n for n in cols if n.startswith("area") and n.split("_", 1)[1] ==
                    f"{f}_mean"]
        return lines, spatial

    def current_frame(self) -> int | None:
        if self.view is None:
            return None
        if self.view.t_scale is None:
            return int(self.view.analysis.frames[-1])
        axis = self._viewer.dims.ndim - 3
        return self.view.frame_at(float(self._viewer.dims.point[axis]))

    def redraw(self) -> None:
        """Draw the curves (and the stress-strain curve) with the current frame marked."""
        import matplotlib

        with matplotlib.rc_context({**DOCK_STYLE, **plot_fonts()}):  # small text; CJK
            self._draw()
        self.canvas.draw_idle()

    def _draw(self) -> None:
        fig = self.figure
        fig.clear()
        self.axes = {}
        lines, spatial = self.curve_columns()
        stress = self.table is not None and "stress_MPa" in self.table.columns and lines
        panels = [p for p in (("lines", lines), ("spatial", spatial)) if p[1]]
        n = len(panels) + bool(stress)
        if n == 0:
            ax = fig.add_subplot()
            ax.text(0.5, 0.5, tr("no probe values"), ha="center", va="center", color="0.4")
            ax.set_axis_off()
        else:
            axes = fig.subplots(n, 1, squeeze=False)[:, 0]
            k = self.current_frame()
            for ax, (key, names) in zip(axes, panels):
                draw_probe_curves(ax, self.table, names, current=k)
                self.axes[key] = ax
            if stress:  # against the engineering strain of the gauge chosen
                self._ss_column = chosen_gauge(self.gauge_combo, self.table)
                draw_stress_strain(axes[-1], self.table, self._ss_column, current=k)
                self.axes["stress"] = axes[-1]
            translate_axes(axes)

    def _on_frame(self, *_) -> None:
        if self.table is not None:
            self.redraw()

    def go_to_frame(self, frame: int) -> None:
        """Move the viewer's frame slider to ``frame``."""
        if self.view is None or self.view.t_scale is None:
            return
        self._viewer.dims.set_point(self._viewer.dims.ndim - 3, self.view.world_time(frame))

    def _on_click(self, event) -> None:
        if self.table is None or event.inaxes is None or event.xdata is None:
            return
        frames = self.table.frames
        if event.inaxes is self.axes.get("stress"):
            pts = event.inaxes.transData.transform(
                np.column_stack([self.table[self._ss_column], self.table["stress_MPa"]]))
            d = np.hypot(pts[:, 0] - event.x, pts[:, 1] - event.y)
            if np.all(np.isnan(d)):
                return
            self.go_to_frame(int(frames[int(np.nanargmin(d))]))
        else:
            self.go_to_frame(int(frames[int(np.argmin(np.abs(frames - event.xdata)))]))

    # ------------------------------------------------------------ saving
    def save_csv(self, path) -> Path | None:
        return None if self.table is None else export_probes_csv(self.table, path)

    def save_plot(self, path) -> Path | None:
        return None if self.table is None else export_probe_plot(self.table, path)

    def _ask(self, title: str, filt: str, save: bool = True) -> str:
        fn = QFileDialog.getSaveFileName if save else QFileDialog.getOpenFileName
        return fn(self, title, "", filt)[0]

    def _ask_load(self) -> None:
        if path := self._ask(tr("Testing-machine CSV"),
                             tr("CSV or text (*.csv *.txt *.tsv *.dat)"), save=False):
            self.load_csv(path)

    def _ask_save(self, title: str, filt: str, fn=None) -> None:
        if path := self._ask(title, filt):
            report_saved(fn or self.save_csv, path)
