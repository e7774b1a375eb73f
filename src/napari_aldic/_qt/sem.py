"""The dock's "SEM corrections (HRDIC)" section (issue 27, docs/sem.md): shows
and edits the dock model's :class:`~.sem_choice.SEMChoice`; a file is read with
the engine's reader when it is chosen, so a bad one is refused at once with one
line naming it."""

from __future__ import annotations

from dataclasses import replace

from magicgui.widgets import CheckBox, FileEdit, Label, LineEdit

from ..i18n import tr
from .controls import Panel
from .sem_choice import SEMChoice, parse_times

__all__ = ["SEMChoice", "SEMPanel", "parse_times"]


class SEMPanel(Panel):
    """Distortion file, drift file (+ scan start times), scan lines, one state line."""

    def __init__(self, model):
        self._model = model
        self._showing = False  # the controls are being set from the model
        super().__init__(labels=True)

    def _setup_ui(self) -> None:
        self.distortion = FileEdit(mode="r", filter="*.json",
                                   label=tr("Distortion calibration"))
        self.drift = FileEdit(mode="r", filter="*.json", label=tr("Drift calibration"))
        for edit in (self.distortion, self.drift):  # magicgui's own button text is English
            edit.choose_btn.text = tr("Choose file...")
        self.start_times = LineEdit(label=tr("Scan start times (s)"), value="")
        self.start_times.tooltip = tr("The reference's and the deformed image's scan start, "
                                      "on the drift series' clock; empty: read from the "
                                      "drift calibration when the images are in its series")
        self.scan_lines = CheckBox(text=tr("Remove scan-line shifts"), value=False)
        self.state = Label(value=tr("No SEM correction: the pair is correlated as it is."))
        self.state.native.setWordWrap(True)  # a long path never widens the dock
        self.extend([self.distortion, self.drift, self.start_times, self.scan_lines,
                     self.state])

    def _setup_callbacks(self) -> None:
        self.distortion.changed.connect(lambda v: self._choose("distortion", v))
        self.drift.changed.connect(lambda v: self._choose("drift", v))
        self.start_times.changed.connect(self._on_times)
        self.scan_lines.changed.connect(self._on_scan_lines)
        self._model.changed.connect(self._on_model)
        self.native.destroyed.connect(lambda *_: self._model.changed.disconnect(self._on_model))

    @property
    def choice(self) -> SEMChoice:
        return self._model.sem or SEMChoice()

    def _set(self, choice: SEMChoice) -> None:
        self._model.update("sem", choice if choice.active or choice.start_times else None)
        self._describe()

    def _choose(self, kind: str, value) -> None:
        if self._showing:
            return
        try:
            self._set(self.choice.choose(kind, value))
        except ValueError as exc:
            self._set(self.choice.choose(kind, None))  # the bad file is not used
            self.state.value = tr("Refused: {error}").format(error=exc)

    def _on_times(self, *_) -> None:
        if self._showing:
            return
        try:
            times = parse_times(self.start_times.value)
        except ValueError as exc:
            self.state.value = str(exc)
            return
        self._set(replace(self.choice, start_times=times))

    def _on_scan_lines(self, value) -> None:
        if not self._showing:
            self._set(replace(self.choice, scan_lines=bool(value)))

    def _on_model(self, section: str) -> None:
        if section != "sem" or self._showing:
            return
        try:
            self._show(self.choice)
        except RuntimeError:  # the panel was closed meanwhile
            pass

    def _show(self, c: SEMChoice) -> None:
        """The controls set from ``c`` (a project opened), and its files checked."""
        self._showing = True
        try:
            self.distortion.value = c.distortion or ""
            self.drift.value = c.drift or ""
            self.start_times.value = "" if c.start_times is None else \
                ", ".join(f"{t:g}" for t in c.start_times)
            self.scan_lines.value = bool(c.scan_lines)
        finally:
            self._showing = False
        try:
            c.options()
        except ValueError as exc:
            self.state.value = tr("Refused: {error}").format(error=" ".join(str(exc).split()))
            return
        self._describe()

    def _describe(self) -> None:
        c = self.choice
        self.state.value = tr("Run corrects: {parts} (a pair: one deformed frame).").format(
            parts=c.words()) if c.active else \
            tr("No SEM correction: the pair is correlated as it is.")
