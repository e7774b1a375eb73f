"""Traps of issue 24, third part (6, 7, 14 and 16), one test each; each failed before
its fix (trap 6's real-run test excepted: the refit was already there, this test runs
it through a real analysis). Screenshots at 1280 x 720 go to the test's folder."""

from __future__ import annotations

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui


def _show(viewer, analysis, display=None):
    from napari_aldic._layers import Display
    from napari_aldic._qt.results import ResultLayers

    image = viewer.add_image(np.zeros((3, 192, 192), np.float32), name="speckle")
    results = ResultLayers(viewer)
    results.analysis, results.image = analysis, image
    results.show(display or Display(), image)
    return results


def _rect_in(widget, ancestor):
    from qtpy.QtCore import QRect

    return QRect(widget.mapTo(ancestor, widget.rect().topLeft()), widget.size())


def _raise_dock(widget) -> None:
    """Bring the dock of ``widget`` to the front of its tabs."""
    from qtpy.QtWidgets import QDockWidget

    while widget is not None and not isinstance(widget, QDockWidget):
        widget = widget.parentWidget()
    widget.raise_()


# ------------------------------------------------------------------ 7
def test_trap07_the_probe_status_has_its_own_row_and_never_covers_the_plot(
        make_napari_viewer, qtbot, tmp_path, small_analysis, save_screenshot):
    from qtpy.QtWidgets import QLabel

    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.plot_dock import ProbePlotDock

    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1280, 720)
    _show(viewer, small_analysis)
    dock = ProbePlotDock(viewer)
    viewer.window.add_dock_widget(dock, area="right", name="Probes")
    viewer.window.add_dock_widget(DICWidget(viewer), name="DIC (AL-DIC)", area="right",
                                  tabify=True)
    dock.add_probe_layers()
    # gauges and points outside the ROI (24..168 px): one message line each
    for y in (4, 12, 20, 178, 186):
        dock.shapes_layer.add_lines(np.array([[y, 4.0], [y, 188.0]]))
    dock.points_layer.add(np.array([[6.0, 6.0], [186.0, 186.0]]))
    load = tmp_path / "machine.csv"
    load.write_text("Frame;Force\n(-);(kN)\n0;0\n1;1.2\n2;2.4\n", encoding="utf-8")
    assert dock.load_csv(load, area_mm2=12.0)
    qtbot.wait(100)
    _raise_dock(dock)
    qtbot.wait(400)
    save_screenshot(viewer, tmp_path / "trap07_probes_1280x720.png")
    window = viewer.window._qt_window
    assert (window.width(), window.height()) == (1280, 720)  # the dock never grows it
    status, text = dock.status_label, dock.status_label.text()
    assert text.count("\n") >= 6, text  # a long list of messages
    # the status in a row of its own, under the plot, never over it
    s, c = _rect_in(status, dock), _rect_in(dock.canvas, dock)
    assert not s.intersects(c) and s.top() >= c.bottom(), (s, c)
    # every message readable: the status shows it all or scrolls to it
    if isinstance(status, QLabel):
        shown_all, scrolls = status.height() >= status.heightForWidth(status.width()), False
    else:
        shown_all, scrolls = False, status.hidden_lines()
        assert not scrolls or status.verticalScrollBar().isVisible()
    assert shown_all or scrolls
    # no control of the dock drawn over another (the load box squeezed over the plot)
    parts = [dock.load_button.parentWidget(), dock.canvas, status, dock.save_csv_button]
    for i, a in enumerate(parts):
        for b in parts[i + 1:]:
            assert not _rect_in(a, dock).intersects(_rect_in(b, dock)), (a, b)
        assert a.height() >= a.minimumSizeHint().height() or a is status, a
    # its own background, dark text on light or light on dark: readable
    pal = status.palette()
    fg, bg = (pal.color(r) for r in ((pal.ColorRole.Text, pal.ColorRole.Base)
                                     if not isinstance(status, QLabel) else
                                     (pal.ColorRole.WindowText, pal.ColorRole.Window)))
    assert abs(fg.lightnessF() - bg.lightnessF()) > 0.5
