"""The Display panel: which result layers to show and how."""

from __future__ import annotations

from magicgui.widgets import CheckBox, ComboBox, Container, FloatSpinBox
from psygnal import Signal

from .._layers import DISPLAY_FIELDS, Display
from .controls import Panel, section

__all__ = ["DisplayPanel"]


class DisplayPanel(Panel):
    """Visible field, displacement vectors and their scale, mesh, deformed configuration.

    Signals
    -------
    display_changed
        A choice that needs the result layers rebuilt changed.
    vector_length_changed
        The arrow scale changed (0: automatic).
    """

    display_changed = Signal()
    vector_length_changed = Signal(float)

    def _setup_ui(self) -> None:
        self.show_field = ComboBox(label="Show", value="|u|", choices=list(DISPLAY_FIELDS),
                                   tooltip="Result image layer made visible after a run "
                                           "(the others are added hidden).")
        self.vectors = CheckBox(text="displacement vectors", value=True,
                                tooltip="Vectors layer of (u, v) at the trusted nodes; every "
                                        "node value is in its features.")
        self.vector_length = FloatSpinBox(label="Vector scale", value=0.0, min=0.0, max=1e6,
                                          step=0.5,
                                          tooltip="Arrow length per unit displacement; 0 = "
                                                  "automatic (the longest arrows span about "
                                                  "one node step).")
        self.mesh = CheckBox(text="mesh", value=False,
                             tooltip="Shapes layer of the element outlines.")
        self.deformed = CheckBox(text="deformed configuration", value=False,
                                 tooltip="Show fields, vectors, nodes and mesh where the "
                                         "material is in each frame instead of in the "
                                         "reference frame.")
        toggles = Container(widgets=[self.vectors, self.mesh, self.deformed],
                            layout="vertical", labels=False)
        self.extend([section("Display"), self.show_field, toggles, self.vector_length])

    def _setup_callbacks(self) -> None:
        for w in (self.mesh, self.deformed, self.vectors):
            w.changed.connect(self.display_changed.emit)
        self.vector_length.changed.connect(
            lambda value: self.vector_length_changed.emit(float(value)))

    def display(self, length: tuple[float, str], time: tuple[float | None, str]) -> Display:
        """The :class:`Display` of the controls with the units ``length`` (pixel
        size, unit) and ``time`` (frame interval or ``None``, unit)."""
        return Display(visible_field=self.show_field.value, vectors=self.vectors.value,
                       vector_length=float(self.vector_length.value), mesh=self.mesh.value,
                       deformed=self.deformed.value, length_scale=float(length[0]),
                       length_unit=length[1], frame_interval=time[0], time_unit=time[1])
