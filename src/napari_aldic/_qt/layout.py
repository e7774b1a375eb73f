"""The dock's layout: collapsible sections in one scroll area, run controls below.

A first-time user reads the sections top to bottom (images and region, mesh and
correlation, strain, units, then Run below, then display and export); every
section folds away. At 1280 x 720 only the scroll area shrinks: the status
line, Run, Cancel and the progress stay in view.
"""

from __future__ import annotations

from qtpy.QtCore import QEvent, QObject, QSize, Qt, QTimer
from qtpy.QtWidgets import QComboBox, QFrame, QScrollArea, QVBoxLayout, QWidget
from superqt import QCollapsible

from ..i18n import tr

__all__ = ["sections_area", "divider", "Section", "EXPANDED", "COLLAPSED"]

#: the least height of the sections' scroll area (about four rows of controls)
MIN_ROWS_PX = 120
#: the marks of an open and a folded section
EXPANDED, COLLAPSED = "▼", "▶"
#: ``(title, widget, expanded)``
Section = tuple[str, QWidget, bool]


class _Scroll(QScrollArea):
    """A vertical scroll area at least as wide as its content needs, so that the
    dock never cuts controls off at the right."""

    def _wide(self, hint: QSize, tall: int = 0) -> QSize:
        inner = self.widget()
        if inner is None:
            return hint
        need = inner.minimumSizeHint().width() + self.verticalScrollBar().sizeHint().width()
        return QSize(max(hint.width(), need + 2 * self.frameWidth()), max(hint.height(), tall))

    def minimumSizeHint(self) -> QSize:  # noqa: N802 (Qt's name)
        # a few rows of controls always in view, also beside another dock (the probes)
        return self._wide(super().minimumSizeHint(), MIN_ROWS_PX)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt's name)
        # the content's needs changed (e.g. a long layer name): ask the dock again
        if obj is self.widget() and event.type() == QEvent.Type.LayoutRequest:
            self.updateGeometry()
        return super().eventFilter(obj, event)

    def sizeHint(self) -> QSize:  # noqa: N802 (Qt's name)
        inner = self.widget()
        tall = min(inner.sizeHint().height(), 700) if inner is not None else 0
        return self._wide(super().sizeHint(), tall)


class _Refit(QObject):
    """Keeps an open section as tall as its panel needs: superqt fixes the height
    of an open section when it opens (its content's size hint), so a panel that grows
    later (the Display legend after a run) was clipped until folded and unfolded
    again. The height is that of the panel's wrapped text at the section's width
    (a narrower dock wraps more lines than the size hint counts), set after
    superqt's own refit of a resize (one turn of the event loop later)."""

    def __init__(self, box: QCollapsible):
        super().__init__(box)
        self._box = box
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(0)
        self._timer.timeout.connect(self.refit)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt's name)
        if event.type() in (QEvent.Type.LayoutRequest, QEvent.Type.Resize) and \
                self._box.isExpanded():
            self._timer.start()
        return False

    def refit(self) -> None:
        """Open the section to the height its content needs at its width."""
        box = self._box
        if not box.isExpanded():
            return
        content = box.content()
        need = content.sizeHint().height()
        layout = content.layout()
        if layout is not None and layout.hasHeightForWidth():
            need = max(need, layout.totalHeightForWidth(content.width()))
        if content.maximumHeight() != need + 10:  # superqt's margin
            content.setMaximumHeight(need + 10)


def sections_area(sections: list[Section]) -> tuple[QScrollArea, dict[str, QCollapsible]]:
    """A scroll area holding one collapsible section per ``(title, widget,
    expanded)``; returns it and the sections by title."""
    inner = QWidget()
    layout = QVBoxLayout(inner)
    layout.setContentsMargins(2, 2, 2, 2)
    layout.setSpacing(0)
    found: dict[str, QCollapsible] = {}
    for title, widget, expanded in sections:
        # "▶" folded, "▼" open (superqt's "▲" for a folded section reads as "open above")
        box = QCollapsible(tr(title), expandedIcon=EXPANDED, collapsedIcon=COLLAPSED)
        box.setDuration(0)  # no animation: the scroll area resizes at once
        box.layout().setContentsMargins(0, 0, 0, 4)
        box.addWidget(widget)
        widget.installEventFilter(_Refit(box))
        if expanded:
            box.expand(animate=False)
        else:
            box.collapse(animate=False)
        button = box.toggleButton()
        font = button.font()
        font.setBold(True)
        button.setFont(font)
        layout.addWidget(box)
        found[title] = box
    layout.addStretch(1)
    for combo in inner.findChildren(QComboBox):
        # long choices (layer names, formats) must not widen the dock beyond the window
        combo.setSizeAdjustPolicy(
            QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
        combo.setMinimumContentsLength(10)
    scroll = _Scroll()
    scroll.setWidgetResizable(True)
    scroll.setWidget(inner)
    inner.installEventFilter(scroll)
    scroll.setFrameShape(QFrame.Shape.NoFrame)
    scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    return scroll, found


def divider() -> QFrame:
    """A thin horizontal line between the scroll area and the run controls."""
    line = QFrame()
    line.setFrameShape(QFrame.Shape.HLine)
    line.setFrameShadow(QFrame.Shadow.Sunken)
    return line
