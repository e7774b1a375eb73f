"""The Strain panel: how strain is computed from each frame's displacement field."""

from __future__ import annotations

from magicgui.widgets import ComboBox, SpinBox
from psygnal import Signal

from ..engine import StrainParams
from ..i18n import tr
from .controls import Panel, Plan, put

__all__ = ["StrainPanel"]

#: the controls' starting values (the engine's strain defaults)
DEFAULTS = StrainParams()

class StrainPanel(Panel):
    """Strain window, method and measure.

    Signals
    -------
    settings_changed
        The window changed (the input check depends on it).
    """

    settings_changed = Signal()

    def _setup_ui(self) -> None:
        self.strain_window = SpinBox(label=tr("Strain window"), value=DEFAULTS.window, min=3,
                                     max=101, step=2,
                                     tooltip=tr("Odd number of nodes across the plane fit; the "
                                             "virtual strain gauge is (window - 1) * step + "
                                             "subset pixels."))
        self.strain_method = ComboBox(label=tr("Strain method"), value=DEFAULTS.method,
                                      choices=[(tr("plane fit"), "plane_fit"),
                                               (tr("FE gradients"), "fem")],
                                      tooltip=tr("Local least-squares plane fit over the window, "
                                              "or gradients of the bilinear element field."))
        self.strain_measure = ComboBox(label=tr("Strain measure"), value=DEFAULTS.measure,
                                       choices=[(tr("Green-Lagrange"), "green_lagrange"),
                                                (tr("infinitesimal"), "infinitesimal"),
                                                (tr("Euler-Almansi"), "euler_almansi")],
                                       tooltip=tr("Finite-strain measure of exx, eyy, exy."))
        self.extend([self.strain_window, self.strain_method,
                     self.strain_measure])

    def _setup_callbacks(self) -> None:
        self.strain_window.changed.connect(self.settings_changed.emit)

    @property
    def settings(self) -> StrainParams:
        """The strain settings of the controls."""
        return StrainParams(window=int(self.strain_window.value),
                              method=self.strain_method.value,
                              measure=self.strain_measure.value)

    @settings.setter
    def settings(self, value: StrainParams) -> None:
        self.strain_window.value = value.window
        self.strain_method.value = value.method
        self.strain_measure.value = value.measure

    def as_dict(self) -> dict:
        """The settings as a settings file's "strain" section."""
        s = self.settings
        return {"window": s.window, "method": s.method, "measure": s.measure}

    def summary(self) -> str:
        """The settings in words (for the log)."""
        s = self.settings
        return tr("strain {method}, window {window}, {measure}").format(
                      method=s.method, window=s.window, measure=s.measure)

    def strain_plan(self, strain: dict, plan: Plan) -> None:
        """Add the controls for a "strain" section (checked by
        :class:`~napari_aldic.engine.Settings`) to ``plan``."""
        for key, control in (("window", self.strain_window), ("method", self.strain_method),
                             ("measure", self.strain_measure)):
            if key in strain:
                put(plan, control, strain[key], tr("strain {key}").format(key=key))
