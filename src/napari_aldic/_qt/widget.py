"""The dock widget: the panels, composed and wired together.

Inputs, Mesh & correlation, Strain, Units and Display scroll in one area;
the settings-file buttons, the Run panel (status, Run/Cancel, progress, log)
stay below it. Each panel is a small class of its own (this package); this
module only connects them: the input check, the run, the result layers.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from magicgui.widgets import Container

from .._analysis import Analysis, Job
from ..engine import DICParams
from .checks import Choices, problems
from .controls import align_labels
from .correlation import CorrelationPanel
from .display import DisplayPanel
from .inputs import InputsPanel
from .results import ResultLayers
from .run import RunPanel
from .settings import SettingsPanel
from .strain import StrainPanel
from .units import UnitsPanel

if TYPE_CHECKING:  # pragma: no cover
    import napari

__all__ = ["DICWidget"]

#: the panels' controls, also attributes of the widget (``widget.subset``,
#: ``widget.image`` ...) for scripts and tests
CONTROLS = {
    "inputs": ("image", "roi_add", "roi_subtract", "roi_labels", "brush", "seeds"),
    "correlation": ("method", "subset", "step", "search", "refine", "smooth", "smooth_px",
                    "init", "reference", "start", "stop", "stride"),
    "strain_panel": ("strain_window", "strain_method", "strain_measure"),
    "units": ("pixel_size", "unit", "frame_interval", "time_unit"),
    "display": ("show_field", "vectors", "vector_length", "mesh", "deformed"),
    "settings": ("save_params_button", "load_params_button"),
    "run_panel": ("status", "run_button", "cancel_button", "progress", "eta", "log"),
}


class DICWidget(Container):
    """Digital image correlation of an image stack (napari-aldic)."""

    def __init__(self, napari_viewer: napari.viewer.Viewer):
        super().__init__(labels=False)
        self._viewer = napari_viewer
        self._errors: list[str] = []
        self._setup_ui()
        self._setup_callbacks()
        self.inputs.assign_existing_layers()
        self._on_image_changed()

    def _setup_ui(self) -> None:
        self.inputs = InputsPanel(self._viewer)
        self.correlation = CorrelationPanel()
        self.strain_panel = StrainPanel()
        self.units = UnitsPanel()
        self.display = DisplayPanel()
        self.run_panel = RunPanel()
        self.settings = SettingsPanel(self.inputs, self.correlation, self.strain_panel,
                                      self.units, log=self.run_panel.write_log,
                                      apply_units=self._apply_units)
        self._results = ResultLayers(self._viewer)
        for panel, names in CONTROLS.items():
            for name in names:
                setattr(self, name, getattr(getattr(self, panel), name))
        # napari docks ``self.native``: the panels scroll, the run controls stay below
        panels = [self.inputs, self.correlation, self.strain_panel, self.units, self.display]
        align_labels(panels)
        body = Container(scrollable=True, labels=False, widgets=panels)
        self.run_panel.insert(1, self.settings)  # between the status line and Run
        scroll = body.root_native_widget
        scroll.setFrameShape(scroll.Shape.NoFrame)
        self._body = body  # the scroll area's magicgui container (keeps the panels alive)
        self.native.layout().addWidget(scroll, 1)
        self.native.layout().addWidget(self.run_panel.native, 0)
        self.native.layout().setContentsMargins(0, 0, 0, 0)

    def _setup_callbacks(self) -> None:
        self.inputs.image.changed.connect(self._on_image_changed)
        self.inputs.inputs_changed.connect(self._validate)
        self.inputs.seeds_assigned.connect(self._use_seeds)
        self.correlation.settings_changed.connect(self._validate)
        self.strain_panel.settings_changed.connect(self._validate)
        self.units.units_changed.connect(self._apply_units)
        self.display.display_changed.connect(self._refresh_results)
        self.display.vector_length_changed.connect(self._on_vector_length)
        self.settings.settings_loaded.connect(self._validate)
        self.run_panel.run_requested.connect(self.run)
        self.run_panel.running_changed.connect(self._on_running)
        self.run_panel.show_results = self._show_analysis
        # closing the widget stops a run after its frame and unhooks it from the viewer
        # (the slot holds no reference to the widget, which may be torn down by then)
        stop, unhook = self.run_panel.stopper(), self.inputs.disconnector()
        self.native.destroyed.connect(lambda *_: (stop(), unhook()))

    # ------------------------------------------------------------ state
    @property
    def running(self) -> bool:
        """Whether an analysis is running."""
        return self.run_panel.running

    @property
    def _analysis(self) -> Analysis | None:
        """The analysis shown in the result layers."""
        return self._results.analysis

    def current_settings(self) -> dict[str, Any]:
        """The complete analysis settings of the controls, as
        :func:`~napari_aldic.engine.io.load_settings` gives them:
        ``{"params": DICParams, "units": Units, "strain": dict, "tracking": dict}``.

        Raises ``ValueError`` when the controls do not make valid settings (an
        even subset, 'Seed points' without points, a pixel size in 'px' ...).
        """
        s = self.settings.current()
        return {"params": s.params, "units": s.units, "strain": s.strain,
                "tracking": s.tracking}

    def _current_params(self) -> DICParams:
        return self.settings.current_params()

    def save_settings(self, path) -> Path | None:
        """Write the current settings to the JSON file ``path`` (``.json`` is
        appended when missing).

        Returns the path written, or ``None`` after an error notification and a
        log line (nothing is written then). The file also works with
        ``napari-aldic run STACK --params FILE.json``.
        """
        return self.settings.save(path)

    def load_settings(self, path) -> bool:
        """Set every control from a settings file (see :meth:`save_settings`;
        also files of ``napari-aldic params`` / ``run --params-out``, or a plain
        JSON object of DICParams fields).

        The whole file is checked first: an unreadable file or invalid content
        gives an error notification and a log line, and leaves the widget
        unchanged (returns ``False``). Sections missing from the file (units,
        strain, tracking) leave their controls as they are. DICParams fields the
        widget does not show (e.g. ``interpolation``, ``mu``) are kept for runs
        and for saving. Seed points of the file are added as a Points layer when
        no seeds layer with points is chosen. A frame range beyond the current
        stack is clamped to it (noted in the log).
        """
        return self.settings.load(path)

    # ------------------------------------------------------------ wiring
    def _use_seeds(self) -> None:
        self.correlation.init.value = "seeds"

    def _on_image_changed(self, *_) -> None:
        if self.inputs.choose_first_image():
            return  # the choice comes back here through ``image.changed``
        shape = self.inputs.stack_shape
        if shape is not None and len(shape) == 3:
            self.correlation.set_frame_count(shape[0])
        img = self.inputs.image_layer
        if img is not None and img.ndim >= 2:
            self.units.read_image(img)
        self._validate()

    def _apply_units(self) -> None:
        """Apply the units to the image, its input layers and the result layers
        (values of u, v, |u| are shown in the length unit)."""
        if self.inputs.image_layer is None:
            return
        self.units.apply_to(self.inputs.input_layers, self._results.layers)
        p, unit = self.units.length
        self.run_panel.write_log(f"units: pixel size {p:g} {unit}, frame interval "
                                 f"{self.units.frame_interval.value:g} "
                                 f"{self.units.time_unit.value}")
        self._refresh_results()

    def _on_running(self, running: bool) -> None:
        self.settings.load_params_button.enabled = not running  # a run keeps its settings
        self._validate()

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
            errors, warns = [f"Cannot check the inputs: {exc}"], []
        self.run_panel.show_problems(errors, warns)
        self._errors = errors
        return not errors

    # ------------------------------------------------------------ running
    def _job(self) -> Job:
        img, data = self.inputs.image_layer, self.inputs.stack_data
        c = self.correlation
        start = int(c.start.value)
        shape = tuple(data.shape[-2:])
        roi, notes = self.inputs.roi(shape, start)
        job = Job(stack=data, roi=roi, params=self._current_params(),
                  reference=c.reference.value, start=start, stop=int(c.stop.value),
                  stride=int(c.stride.value), brush=self.inputs.brush_mask(shape, start),
                  strain=self.strain_panel.settings, source=img.name)
        job.summary = job.describe(notes, c.extra_params)
        return job

    def run(self, *_) -> None:
        """Start the analysis in a worker thread (no-op while one runs)."""
        from napari.utils.notifications import show_error, show_warning

        if self.running:
            return
        if not self._validate():
            show_warning("napari-aldic: " + " ".join(self._errors))
            return
        try:
            job = self._job()
        except Exception as exc:
            show_error(f"napari-aldic: could not prepare the run: {exc}")
            self.run_panel.write_log(f"ERROR preparing the run: {exc}")
            return
        self._results.image = self.inputs.image_layer
        self.run_panel.start(job)

    def cancel(self, *_) -> None:
        """Stop after the frame being computed; finished frames are kept."""
        self.run_panel.cancel()

    # ------------------------------------------------------------ results
    def _show_analysis(self, analysis: Analysis) -> None:
        self._results.analysis = analysis
        self._results.show(self._display_options(), self.inputs.image_layer)
        self._results.go_to_last_frame()

    def _display_options(self):
        return self.display.display(self.units.length, self.units.time)

    def _refresh_results(self, *_) -> None:
        if self._results.analysis is None or self.running:
            return
        try:
            self._results.show(self._display_options(), self.inputs.image_layer)
        except Exception as exc:
            from napari.utils.notifications import show_error

            show_error(f"napari-aldic: could not update the results: {exc}")

    def _on_vector_length(self, length: float) -> None:
        if not self._results.set_vector_length(length):
            self._refresh_results()  # automatic length: computed from the field
