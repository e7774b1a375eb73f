"""Traps of issue 24, third part (6, 7, 14 and 16), one test each; each failed before
its fix, except trap 6's: its clipping was not reproduced on main (nor with the earlier
refit of the sections removed), so its test is a guard that runs a real analysis with
nine reasons through the dock. Screenshots at 1280 x 720 go to the test's folder."""

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
    lab = dock.load_label  # the load file's wrapped lines get their height (both were cut
    assert lab.text().startswith("3 load samples")  # at 1400 x 900, the dock not scrolled)
    for size in ((1280, 720), (1400, 900)):
        window.resize(*size)
        qtbot.wait(300)
        assert lab.height() >= lab.heightForWidth(lab.width()), (size, lab.height())
    window.resize(1280, 720)
    # its own background, dark text on light or light on dark: readable
    pal = status.palette()
    fg, bg = (pal.color(r) for r in ((pal.ColorRole.Text, pal.ColorRole.Base)
                                     if not isinstance(status, QLabel) else
                                     (pal.ColorRole.WindowText, pal.ColorRole.Window)))
    assert abs(fg.lightnessF() - bg.lightnessF()) > 0.5


# ------------------------------------------------------------------ 16
def test_trap16_the_log_summary_says_u_v_in_the_chosen_unit(small_analysis):
    import re

    from napari_aldic._qt.explain import result_summary
    from napari_aldic.engine import Units

    res = small_analysis.results[-1]
    valid = np.asarray(res.valid, bool)
    px = result_summary(res)
    mm = result_summary(res, Units(0.02, "mm"))
    assert " px [" in px and " mm [" in mm and " px [" not in mm
    u_mm = float(re.search(r"u: mean ([-+0-9.e]+) mm", mm).group(1))
    assert u_mm == pytest.approx(0.02 * np.asarray(res.u)[valid].mean(), rel=1e-3)
    v_min = float(re.search(r"v: mean \S+ mm \[([-+0-9.e]+),", mm).group(1))
    assert v_min == pytest.approx(0.02 * np.asarray(res.v)[valid].min(), rel=1e-3)
    assert "subset 21 px" in mm  # the subset and step stay in pixels
    assert result_summary(res, Units()) == px


def test_trap16_a_run_logs_its_summary_in_mm(make_napari_viewer_proxy, qtbot, speckle_stack):
    from napari_aldic._qt import DICWidget

    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, (96, 96)), name="speckle")
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
    w.method.value, w.subset.value, w.step.value = "local", 21, 16
    w.unit.value, w.pixel_size.value = "mm", 0.02
    assert w._job().units.unit == "mm"
    w.run()
    qtbot.waitUntil(lambda: not w.running, timeout=120_000)
    summary = [ln for ln in w.log.value.splitlines() if ln.startswith("u: mean")]
    assert summary and " mm [" in summary[-1] and " px [" not in summary[-1], summary


def _pages(pdf) -> int:
    import re

    return len(re.findall(rb"/Type\s*/Page(?!s)", pdf.read_bytes()))


def _probes_with_load(viewer, tmp_path, qtbot):
    from napari_aldic._qt.plot_dock import ProbePlotDock

    dock = ProbePlotDock(viewer)
    qtbot.addWidget(dock)
    dock.add_probe_layers()
    dock.shapes_layer.add_lines(np.array([[96.0, 40.0], [96.0, 150.0]]))
    dock.points_layer.add(np.array([[80.0, 80.0]]))
    load = tmp_path / "machine.csv"
    load.write_text("Frame;Force\n(-);(kN)\n0;0\n1;1.2\n2;2.4\n", encoding="utf-8")
    assert dock.load_csv(load, area_mm2=12.0)
    dock.recompute()
    assert "stress_MPa" in dock.table.columns
    return dock


def test_trap16_the_widget_pdf_report_has_a_probe_page(make_napari_viewer_proxy, qtbot,
                                                       tmp_path, small_analysis):
    from napari_aldic._qt import DICWidget

    viewer = make_napari_viewer_proxy()
    viewer.add_image(np.zeros((3, 192, 192), np.float32), name="speckle")
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
    w.show_analysis(small_analysis)
    n = _pages(w.exports.export(tmp_path / "plain.pdf", "pdf")[0])
    assert n >= 5 and w.exports.probe_table() is None  # no probes: no probe page
    _probes_with_load(viewer, tmp_path, qtbot)
    table = w.exports.probe_table()
    assert table is not None and "stress_MPa" in table.columns  # the dock's load file too
    with_probes = w.exports.export(tmp_path / "probes.pdf", "pdf")[0]
    assert _pages(with_probes) == n + 1
    # the button's way (a worker thread) too
    w.exports.export_in_background(tmp_path / "button.pdf", "pdf")
    qtbot.waitUntil(lambda: (tmp_path / "button.pdf").exists() and w.exports._worker is None,
                    timeout=60_000)
    assert _pages(tmp_path / "button.pdf") == n + 1


def test_trap16_a_project_keeps_the_results_and_the_load_file(make_napari_viewer_proxy, qtbot,
                                                              tmp_path, small_analysis,
                                                              speckle_stack):
    import shutil

    import tifffile

    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.plot_dock import ProbePlotDock

    tif = tmp_path / "data" / "stack.tif"
    tif.parent.mkdir()
    tifffile.imwrite(tif, speckle_stack(3, (192, 192)), photometric="minisblack")
    viewer = make_napari_viewer_proxy()
    viewer.open(str(tif), plugin="napari-aldic")
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
    w.unit.value, w.pixel_size.value = "mm", 0.02
    w.show_analysis(small_analysis)
    _probes_with_load(viewer, tmp_path / "data", qtbot)
    (tmp_path / "work").mkdir()
    project = w.save_project(tmp_path / "work" / "analysis.json")
    assert project is not None and (tmp_path / "work" / "analysis_results").is_dir()
    # the project and its results move together to another folder (paths are relative)
    moved = tmp_path / "moved"
    shutil.copytree(tmp_path / "work", moved / "work")
    shutil.copytree(tmp_path / "data", moved / "data")
    shutil.rmtree(tmp_path / "work")
    other = make_napari_viewer_proxy()
    w2 = DICWidget(other)
    other.window.add_dock_widget(w2, name="DIC (AL-DIC)", area="right")
    assert w2.analysis is None and not w2.exports.export_button.enabled
    assert w2.open_project(moved / "work" / "analysis.json")
    a = w2.analysis
    assert a is not None and a.frames == small_analysis.frames  # no run needed
    for r0, r1 in zip(small_analysis.results, a.results):
        np.testing.assert_allclose(r1.u, r0.u, atol=1e-9)
        np.testing.assert_array_equal(r1.valid, r0.valid)
    np.testing.assert_allclose(a.strains[-1].exx, small_analysis.strains[-1].exx, atol=1e-9)
    assert w2.exports.export_button.enabled and w2._results.layer("|u|") is not None
    assert "mm" in w2._results.layer("|u|").name
    dock = ProbePlotDock(other)  # the probes dock opened again: the load file is back
    qtbot.addWidget(dock)
    dock.recompute()
    assert dock.load_record is not None and "stress_MPa" in dock.table.columns
    assert str(moved / "data") in str(dock.load_record.source)
    # a changed result file is named and not used (the set-up still opens)
    frame = sorted((moved / "work" / "analysis_results").glob("frame_*.npz"))[-1]
    frame.write_bytes(frame.read_bytes()[:-10] + b"0123456789")
    third = make_napari_viewer_proxy()
    w3 = DICWidget(third)
    third.window.add_dock_widget(w3, name="DIC (AL-DIC)", area="right")
    assert w3.open_project(moved / "work" / "analysis.json")
    assert w3.analysis is None and "results were not restored" in w3.log.value
    assert frame.name in w3.log.value


# ------------------------------------------------------------------ 14
def test_trap14_the_colour_bar_says_its_unit_beside_it(make_napari_viewer, qtbot, tmp_path,
                                                      small_analysis, save_screenshot):
    from napari_aldic._layers import Display

    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1280, 720)
    results = _show(viewer, small_analysis, Display(length_scale=0.01, length_unit="mm"))
    for key, unit in (("u", "[mm]"), ("exy", "[-]"), ("|u|", "[mm]")):
        results.show_field(key)
        qtbot.wait(200)
        save_screenshot(viewer, tmp_path / f"trap14_{key.replace('|', 'abs_')}_1280x720.png")
        layer = results.layer(key)
        bar, name = layer.colorbar, layer.name_overlay
        assert bar.visible and name.visible and layer.name.endswith(unit)
        assert name.position == bar.position  # the name, with its unit, beside the bar
        lo, hi = layer.contrast_limits
        if key == "exy":  # symmetric: -max, 0, +max ticked (the rounded limits)
            assert lo == -hi and hi > 0
        for other in ("u", "exy", "|u|", "exx", "von Mises"):
            if other != key:
                o = results.layer(other)
                assert not o.colorbar.visible and not o.name_overlay.visible, other


# ------------------------------------------------------------------ 6
def _damaged(stack):
    """Frames 1 and 2 with a blank patch, noise, a shifted block and a saturated band:
    nodes untrusted for many reasons."""
    stack = stack.copy()
    rng = np.random.default_rng(1)
    for k in (1, 2):
        stack[k, 20:60, 20:60] = 128
        stack[k, 120:170, 20:70] = rng.integers(0, 255, (50, 50))
        stack[k, 100:160, 110:170] = np.roll(stack[0, 100:160, 110:170], 25, axis=1)
        stack[k, 10:30, 120:180] = 255
    return stack


def test_trap06_after_a_run_every_reason_of_the_display_legend_is_shown(
        make_napari_viewer, qtbot, tmp_path, speckle_stack, save_screenshot):
    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.plot_dock import ProbePlotDock

    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1280, 720)
    viewer.add_image(_damaged(speckle_stack(3, (192, 192))), name="speckle")
    viewer.add_shapes([np.array([[4, 4], [4, 188], [188, 188], [188, 4]], float)],
                      shape_type="rectangle", name="ROI", face_color="transparent")
    w, probes = DICWidget(viewer), ProbePlotDock(viewer)
    viewer.window.add_dock_widget(probes, area="right", name="Probes")
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right", tabify=True)
    w.method.value, w.subset.value, w.step.value = "local", 21, 8
    w.run_button.clicked()
    qtbot.wait(100)
    _raise_dock(probes)  # the user watches the probes during the run: the dock is hidden
    qtbot.waitUntil(lambda: not w.running, timeout=120_000)
    qtbot.wait(300)
    _raise_dock(w.native)
    qtbot.wait(300)
    last = w.analysis.results[-1]
    reasons = set(np.asarray(last.reason)[~np.asarray(last.valid, bool)].tolist())
    assert len(reasons) >= 6, reasons  # a long legend
    legend, box = w.display.legend.native, w.sections["5. Display"]
    assert legend.text().count("&#10006;") == len(reasons)  # one row per reason
    w.scroll_area.ensureWidgetVisible(legend)
    qtbot.wait(200)
    save_screenshot(viewer, tmp_path / "trap06_display_after_run_1280x720.png")
    content = box.content()
    for width in (None, 560, 700):  # as laid out, and in a wider dock
        if width:
            window = viewer.window._qt_window
            dock = w.native
            while dock is not None and dock.metaObject().className() != "QtViewerDockWidget":
                dock = dock.parentWidget()
            from qtpy.QtCore import Qt

            window.resizeDocks([dock], [width], Qt.Orientation.Horizontal)
            qtbot.wait(300)
        # the legend gets the height its wrapped rows need, and the open section shows it
        assert legend.height() >= legend.heightForWidth(legend.width()), width
        bottom = legend.mapTo(content, legend.rect().bottomLeft()).y()
        assert bottom <= content.height() <= content.maximumHeight(), (width, bottom,
                                                                        content.height())
