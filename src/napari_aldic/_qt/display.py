"""The Display panel: which result layers to show and how, and what they mean."""

from __future__ import annotations

from magicgui.widgets import CheckBox, ComboBox, Container, FloatSpinBox, Label
from psygnal import Signal

from .._layers import DISPLAY_FIELDS, REASON_COLORS, Display
from ..i18n import tr, tr_noop
from .controls import Panel
from .explain import reason_text

__all__ = ["DisplayPanel", "legend_html"]

#: what the note says about where the fields are drawn
_NOTE_REFERENCE = tr_noop("Fields are drawn in the reference configuration (where the "
                          "material is in the first analysed frame), also over later frames; "
                          "tick 'deformed configuration' to draw them where the material is "
                          "in each frame.")
_NOTE_DEFORMED = tr_noop("Fields are drawn in the deformed configuration: where the material "
                         "is in the frame shown.")


def legend_html(counts: dict[int, int]) -> str:
    """The legend of the unreliable-node markers: colour, reason and count."""
    if not counts:
        return tr("Unreliable nodes: none.")
    rows = []
    for code, n in sorted(counts.items()):
        r, g, b, _ = REASON_COLORS.get(int(code), (1.0, 0.0, 0.0, 1.0))
        colour = f"#{int(255 * r):02x}{int(255 * g):02x}{int(255 * b):02x}"
        rows.append(f"<span style='color:{colour}'>&#10006;</span> "
                    f"{reason_text(code)}: {n}")
    return tr("Unreliable nodes (last frame):<br>") + tr("<br>").join(rows)


class DisplayPanel(Panel):
    """Visible field, vectors and their scale, mesh, deformed configuration,
    rigid-body motion; a note on the configuration and the legend of the
    unreliable nodes.

    Signals
    -------
    display_changed
        A choice that needs the result layers rebuilt changed.
    field_chosen(str)
        'Show' changed: that field becomes the visible layer (nothing is rebuilt).
    vector_length_changed(float)
        The arrow scale changed (0: automatic).
    """

    display_changed = Signal()
    field_chosen = Signal(str)
    vector_length_changed = Signal(float)

    def _setup_ui(self) -> None:
        self.show_field = ComboBox(label=tr("Show"), value="|u|", choices=list(DISPLAY_FIELDS),
                                   tooltip=tr("The result image shown (and made the active "
                                           "layer); the others stay in the layer list, "
                                           "hidden."))
        self.vectors = CheckBox(text=tr("displacement vectors"), value=True,
                                tooltip=tr("Vectors layer of (u, v) at the trusted nodes; every "
                                        "node value is in its features."))
        self.vector_length = FloatSpinBox(label=tr("Vector scale"), value=0.0, min=0.0, max=1e6,
                                          step=0.5,
                                          tooltip=tr("Arrow length per unit displacement; 0 = "
                                                  "automatic (the longest arrows span about "
                                                  "one node step)."))
        self.mesh = CheckBox(text=tr("mesh"), value=False,
                             tooltip=tr("Shapes layer of the element outlines."))
        self.deformed = CheckBox(text=tr("deformed configuration"), value=False,
                                 tooltip=tr("Show fields, vectors, nodes and mesh where the "
                                         "material is in each frame instead of in the "
                                         "reference frame."))
        self.rigid = CheckBox(text=tr("subtract rigid-body motion"), value=False,
                              tooltip=tr("Show u, v, |u| and the arrows without each frame's "
                                      "best-fit rotation and translation (strains do not "
                                      "change), so that deformation stands out of a large "
                                      "rigid motion."))
        toggles = Container(widgets=[self.vectors, self.mesh, self.deformed, self.rigid],
                            layout="vertical", labels=False)
        self.note = Label(value=tr(_NOTE_REFERENCE))
        self.legend = Label(value=tr("Unreliable nodes: run an analysis first."))
        self.extend([self.show_field, toggles, self.vector_length, self.note, self.legend])
        # 0 is the automatic scale: say so rather than show "0.00"
        self.vector_length.native.setSpecialValueText(tr("automatic"))
        from qtpy.QtWidgets import QSizePolicy

        for label in (self.note, self.legend):
            label.native.setWordWrap(True)
            # wrapped text takes the width there is (never widens the dock), and the
            # height it needs then
            label.native.setSizePolicy(QSizePolicy.Policy.Preferred,
                                       QSizePolicy.Policy.Minimum)
            label.native.setMinimumWidth(120)

    def _setup_callbacks(self) -> None:
        for w in (self.mesh, self.deformed, self.vectors, self.rigid):
            w.changed.connect(self.display_changed.emit)
        self.deformed.changed.connect(self._on_deformed)
        self.show_field.changed.connect(lambda key: self.field_chosen.emit(str(key)))
        self.vector_length.changed.connect(
            lambda value: self.vector_length_changed.emit(float(value)))

    def _on_deformed(self, *_) -> None:
        self.note.value = tr(_NOTE_DEFORMED if self.deformed.value else _NOTE_REFERENCE)

    def set_legend(self, counts: dict[int, int]) -> None:
        """Show the legend for these reason counts ``{code: nodes}``."""
        self.legend.value = legend_html(counts)

    # ------------------------------------------------------------ state
    @property
    def choices(self) -> dict:
        """The display choices as plain values (for project files)."""
        return {"show_field": self.show_field.value, "vectors": self.vectors.value,
                "vector_length": float(self.vector_length.value), "mesh": self.mesh.value,
                "deformed": self.deformed.value, "rigid": self.rigid.value}

    def set_choices(self, values: dict) -> None:
        """Set the controls from :attr:`choices` (unknown keys are ignored)."""
        for key, value in values.items():
            control = getattr(self, key, None)
            if key in self.choices and control is not None:
                control.value = value

    def display(self, length: tuple[float, str], time: tuple[float | None, str]) -> Display:
        """The :class:`Display` of the controls with the units ``length`` (pixel
        size, unit) and ``time`` (frame interval or ``None``, unit)."""
        return Display(visible_field=self.show_field.value, vectors=self.vectors.value,
                       vector_length=float(self.vector_length.value), mesh=self.mesh.value,
                       deformed=self.deformed.value, rigid=self.rigid.value,
                       length_scale=float(length[0]), length_unit=length[1],
                       frame_interval=time[0], time_unit=time[1])
