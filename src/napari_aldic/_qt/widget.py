"""The dock widget: the panels, composed and wired together.

Collapsible sections in one scroll area (the order a first analysis takes), the run
controls below it, always in view; each panel is its own class, connected here.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.widgets import Container

from .._analysis import Analysis, Job
from ..engine import DICParams
from ..i18n import tr, tr_noop
from . import warmup
from .advice import start_advice
from .checks import Choices, problems
from .controls import align_labels
from .correlation import CorrelationPanel
from .display import DisplayPanel
from .explain import with_explanation
from .export import ExportPanel
from .inputs import InputsPanel
from .language import LanguageSelector, apply_ui_language, follow_language, retranslate_tree
from .layout import divider, sections_area
from .live import LivePanel
from .model import DockModel
from .probes import probe_table
from .project import is_probe_layer
from .results import ResultLayers, geometry_of, prepare
from .run import RunPanel
from .sem import SEMPanel
from .settings import SettingsPanel
from .strain import StrainPanel
from .units import UnitsPanel
from .volume import VolumePanel

if TYPE_CHECKING:  # pragma: no cover
    import napari

__all__ = ["DICWidget", "SECTIONS"]

#: the panels' controls, also attributes of the widget (``widget.subset``,
#: ``widget.image`` ...) for scripts and tests
CONTROLS = {
    "inputs": ("image", "roi_add", "roi_subtract", "roi_labels", "brush", "seeds"),
    "correlation": ("method", "subset", "step", "search", "refine", "smooth", "smooth_px",
                    "shape_function", "init", "reference", "start", "stop", "stride"),
    "strain_panel": ("strain_window", "strain_method", "strain_measure"),
    "units": ("pixel_size", "unit", "frame_interval", "time_unit"),
    "display": ("show_field", "vectors", "vector_length", "mesh", "deformed", "rigid"),
    "settings": ("save_params_button", "load_params_button", "save_project_button",
                 "open_project_button", "defaults_button"),
    "run_panel": ("status", "run_button", "cancel_button", "progress", "eta", "log"),
}
#: the sections, top to bottom: (title, panel attribute, expanded at first)
#: (the titles are the keys of ``widget.sections``; they are shown translated)
SECTIONS = ((tr_noop("1. Images and region"), "inputs", True),
            (tr_noop("2. Mesh and correlation"), "correlation", True),
            (tr_noop("3. Strain"), "strain_panel", False),
            (tr_noop("4. Units"), "units", False),
            (tr_noop("5. Display"), "display", True),
            (tr_noop("6. Export"), "exports", False),
            (tr_noop("Project and parameters"), "settings", False),
            (tr_noop("Live (watch a camera folder)"), "live", False),
            (tr_noop("Volume (DVC)"), "volume", False),
            (tr_noop("SEM corrections (HRDIC)"), "sem", False),
            (tr_noop("Log"), "log", True))
#: the panels whose labels share one column
ALIGNED = ("inputs", "correlation", "strain_panel", "units", "display", "exports", "volume", "sem")


class DICWidget(Container):
    """Digital image correlation of an image stack (napari-aldic)."""

    def __init__(self, napari_viewer: napari.viewer.Viewer):
        apply_ui_language()  # before any text is made
        super().__init__(labels=False)
        self._viewer = napari_viewer
        self._errors: list[str] = []
        #: the analysis set up in the dock: the panels write it, Run reads its job
        self.model = DockModel()
        self._setup_ui()
        self._setup_callbacks()
        self.inputs.assign_existing_layers()
        self._on_image_changed()
        self.settings.restore_last_used()
        self._results.adopt(self.correlation.init) and self.exports.refresh()  # reopened
        follow_language(self, DICWidget.retranslate)  # a new language applies at once
        warmup.start_in_background(self.run_panel.set_preparing, self._on_engine_ready,
                                   self.native)

    def _setup_ui(self) -> None:
        self.inputs = InputsPanel(self._viewer)
        self.correlation = CorrelationPanel()
        self.strain_panel = StrainPanel()
        self.units = UnitsPanel()
        self.display = DisplayPanel()
        self.run_panel = RunPanel()
        self._results = ResultLayers(self._viewer)
        self.exports = ExportPanel(lambda: self._results.analysis, lambda: self.units.units,
                                   self._current_frame, self.run_panel.write_log,
                                   lambda: probe_table(self._viewer.layers))
        self.settings = SettingsPanel(self.model, self.inputs, self.correlation, self.strain_panel,
                                      self.units, self.display, log=self.run_panel.write_log,
                                      apply_units=self._apply_units, viewer=self._viewer)
        self.live = LivePanel(self._viewer, lambda: (  # issue 26: live mode, its own panel
            self._current_params(), self.strain_panel.as_dict(),
            self.correlation.reference.value), self._display_options, self._results)
        self.volume = VolumePanel(self._viewer)  # issue 28: 3-D volumes, its own section
        self.sem = SEMPanel(self.model)  # issue 27: SEM corrections, kept in the model
        self.language = LanguageSelector()
        self.settings.append(self.language)
        for panel, names in CONTROLS.items():
            for name in names:
                setattr(self, name, getattr(getattr(self, panel), name))
        align_labels([getattr(self, name) for name in ALIGNED])
        sections = [(title, getattr(self, attr).native, open_)
                    for title, attr, open_ in SECTIONS]
        self.scroll_area, self.sections = sections_area(sections)
        layout = self.native.layout()
        layout.addWidget(self.scroll_area, 1)
        layout.addWidget(divider(), 0)
        layout.addWidget(self.run_panel.native, 0)
        layout.setContentsMargins(0, 0, 0, 0)

    def _setup_callbacks(self) -> None:
        for panel in (self.correlation, self.strain_panel, self.units, self.display):
            panel.changed.connect(self._write_model)  # any control of the panel
        self._write_model()
        self.settings.sync = self._write_model
        # the export note says the model's units, whichever way they changed
        self.model.changed.connect(lambda part: part == "units" and self.exports.refresh())
        self.inputs.image.changed.connect(self._on_image_changed)
        self.inputs.inputs_changed.connect(self._validate)
        self.inputs.seeds_assigned.connect(self._use_seeds)
        self.correlation.settings_changed.connect(self._validate)
        self.correlation.advise_requested.connect(lambda: start_advice(self))
        self.strain_panel.settings_changed.connect(self._validate)
        self.units.units_changed.connect(self._apply_units)
        self.display.display_changed.connect(self._refresh_results)
        self.display.field_chosen.connect(self._results.show_field)
        self.display.vector_length_changed.connect(self._on_vector_length)
        self.settings.settings_loaded.connect(self._validate)
        self.settings.project_opened.connect(self._on_project_opened)
        self.run_panel.run_requested.connect(self.run)
        self.run_panel.running_changed.connect(self._on_running)
        self.live.watch_run(self.run_panel)  # one analysis at a time, its status said
        self.run_panel.show_results = self._show_steps
        # closing the widget stops a run after its frame and unhooks it from the viewer
        # (the slot holds no reference to the widget, which may be torn down by then)
        stop, unhook = self.run_panel.stopper(), self.inputs.disconnector()
        self.native.destroyed.connect(lambda *_: (stop(), unhook()))
        self._remember = self.settings.remember_last_used

    # ------------------------------------------------------------ state
    @property
    def running(self) -> bool:
        """Whether an analysis is running (its result layers not all shown yet)."""
        return self.run_panel.running

    @property
    def analysis(self) -> Analysis | None:
        """The analysis shown in the result layers."""
        return self._results.analysis

    def current_settings(self) -> dict[str, Any]:
        """The controls' settings: the fields of a :class:`~napari_aldic.engine.Settings`;
        ``ValueError`` when they make none (an even subset, a pixel size in 'px' ...)."""
        s = self.settings.current()
        return {"params": s.params, "units": s.units, "strain": s.strain, "tracking": s.tracking}

    def _current_params(self) -> DICParams:
        return self.settings.current_params()

    def save_settings(self, path) -> Path | None:
        """Write the settings to the JSON file ``path`` (``.json`` appended when missing;
        read by ``napari-aldic run --params``); the path, or ``None`` after an error."""
        return self.settings.save(path)

    def load_settings(self, path) -> bool:
        """Set every control from a settings file (also ``napari-aldic params``' or a JSON
        object of DICParams fields); an invalid one changes nothing (``False``)."""
        return self.settings.load(path)

    def save_project(self, path) -> Path | None:
        """Save the analysis (image, layers, settings; results and load file beside it)."""
        return self.settings.save_project(path)

    def open_project(self, path) -> bool:
        """Open a project file: image, layers, controls and saved results restored."""
        return self.settings.open_project(path)

    def restore_defaults(self) -> None:
        """Set every parameter, unit and display control to its default."""
        self.settings.restore_defaults()

    def retranslate(self, rt) -> None:
        """Say the dock in the language just chosen; values and analysis kept (trap 5)."""
        retranslate_tree(self.native, rt)
        align_labels([getattr(self, name) for name in ALIGNED])  # their new widths
        self._validate()
        self.exports.refresh()

    # ------------------------------------------------------------ wiring
    def _write_model(self, *_) -> None:
        """The panels' values into the model (invalid ones wait for the next change)."""
        m, c = self.model, self.correlation
        try:
            m.update("params", c.params((), init="fft"))
        except ValueError:
            pass
        m.update("init", c.init.value)
        m.update("tracking", c.tracking)
        m.update("strain", self.strain_panel.settings)
        try:
            m.update("units", self.units.units)
        except ValueError:  # a pixel size in 'px': no valid units
            m.update("units", None)
        m.update("display", self.display.choices)

    def _use_seeds(self) -> None:
        self.correlation.init.value = "seeds"

    def _on_engine_ready(self, error: str | None) -> None:
        try:
            self.run_panel.set_preparing(False)
            if error:
                self.run_panel.write_log(
                    tr("preparing the correlation engine failed: {error}").format(error=error))
        except RuntimeError:  # the widget was closed meanwhile
            pass

    def _on_image_changed(self, *_) -> None:
        if self.inputs.choose_first_image():
            return  # the choice comes back here through ``image.changed``
        self.inputs.match_image()
        shape = self.inputs.stack_shape
        if shape is not None and len(shape) == 3:
            self.correlation.set_frame_count(shape[0])
        img = self.inputs.image_layer
        if img is not None and img.ndim >= 2:
            self.units.read_image(img)
        self._validate()

    def _on_project_opened(self) -> None:
        self._on_image_changed()
        if (restored := self.settings.projects.restored) is None:  # saved results (trap 16)
            return self._refresh_results()
        self._results.image = self.inputs.image_layer
        self.show_analysis(restored)

    def _apply_units(self) -> None:
        """Apply the units to the image, its input, probe and result layers."""
        self.exports.refresh()
        if self.inputs.image_layer is None:
            return
        inputs = self.inputs.input_layers
        # probe layers lie on the image too: they rescale with it (trap 3 of issue 24)
        probes = [lay for lay in self._viewer.layers
                  if is_probe_layer(lay) and not any(lay is x for x in inputs)]
        self.units.apply_to([*inputs, *probes], self._results.layers)
        p, unit = self.units.length
        self.run_panel.write_log(tr("units: pixel size {p:g} {unit}, frame interval "
                                    "{frame_interval:g} {time_unit}").format(
                                        p=p, unit=unit,
                                        frame_interval=self.units.frame_interval.value,
                                        time_unit=self.units.time_unit.value))
        self._refresh_results()

    def _on_running(self, running: bool) -> None:
        for button in (self.settings.load_params_button, self.settings.open_project_button,
                       self.settings.defaults_button):
            button.enabled = not running  # a run keeps its settings
        self._validate()
        self.exports.refresh()

    def _current_frame(self) -> int | None:
        img = self.inputs.image_layer
        if img is None or img.ndim < 3:
            return None
        axis = self._viewer.dims.ndim - img.ndim
        world = float(self._viewer.dims.point[axis])
        return int(round((world - float(img.translate[0])) / float(img.scale[0])))

    def _choices(self) -> Choices:
        c, inputs = self.correlation, self.inputs
        start = int(c.start.value)
        return Choices(image=inputs.image_layer, shape=inputs.stack_shape,
                       subset=int(c.subset.value), step=int(c.step.value),
                       window=int(self.strain_panel.strain_window.value), start=start,
                       stop=int(c.stop.value), stride=int(c.stride.value), init=c.init.value,
                       reference=c.reference.value, seeds=inputs.seeds.value,
                       brush=inputs.brush.value, roi=lambda shape: inputs.roi(shape, start))

    def _validate(self, *_) -> bool:
        try:
            errors, warns = problems(self._choices())
        except Exception as exc:  # never let a check break the widget
            errors, warns = [tr("Cannot check the inputs: {exc}").format(exc=exc)], []
        self.run_panel.show_problems(errors, warns)
        self._errors = errors
        return not errors

    # ------------------------------------------------------------ running
    def _job(self) -> Job:
        """The run's job: the model's, on the chosen image and its ROI."""
        self._write_model()
        img, data = self.inputs.image_layer, self.inputs.stack_data
        start = int(self.model.tracking["start"])
        shape = tuple(data.shape[-2:])
        roi, notes = self.inputs.roi(shape, start)
        seeds = self.inputs.seed_points() if self.model.init == "seeds" else ()
        return self.model.job(data, roi, brush=self.inputs.brush_mask(shape, start),
                              seeds=seeds, source=img.name, notes=notes)

    def run(self, *_) -> None:
        """Start the analysis in a worker thread (no-op while one runs)."""
        from napari.utils.notifications import show_error, show_warning

        if self.running or self.run_panel.live:  # one analysis at a time
            return
        if not self._validate():
            show_warning("napari-aldic: " + " ".join(self._errors))
            return
        try:
            job = self._job()
        except Exception as exc:
            show_error(tr("napari-aldic: could not prepare the run: {exc}").format(
                exc=with_explanation(exc)))
            self.run_panel.write_log(tr("ERROR preparing the run: {exc}").format(exc=exc))
            return
        self._remember()
        self._results.image = image = self.inputs.image_layer
        geometry, display = geometry_of(image), self._display_options()
        # the result layers are made in the worker too: the viewer only adds them
        self.run_panel.start(job, after=lambda a: prepare(a, geometry, display, True),
                             before=warmup.wait)

    def cancel(self, *_) -> None:
        """Stop after the frame being computed; finished frames are kept."""
        self.run_panel.cancel()

    # ------------------------------------------------------------ results
    def show_analysis(self, analysis: Analysis) -> None:
        """Show ``analysis`` (e.g. of ``run_analysis``) as result layers on the image, at once."""
        for _ in self._show_steps(analysis, None):
            pass

    def _show_steps(self, analysis: Analysis, prepared):
        """Show the results step by step (one layer per step)."""
        self._results.analysis = analysis
        if self._results.image is None:
            self._results.image = self.inputs.image_layer
        display = self._display_options()
        if prepared is None or prepared.display != display:
            prepared = self._results.prepare(display, self._results.placed_on(
                self.inputs.image_layer))
        if prepared is not None:
            yield from self._results.steps(prepared)
        yield from self._results.field_steps(display.visible_field)
        yield
        self._after_show(display)
        yield
        self._results.go_to_last_frame()

    def _after_show(self, display) -> None:
        last = next((r for r in reversed(self.analysis.results) if r is not None), None)
        counts = {}
        if last is not None:
            codes, n = np.unique(np.asarray(last.reason)[~np.asarray(last.valid, bool)],
                                 return_counts=True)
            counts = {int(c): int(k) for c, k in zip(codes, n)}
        self.display.set_legend(counts)
        self.exports.refresh()
        self.run_panel.write_log(
            tr("results drawn in the deformed configuration (Display > deformed configuration)")
            if display.deformed else
            tr("results drawn in the reference configuration (Display > deformed configuration)"))

    def _display_options(self):
        return self.display.display(self.units.length, self.units.time)

    def _refresh_results(self, *_) -> None:
        if self._results.analysis is None or self.running:
            return
        try:
            display = self._display_options()
            self._results.show(display, self.inputs.image_layer)
            self._results.show_field(display.visible_field)
        except Exception as exc:
            from napari.utils.notifications import show_error

            show_error(tr("napari-aldic: could not update the results: {exc}").format(exc=exc))

    def _on_vector_length(self, length: float) -> None:
        if not self._results.set_vector_length(length):
            self._refresh_results()  # automatic length: computed from the field
