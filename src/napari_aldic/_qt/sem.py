"""The dock's "SEM corrections (HRDIC)" section (issue 27, docs/sem.md).

:class:`SEMChoice` (no Qt) is what the section says: a distortion and a drift
calibration file (each kept with the SHA-256 of its bytes, so a project opened
later finds out when a file was replaced), the scan start times of the pair
for the drift, and whether scan-line shifts are removed. It lives in the dock's
model (``DockModel.sem``): the Run reads it (``correlate_sem`` instead of
``correlate``), a project file keeps it. :class:`SEMPanel` shows and edits it;
a file is read with the engine's reader when it is chosen, so a bad one is
refused at once with one line naming it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from magicgui.widgets import CheckBox, FileEdit, Label, LineEdit

from ..engine.io import file_sha256
from ..engine.sem import load_distortion, load_drift
from ..i18n import tr
from .controls import Panel

__all__ = ["SEMChoice", "SEMPanel", "parse_times"]

_KINDS = ("distortion", "drift")


def parse_times(text: str) -> tuple[float, float] | None:
    """``"t_ref, t_def"`` (seconds) as two numbers; ``None`` when empty."""
    parts = [p for p in text.replace(",", " ").split() if p]
    if not parts:
        return None
    try:
        times = tuple(float(p) for p in parts)
    except ValueError:
        times = ()
    if len(times) != 2:
        raise ValueError(tr("scan start times {text!r}: give two numbers in seconds, the "
                            "reference's and the deformed image's").format(text=text))
    return times


def _load(kind: str, path: str):
    return (load_distortion if kind == "distortion" else load_drift)(path)


@dataclass(frozen=True)
class SEMChoice:
    """The SEM corrections chosen for one analysis (paths as given, with hashes)."""

    distortion: str | None = None
    distortion_sha256: str | None = None
    drift: str | None = None
    drift_sha256: str | None = None
    start_times: tuple[float, float] | None = None
    scan_lines: bool = False

    @property
    def active(self) -> bool:
        return bool(self.distortion or self.drift or self.scan_lines)

    def choose(self, kind: str, path) -> SEMChoice:
        """This choice with the ``kind`` ("distortion", "drift") file ``path``
        (``None``/empty: none), read and hashed now; ``ValueError`` naming the
        file when it is no such calibration."""
        if not path or str(path) in ("", "."):
            return replace(self, **{kind: None, f"{kind}_sha256": None})
        path = str(Path(path).expanduser())
        try:
            _load(kind, path)
            digest = file_sha256(path, f"{kind} calibration")
        except (OSError, ValueError) as exc:
            raise ValueError(" ".join(str(exc).split())) from None
        return replace(self, **{kind: path, f"{kind}_sha256": digest})

    def options(self) -> dict:
        """The keyword arguments of ``correlate_sem``: each file read again and
        checked against the hash taken when it was chosen."""
        out: dict = {"scan_lines": bool(self.scan_lines)}
        for kind in _KINDS:
            path = getattr(self, kind)
            if not path:
                continue
            model = _load(kind, path)
            if file_sha256(path) != getattr(self, f"{kind}_sha256"):
                raise ValueError(tr("the {kind} file {path} changed since it was chosen: "
                                    "choose it again").format(kind=kind, path=path))
            out[kind] = model
        if self.drift:
            out["start_times"] = self.start_times
        return out

    def words(self) -> str:
        """The corrections in words ("distortion d.json, scan lines")."""
        parts = [tr("distortion {name}").format(name=Path(self.distortion).name)] \
            if self.distortion else []
        if self.drift:
            parts.append(tr("drift {name}").format(name=Path(self.drift).name))
        if self.scan_lines:
            parts.append(tr("scan lines"))
        return ", ".join(parts)

    def to_dict(self) -> dict:
        return {"distortion": self.distortion, "distortion_sha256": self.distortion_sha256,
                "drift": self.drift, "drift_sha256": self.drift_sha256,
                "start_times": None if self.start_times is None else list(self.start_times),
                "scan_lines": bool(self.scan_lines)}

    @classmethod
    def from_dict(cls, d) -> SEMChoice | None:
        """The choice of a project's ``"sem"`` section (``None`` for none);
        ``ValueError`` when the section is damaged (files are not read here)."""
        if d is None:
            return None
        ok = isinstance(d, dict) and all(
            d.get(k) is None or isinstance(d.get(k), str)
            for k in ("distortion", "distortion_sha256", "drift", "drift_sha256"))
        times = d.get("start_times") if isinstance(d, dict) else None
        ok = ok and (times is None or (isinstance(times, list) and len(times) == 2 and all(
            isinstance(t, (int, float)) and not isinstance(t, bool) for t in times)))
        if not ok or not isinstance(d.get("scan_lines", False), bool):
            raise ValueError(tr("the project's 'sem' section is damaged"))
        return cls(d.get("distortion"), d.get("distortion_sha256"), d.get("drift"),
                   d.get("drift_sha256"), None if times is None else tuple(map(float, times)),
                   bool(d.get("scan_lines", False)))


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
