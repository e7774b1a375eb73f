"""What the panels share: the :class:`Panel` base, section titles, settings plans.

A *plan* is a list of ``(control, value)`` pairs that a settings file asks
for. Every value is checked against its control first (:func:`put`), so a
file is either applied completely (:func:`apply_plan`) or not at all.
"""

from __future__ import annotations

import math
from typing import Any

from magicgui.widgets import ComboBox, Container, FloatSpinBox, Label, SpinBox

from ..i18n import tr

__all__ = ["Panel", "Plan", "section", "align_labels", "check_value", "put", "apply_plan",
           "fit_decimals"]

#: ``(control, value)`` pairs to apply together
Plan = list[tuple[Any, Any]]


class Panel(Container):
    """A panel of the dock widget: its controls are made in ``_setup_ui`` and
    connected in ``_setup_callbacks`` (called in this order on construction).

    Parameters
    ----------
    labels : bool
        Show the controls' labels in a column beside them.
    layout : {"vertical", "horizontal"}
    margins : 4-tuple or None
        Layout margins; ``None`` keeps magicgui's default.
    """

    def __init__(self, *, labels: bool = True, layout: str = "vertical",
                 margins: tuple | None = (0, 0, 0, 0)):
        super().__init__(labels=labels, layout=layout)
        if margins is not None:
            self.margins = margins
        self._setup_ui()
        self._setup_callbacks()

    def _setup_ui(self) -> None:
        raise NotImplementedError

    def _setup_callbacks(self) -> None:
        """Connect the controls (nothing by default)."""


def align_labels(panels) -> None:
    """Give the labelled controls of several panels one label column width, as
    if they were one form (magicgui aligns the labels of one container only)."""
    from magicgui.application import use_app

    measure = use_app().get_obj("get_text_width")
    # magicgui's own row of a control: label + control (None for buttons, check boxes)
    rows = [(w.label, w._labeled_widget()) for panel in panels for w in panel]
    rows = [(label, row) for label, row in rows if row is not None]
    if rows:
        widest = max(measure(label) for label, _ in rows)
        for _, row in rows:
            row.label_width = widest


def section(title: str) -> Label:
    """The bold title line of a panel."""
    return Label(value=f"<b>{title}</b>", label="")


def _whole(value, what: str) -> int:
    """``value`` as an int; ``ValueError`` naming ``what`` unless it is a whole number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (isinstance(value, float) and not value.is_integer()):
        raise ValueError(tr("{what} {value!r} must be a whole number").format(
                                what=what, value=value))
    return int(value)


def check_value(widget, value, what: str) -> None:
    """Raise ``ValueError`` unless ``widget`` can take ``value`` as it is."""
    if isinstance(widget, ComboBox):
        if value not in widget.choices:
            raise ValueError(tr("{what} {value!r} is not one of {list}").format(
                                    what=what, value=value, list=list(widget.choices)))
        return
    if isinstance(widget, FloatSpinBox):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not math.isfinite(value):
            raise ValueError(tr("{what} {value!r} must be a number").format(
                                    what=what, value=value))
    elif isinstance(widget, SpinBox):
        value = _whole(value, what)
    if not widget.min <= value <= widget.max:
        raise ValueError(tr("{what} {value:g} is outside the range {min:g}..{max:g} of the "
                            "widget").format(
                                what=what, value=value, min=widget.min, max=widget.max))


def put(plan: Plan, widget, value, what: str) -> None:
    """Append ``(widget, value)`` to ``plan`` after :func:`check_value`."""
    check_value(widget, value, what)
    plan.append((widget, value))


def fit_decimals(spin: FloatSpinBox, value: float) -> None:
    """Show enough decimals in ``spin`` to hold ``value`` exactly (up to 10)."""
    native = spin.native
    if not hasattr(native, "decimals"):  # pragma: no cover - another backend
        return
    d = native.decimals()
    while d < 10 and abs(round(value, d) - value) > 1e-12 * max(1.0, abs(value)):
        d += 1
    if d > native.decimals():
        native.setDecimals(d)


def apply_plan(plan: Plan) -> None:
    """Set every control of ``plan`` to its value."""
    for widget, value in plan:
        if isinstance(widget, FloatSpinBox):
            fit_decimals(widget, float(value))
        widget.value = value
