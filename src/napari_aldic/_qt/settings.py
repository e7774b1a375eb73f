"""The settings-file panel: save and load every analysis setting as JSON.

The file is a :class:`~napari_aldic.engine.Settings` document (parameters,
units, strain, tracking), so ``napari-aldic run STACK --params FILE.json``
reads it too. A file is checked completely (by ``Settings`` and against the
range of every control) before anything changes.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from magicgui.widgets import PushButton
from psygnal import Signal

from .._analysis import describe_fields
from ..engine import DICParams, Settings
from ..engine.io import read_settings, write_settings
from .controls import Panel, Plan, apply_plan
from .correlation import CorrelationPanel
from .inputs import InputsPanel
from .strain import StrainPanel
from .units import UnitsPanel

__all__ = ["SettingsPanel", "JSON_FILTER"]

JSON_FILTER = "DIC parameters (*.json);;All files (*)"


def _message(exc: BaseException) -> str:
    """One line describing an error."""
    msg = str(exc) or exc.__class__.__name__
    if isinstance(exc, FileNotFoundError) and not str(exc).strip():
        msg = f"no such file: {exc.filename}"
    return " ".join(line.strip() for line in msg.splitlines() if line.strip())


class SettingsPanel(Panel):
    """"Save parameters…" and "Load parameters…" for the other panels' settings.

    Signals
    -------
    settings_loaded
        A settings file was applied to the controls.
    """

    settings_loaded = Signal()

    def __init__(self, inputs: InputsPanel, correlation: CorrelationPanel,
                 strain: StrainPanel, units: UnitsPanel, log: Callable[[str], None],
                 apply_units: Callable[[], None]):
        self._inputs, self._correlation = inputs, correlation
        self._strain, self._units = strain, units
        self._log, self._apply_units = log, apply_units
        self._folder: Path | None = None  # folder of the last settings file
        super().__init__(labels=False, layout="horizontal", margins=None)

    def _setup_ui(self) -> None:
        self.save_params_button = PushButton(
            text="Save parameters…",
            tooltip="Write the analysis settings (correlation, tracking and frame range, "
                    "strain, units) to a readable JSON file; it also works with "
                    "'napari-aldic run STACK --params FILE.json'.")
        self.load_params_button = PushButton(
            text="Load parameters…",
            tooltip="Set every parameter from a JSON file saved here or written by "
                    "'napari-aldic params' / 'run --params-out'.")
        self.extend([self.save_params_button, self.load_params_button])

    def _setup_callbacks(self) -> None:
        self.save_params_button.changed.connect(self._on_save_clicked)
        self.load_params_button.changed.connect(self._on_load_clicked)

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
        return Settings(self.current_params(), self._units.units, self._strain.as_dict(),
                        self._correlation.tracking)

    def summary(self) -> str:
        """Every setting in words (for the log)."""
        return (f"{self._correlation.summary()}; {self._strain.summary()}; "
                f"{self._units.summary()}")

    # ------------------------------------------------------------ files
    def save(self, path) -> Path | None:
        """Write the current settings to the JSON file ``path`` (``.json`` is
        appended when missing). Returns the path written, or ``None`` after an
        error notification and a log line (nothing is written then)."""
        from napari.utils.notifications import show_error

        try:
            written = write_settings(path, self.current())
        except Exception as exc:  # invalid settings, unwritable file: explain, never crash
            msg = _message(exc)
            self._log(f"ERROR saving the parameters to {path}: {msg}")
            show_error(f"napari-aldic: could not save the parameters: {msg}")
            return None
        self._folder = written.parent
        self._log(f"parameters saved to {written}: {self.summary()}")
        return written

    def load(self, path) -> bool:
        """Set every control from a settings file; see ``DICWidget.load_settings``."""
        from napari.utils.notifications import show_error, show_warning

        try:
            plan, extra, seeds, notes = self._plan(path)
        except Exception as exc:  # unreadable or invalid file: nothing is changed
            msg = _message(exc)
            self._log(f"ERROR loading parameters from {path}: {msg}")
            show_error(f"napari-aldic: could not load the parameters: {msg}")
            return False
        units_before = self._units.values
        try:
            self._apply(plan, extra, seeds, notes)
        except Exception as exc:  # pragma: no cover - the plan was checked beforehand
            msg = _message(exc)
            self._log(f"ERROR loading parameters from {path}: {msg}")
            show_error(f"napari-aldic: could not load the parameters: {msg}")
            self.settings_loaded.emit()
            return False
        if self._units.values != units_before:
            try:  # rescale the image and its layers once, for all unit controls
                self._apply_units()
            except Exception as exc:  # pragma: no cover - a layer refusing its scale
                show_error(f"napari-aldic: could not apply the units: {_message(exc)}")
                self._log(f"ERROR applying the units: {_message(exc)}")
        self._folder = Path(os.fspath(path)).expanduser().parent
        self._log(f"parameters loaded from {path}: {self.summary()}")
        if extra:
            self._log(f"kept from the file (not shown in the widget): {describe_fields(extra)}")
        for note in notes:
            self._log(note)
        clamped = [n for n in notes if n.startswith("frame range")]
        if clamped:
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

    def _plan(self, path) -> tuple[Plan, dict, tuple, list[str]]:
        """Read and check a settings file: ``(plan, extra, seeds, notes)``, the
        plan a list of ``(control, value)``; raises on any problem."""
        s = read_settings(path)
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

    # ------------------------------------------------------------ dialogs
    def start_folder(self, name: str = "") -> str:
        """Where the file dialogs open: the last settings file's folder, else the
        image's folder, else the working folder."""
        folder = self._folder
        if folder is None:
            img = self._inputs.image_layer
            src = getattr(getattr(img, "source", None), "path", None) if img is not None else None
            folder = Path(src).parent if src else Path.cwd()
        return str(folder / name) if name else str(folder)

    def _on_save_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        img = self._inputs.image_layer
        stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in img.name) \
            if img is not None else "dic"
        path, _ = QFileDialog.getSaveFileName(self.native, "Save DIC parameters",
                                              self.start_folder(f"{stem}_parameters.json"),
                                              JSON_FILTER)
        if path:
            self.save(path)

    def _on_load_clicked(self, *_) -> None:
        from qtpy.QtWidgets import QFileDialog

        path, _ = QFileDialog.getOpenFileName(self.native, "Load DIC parameters",
                                              self.start_folder(), JSON_FILTER)
        if path:
            self.load(path)
