"""Parts of the probe plot dock's layout: its status text and its scroll area.

The status text (probe messages, one line per probe with a problem) is a read-only
box of its own, a few lines tall, that scrolls: a long list never pushes into the
plot above it, and it is drawn on the theme's base colour, so it reads in a light and
a dark theme (issue 24, trap 7: a wrapped label drew light text over the white plot).
The whole dock scrolls when the window is lower than its controls and plot need, so
no control is squeezed over another and the window never grows to fit the dock.
"""

from __future__ import annotations

from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
from qtpy.QtCore import QSize, Qt
from qtpy.QtWidgets import QFrame, QLabel, QPlainTextEdit, QScrollArea, QSizePolicy, QWidget

from ..i18n import tr

__all__ = ["PlotCanvas", "StatusText", "WrappedLabel", "report_saved", "scrolled"]

#: the plot's preferred height (it grows with the dock; a low window scrolls)
PLOT_HINT_PX = 150

#: the status box's height in text lines (more lines scroll)
STATUS_LINES = 4


class StatusText(QPlainTextEdit):
    """A read-only, wrapped, scrolling status text with QLabel's ``text``/``setText``."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setReadOnly(True)
        self.setLineWrapMode(QPlainTextEdit.LineWrapMode.WidgetWidth)
        self.setFrameShape(QFrame.Shape.StyledPanel)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Fixed)
        self.setMinimumWidth(40)  # never the width of a long word
        line = self.fontMetrics().lineSpacing()
        margins = 2 * (self.frameWidth() + int(self.document().documentMargin())) + 2
        self.setFixedHeight(STATUS_LINES * line + margins)

    def text(self) -> str:
        return self.toPlainText()

    def setText(self, text: str) -> None:  # noqa: N802 (QLabel's name)
        if text != self.toPlainText():
            self.setPlainText(text)
        self.setToolTip(text)

    def hidden_lines(self) -> bool:
        """Whether part of the text is out of view (it is reached by scrolling)."""
        bar = self.verticalScrollBar()
        return bar.maximum() > bar.minimum()


class WrappedLabel(QLabel):
    """A wrapped label that is always as tall as its lines at its width (in a form
    row, Qt gave the load file's two lines the height of one: both cut)."""

    def _fit(self) -> None:
        need = self.heightForWidth(self.width())
        if need > 0 and need != self.minimumHeight():
            self.setMinimumHeight(need)

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        super().resizeEvent(event)
        self._fit()

    def setText(self, text: str) -> None:  # noqa: N802 (Qt's name)
        super().setText(text)
        self._fit()


class PlotCanvas(FigureCanvasQTAgg):
    """The plot canvas; it asks for a modest height (its figure's own size would be
    asked for in full in the dock's scroll area, pushing the controls out of view)."""

    def sizeHint(self) -> QSize:  # noqa: N802 (Qt's name)
        return QSize(super().sizeHint().width(), PLOT_HINT_PX)


def scrolled(content: QWidget) -> QScrollArea:
    """``content`` in a vertical scroll area that fills the dock."""
    area = QScrollArea()
    area.setWidgetResizable(True)
    area.setFrameShape(QFrame.Shape.NoFrame)
    area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    area.setWidget(content)
    return area


def report_saved(fn, path) -> None:
    """Call ``fn(path)`` (a save of the probe dock) and notify what came of it."""
    from napari.utils.notifications import show_error, show_info

    try:
        out = fn(path)
    except (ValueError, OSError) as exc:
        show_error(f"napari-aldic: {exc}")
        return
    if out is None:
        show_error(tr("napari-aldic: no probe values to save yet"))
    else:
        show_info(tr("napari-aldic: saved {out}").format(out=out))

