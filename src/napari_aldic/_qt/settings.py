"""The Project and parameters panel: settings files, project files, defaults, memory.

A settings file is a :class:`~napari_aldic.engine.Settings` document
(parameters, units, strain, tracking), so ``napari-aldic run STACK --params
FILE.json`` reads it too. A file is checked completely (by ``Settings`` and
against the range of every control) before anything changes. A project file
(:mod:`.project`, opened and saved by :mod:`.project_actions`) holds the whole
set-up with its layers. The settings of the last run are remembered across
napari sessions (:mod:`.prefs`); "Restore defaults" forgets them.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path

from magicgui.widgets import Container, PushButton
from psygnal import Signal

from .._analysis import describe_fields
from ..engine import DICParams, Settings
from ..engine.io import read_settings, write_settings
from ..i18n import tr, tr_noop
from . import prefs
from .controls import Panel, Plan, apply_plan
from .correlation import CorrelationPanel
from .display import DisplayPanel
from .explain import message
from .inputs import InputsPanel
from .model import DockModel
from .probes import image_view, probes_from_layers
from .project import is_probe_layer
from .project_actions import ProjectActions
from .strain import StrainPanel
from .units import UnitsPanel

__all__ = ["SettingsPanel", "JSON_FILTER", "message"]

JSON_FILTER = tr_noop("DIC parameters (*.json);;All files (*)")
#: the display choices "Restore defaults" sets
DISPLAY_DEFAULTS = {"show_field": "|u|", "vectors": True, "vector_length": 0.0, "mesh": False,
                    "deformed": False, "rigid": False}


class SettingsPanel(Panel):
    """Save/open analysis (project), save/load parameters, restore defaults.

    Signals
    -------
    settings_loaded
        Settings were applied to the controls.
    project_opened
        A project file was opened (image, layers and controls restored).
    """

    settings_loaded = Signal()
    project_opened = Signal()

    def __init__(self, model: DockModel, inputs: InputsPanel, correlation: CorrelationPanel,
                 strain: StrainPanel, units: UnitsPanel, display: DisplayPanel,
                 log: Callable[[str], None], apply_units: Callable[[], None], viewer=None):
        self._model = model
        #: writes the panels' values into the model (set by the dock; before a save)
        self.sync: Callable[[], None] = lambda: None
        self._inputs, self._correlation = inputs, correlation
        self._strain, self._units, self._display = strain, units, display
        self._log, self._apply_units = log, apply_units
        self._viewer = viewer
        self._folder: Path | None = None  # folder of the last file
        self.projects = ProjectActions(model, inputs, viewer, log, parent=self)
        c = correlation  # the controls' first values are the defaults
        self._defaults = [(w, w.value) for w in (
            c.method, c.subset, c.step, c.search, c.refine, c.smooth, c.smooth_px, c.init,
            c.reference, c.start, c.stride, strain.strain_window, strain.strain_method,
            strain.strain_measure, units.unit, units.pixel_size, units.time_unit,
            units.frame_interval)]
        super().__init__(labels=False, margins=None)

    def _setup_ui(self) -> None:
        button = PushButton
        self.save_project_button = button(
            text=tr("Save analysis…"), tooltip=tr("Save everything set up here (image file, ROI, "
            "holes, labels, refine region, seeds, probes, parameters, units, display) in one "
            "project file."))
        self.open_project_button = button(
            text=tr("Open analysis…"), tooltip=tr("Open a project file: the image and its layers "
            "are added and every control is set."))
        self.save_params_button = button(
            text=tr("Save parameters…"), tooltip=tr("Write the analysis settings (correlation, "
            "tracking and frame range, strain, units, probe layers) to a readable JSON file; "
            "it also works with 'napari-aldic run STACK --params FILE.json'."))
        self.load_params_button = button(
            text=tr("Load parameters…"), tooltip=tr("Set every parameter from a JSON file saved "
            "here or written by 'napari-aldic params' / 'run --params-out'."))
        self.defaults_button = button(
            text=tr("Restore defaults"), tooltip=tr("Set every parameter, unit and display choice "
            "to its default (the last used ones are remembered between napari sessions)."))
        rows = [[self.save_project_button, self.open_project_button],
                [self.save_params_button, self.load_params_button], [self.defaults_button]]
        for row in rows:
            box = Container(widgets=row, layout="horizontal", labels=False)
            box.margins = (0, 0, 0, 0)
            self.append(box)

    def _setup_callbacks(self) -> None:
        self.save_params_button.changed.connect(self._on_save_clicked)
        self.load_params_button.changed.connect(self._on_load_clicked)
        self.save_project_button.changed.connect(self.projects.on_save_clicked)
        self.open_project_button.changed.connect(self.projects.on_open_clicked)
        self.defaults_button.changed.connect(lambda *_: self.restore_defaults())

    # ------------------------------------------------------------ state
    def current_params(self) -> DICParams:
        """The DICParams of the controls (seed points from the seeds layer, in image
        pixels), with the fields the widget does not show from the last loaded file."""
        seeds = self._inputs.seed_points() if self._correlation.init.value == "seeds" else ()
        return self._correlation.params(seeds)

    def current(self) -> Settings:
        """The complete analysis settings of the controls (``ValueError`` when they
        do not make valid settings: 'Seed points' without points, a pixel size in
        'px' ...)."""
        return Settings(self.current_params(), self._units.units, self._model.strain.to_dict(),
                        dict(self._model.tracking), probes=self.current_probes())

    def current_probes(self) -> dict | None:
        """The probe layers (Points/Shapes marked as probes) as a probe set in the
        image's pixels, for parameter files (``napari-aldic probe --probes FILE``)."""
        img = self._inputs.image_layer
        if self._viewer is None or img is None:
            return None
        layers = [lay for lay in self._viewer.layers if is_probe_layer(lay)]
        shapes = next((lay for lay in layers if lay.__class__.__name__ == "Shapes"), None)
        points = next((lay for lay in layers if lay.__class__.__name__ == "Points"), None)
        if shapes is None and points is None:
            return None
        view = image_view(img)
        probes, _notes = probes_from_layers(shapes, points, view)
        return probes.to_dict() if len(probes) else None

    def storable(self, frame_range: bool = True) -> dict:
        """The model's settings without seed points (see :meth:`DockModel.storable`)."""
        self.sync()
        return self._model.storable(frame_range)

    def set_init(self, init: str) -> None:
        """Choose the initial guess ("fft" or "seeds")."""
        self._correlation.init.value = init

    def set_display(self, choices: dict) -> None:
        """Set the display choices (unknown keys are ignored)."""
        self._display.set_choices(choices)

    def summary(self) -> str:
        """Every setting in words (for the log)."""
        return (f"{self._correlation.summary()}; {self._strain.summary()}; "
                f"{self._units.summary()}")

    # ------------------------------------------------------------ applying
    def apply(self, s: Settings, source: str, init: str | None = None,
              quiet: bool = False) -> bool:
        """Set the controls from ``s`` (and the initial guess ``init``); the units
        are applied to the layers once. Invalid for a control: nothing changes,
        an error is logged (and notified unless ``quiet``); returns success."""
        from napari.utils.notifications import show_error, show_warning

        try:
            plan, extra, seeds, notes = self._plan(s)
            if init is not None:
                plan.append((self._correlation.init, init))
        except Exception as exc:  # a value a control cannot take: nothing is changed
            self._log(tr("ERROR loading parameters from {source}: {exc}").format(
                             source=source, exc=message(exc)))
            if not quiet:
                show_error(tr("napari-aldic: could not load the parameters: {exc}").format(
                                  exc=message(exc)))
            return False
        units_before = self._units.values
        self._apply(plan, extra, seeds, notes)
        if self._units.values != units_before:
            try:  # rescale the image and its layers once, for all unit controls
                self._apply_units()
            except Exception as exc:  # pragma: no cover - a layer refusing its scale
                show_error(tr("napari-aldic: could not apply the units: {exc}").format(
                                  exc=message(exc)))
                self._log(tr("ERROR applying the units: {exc}").format(exc=message(exc)))
        self._log(tr("parameters loaded from {source}: {summary}").format(
                         source=source, summary=self.summary()))
        if extra:
            self._log(tr("kept from the file (not shown in the widget): "
                         "{describe_fields}").format(
                             describe_fields=describe_fields(extra)))
        for note in notes:
            self._log(note)
        clamped = [n for n in notes if n.startswith(tr("frame range") + ":")]
        if clamped and not quiet:
            show_warning("napari-aldic: " + clamped[0])
        self.settings_loaded.emit()
        return True

    def _apply(self, plan: Plan, extra: dict, seeds: tuple, notes: list[str]) -> None:
        """Apply a checked plan; on an error the controls are set back."""
        before = [(w, w.value) for w, _ in plan]
        extra_before = self._correlation.extra_params
        try:
            with self._units.quiet():  # units are applied to the layers once, afterwards
                apply_plan(plan)
            self._correlation.extra_params = extra
            if seeds:
                self._inputs.restore_seeds(seeds, notes)
        except Exception:
            with self._units.quiet():
                apply_plan(before)
            self._correlation.extra_params = extra_before
            raise

    def _plan(self, s: Settings) -> tuple[Plan, dict, tuple, list[str]]:
        """The controls for settings ``s``: ``(plan, extra, seeds, notes)``, the plan
        a list of ``(control, value)``; raises on any value a control cannot take."""
        plan: Plan = []
        notes: list[str] = []
        extra = self._correlation.params_plan(s.params, plan)
        seeds = s.params.seeds if s.params.init == "seeds" else ()
        if s.strain is not None:
            self._strain.strain_plan(s.strain, plan)
        if s.tracking is not None:
            shape = self._inputs.stack_shape
            n = shape[0] if shape is not None and len(shape) == 3 else None
            self._correlation.tracking_plan(s.tracking, plan, notes, n)
        if s.units is not None:
            self._units.units_plan(s.units, plan)
        return plan, extra, seeds, notes

    # ------------------------------------------------------------ memory, defaults
    def remember_last_used(self) -> None:
        """Store the settings for the next napari session (never an error)."""
        try:
            prefs.write_last_used(self.storable(frame_range=False))
        except Exception as exc:  # pragma: no cover - a convenience only
            self._log(tr("could not remember the parameters: {exc}").format(exc=message(exc)))

    def restore_last_used(self) -> bool:
        """Set the controls to the last used settings, if any were stored."""
        doc = prefs.read_last_used()
        if doc is None:
            return False
        try:
            s = Settings.from_dict(doc.get("settings") or {})
        except ValueError:
            return False  # an outdated file: the defaults stay
        # a calibration belongs to one image: never applied to the next one (files
        # of 0.1 remembered it); units come from the image's metadata or the user
        s = dataclasses.replace(s, units=None)
        init = doc.get("init") if doc.get("init") in ("fft", "seeds") else None
        if init == "seeds" and self._inputs.seeds.value is None:
            init = "fft"  # no seeds layer in this session
        ok = self.apply(s, tr("the last session (Restore defaults resets them)"), init, quiet=True)
        if ok and isinstance(doc.get("display"), dict):
            self._display.set_choices(doc["display"])
        return ok

    def restore_defaults(self) -> None:
        """Every parameter, unit and display choice back to its default (the frame
        range: the whole stack)."""
        units_before = self._units.values
        with self._units.quiet():
            apply_plan([*self._defaults, (self._correlation.stop,
                                          int(self._correlation.stop.max))])
        self._correlation.extra_params = {}
        if self._units.values != units_before:
            self._apply_units()
        self._display.set_choices(DISPLAY_DEFAULTS)
        self._log(tr("defaults restored: {summary}").format(summary=self.summary()))
        self.settings_loaded.emit()

    # ------------------------------------------------------------ files
    def save(self, path) -> Path | None:
        """Write the current settings to the JSON file ``path`` (``.json`` is
        appended when missing). Returns the path written, or ``None`` after an
        error notification and a log line (nothing is written then)."""
        from napari.utils.notifications import show_error

        try:
            written = write_settings(path, self.current())
        except Exception as exc:  # invalid settings, unwritable file: explain, never crash
            self._log(tr("ERROR saving the parameters to {path}: {exc}").format(
                             path=path, exc=message(exc)))
            show_error(tr("napari-aldic: could not save the parameters: {exc}").format(
                              exc=message(exc)))
            return None
        self._folder = written.parent
        self._log(tr("parameters saved to {written}: {summary}").format(
                         written=written, summary=self.summary()))
        return written

    def load(self, path) -> bool:
        """Set every control from a settings file; see ``DICWidget.load_settings``."""
        from napari.utils.notifications import show_error

        try:
            s = read_settings(path)
        except Exception as exc:  # unreadable or invalid file: nothing is changed
            self._log(tr("ERROR loading parameters from {path}: {exc}").format(
                             path=path, exc=message(exc)))
            show_error(tr("napari-aldic: could not load the parameters: {exc}").format(
                              exc=message(exc)))
            return False
        self._folder = Path(os.fspath(path)).expanduser().parent
        return self.apply(s, str(path))

    def save_project(self, path) -> Path | None:
        """See ``DICWidget.save_project``."""
        return self.projects.save(path)

    def open_project(self, path) -> bool:
        """See ``DICWidget.open_project``."""
        return self.projects.open(path)

    # ------------------------------------------------------------ dialogs
    def start_folder(self, name: str = "") -> str:
        """Where the file dialogs open: the last file's folder, else the image's
        folder, else the working folder."""
        folder = self._folder
        if folder is None:
            img = self._inputs.image_layer
            src = getattr(getattr(img, "source", None), "path", None) if img is not None else None
            folder = Path(src).parent if src else Path.cwd()
        return str(folder / name) if name else str(folder)

    def stem(self) -> str:
        """A file name stem from the image's name."""
        img = self._inputs.image_layer
        return "".join(c if c.isalnum() or c in "-_." else "_" for c in img.name) \
            if img is not None else "dic"

    def _on_save_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        path, _ = QFileDialog.getSaveFileName(self.native, tr("Save DIC parameters"),
                                              self.start_folder(f"{self.stem()}_parameters"
                                                                ".json"), tr(JSON_FILTER))
        if path:
            self.save(path)

    def _on_load_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        path, _ = QFileDialog.getOpenFileName(self.native, tr("Load DIC parameters"),
                                              self.start_folder(), tr(JSON_FILTER))
        if path:
            self.load(path)
