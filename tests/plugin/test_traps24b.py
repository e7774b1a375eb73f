"""Traps of issue 24, second part (8, 13, 14, 15 and live mode), one test each; each
failed before its fix."""

from __future__ import annotations

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic import i18n
from napari_aldic._layers import Display, bar_limits

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui


def _bar_ticks(lo, hi, dpi=96):
    """The tick values napari's colour bar (vispy's axis, 150 px high) labels."""
    from vispy.visuals.axis import _get_ticks_talbot

    return np.asarray(_get_ticks_talbot(lo, hi, 150 / dpi, 2))


def _show(viewer, analysis, display: Display | None = None):
    from napari_aldic._qt.results import ResultLayers

    image = viewer.add_image(np.zeros((3, 192, 192), np.float32), name="speckle")
    results = ResultLayers(viewer)
    results.analysis, results.image = analysis, image
    results.show(display or Display(), image)
    return results


def _dock_with_gauges(viewer, qtbot, tmp_path, gauges):
    from napari_aldic._qt.plot_dock import ProbePlotDock

    dock = ProbePlotDock(viewer)
    qtbot.addWidget(dock)
    dock.add_probe_layers()
    for x0, y0, x1, y1 in gauges:
        dock.shapes_layer.add_lines(np.array([[y0, x0], [y1, x1]], float))
    load = tmp_path / "machine.csv"
    load.write_text("Frame;Force\n(-);(kN)\n0;0\n1;1.2\n2;2.4\n", encoding="utf-8")
    assert dock.load_csv(load, area_mm2=12.0)
    dock.recompute()
    return dock


# ------------------------------------------------------------------ 14
@pytest.mark.parametrize("a", [3.1e-5, 8e-4, 0.0031, 0.012, 0.8, 2.6, 47.0])
def test_trap14_symmetric_and_from_zero_limits_get_ticks_at_their_ends(a):
    for lo, hi in ((-a, a), (0.0, a)):
        blo, bhi = bar_limits((lo, hi))
        assert bhi >= a and bhi <= 2.01 * a and blo == (0.0 if lo == 0 else -bhi)
        for dpi in (72, 96, 120):
            ticks = _bar_ticks(blo, bhi, dpi)
            for end in (blo, 0.0, bhi):  # -a, 0, +a (or 0, a) labelled
                assert np.isclose(ticks, end, rtol=1e-6, atol=1e-12 * bhi).any(), (a, ticks)
    assert bar_limits((-0.3, 1.7)) == (-0.3, 1.7)  # a plain range stays as it is


def test_trap14_the_canvas_colour_bar_shows_its_limits(make_napari_viewer_proxy,
                                                           small_analysis):
    viewer = make_napari_viewer_proxy()
    results = _show(viewer, small_analysis, Display(length_scale=0.01, length_unit="mm"))
    for key, unit in (("|u|", "[mm]"), ("exx", "[-]"), ("von Mises", "[-]")):
        results.show_field(key)
        layer = results.layer(key)
        assert layer.colorbar.visible  # its unit is in the layer's name (no bar label)
        assert layer.name.endswith(unit)
        lo, hi = layer.contrast_limits
        ticks = _bar_ticks(lo, hi)
        assert all(np.isclose(ticks, e, atol=1e-9 * hi).any() for e in (lo, 0.0, hi)), ticks
        others = [results.layer(k) for k in ("u", "exy") if k != key]
        assert not any(o.colorbar.visible for o in others)


# ------------------------------------------------------------------ 8
def test_trap08_the_user_chooses_the_gauge_and_degraded_points_are_marked(
        make_napari_viewer_proxy, qtbot, tmp_path, small_analysis):
    from napari_aldic._qt.gauges import fill_gauges

    viewer = make_napari_viewer_proxy()
    _show(viewer, small_analysis)
    dock = _dock_with_gauges(viewer, qtbot, tmp_path, [(50, 96, 140, 96), (40, 60, 150, 60)])
    # line2 read with care at frame 1 (as next to a crack or a hole)
    dock.table.columns["line2_strain"].status[1] = 1
    status = np.asarray(dock.table.columns["line2_strain"].status)
    fill_gauges(dock.gauge_combo, dock.table)
    combo = dock.gauge_combo
    assert [combo.itemData(i) for i in range(combo.count())] == ["line1_strain",
                                                                 "line2_strain"]
    assert "degraded" in combo.itemText(1) and "degraded" not in combo.itemText(0)
    combo.setCurrentIndex(1)
    assert dock._ss_column == "line2_strain"
    ax = dock.axes["stress"]
    assert ax.get_xlabel().startswith("line2")
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "degraded" in labels
    marked = [ln for ln in ax.get_lines() if ln.get_label() == "degraded"][0]
    assert len(marked.get_xdata()) == int((status == 1).sum())
    dock.recompute()  # a new measurement keeps the choice
    assert dock.gauge_combo.currentData() == "line2_strain" == dock._ss_column


# ------------------------------------------------------------------ 13
def test_trap13_probe_messages_and_plot_axes_follow_the_language(
        make_napari_viewer_proxy, qtbot, tmp_path, small_analysis, monkeypatch):
    monkeypatch.setenv(i18n.ENV_VAR, "de")
    try:
        viewer = make_napari_viewer_proxy()
        _show(viewer, small_analysis)
        dock = _dock_with_gauges(viewer, qtbot, tmp_path, [(4, 60, 188, 60)])
        assert i18n.current_language() == "de"
        ax = dock.axes["stress"]
        assert ax.get_xlabel() == i18n.tr("{gauge} (engineering strain)").format(
            gauge="line1_strain") and "engineering" not in ax.get_xlabel()
        assert "engineering" not in ax.get_ylabel() and "stress" not in ax.get_title()
        assert dock.axes["lines"].get_xlabel() == i18n.tr("frame") != "frame"
        text = dock.status_label.text()
        assert "line1:" in text and " at frame(s) " not in text and "degraded" not in text
    finally:
        i18n.set_language("en")


# trap 13's German export text: tests/plugin/test_probe_text.py::
# test_trap13_the_german_export_section_fits (every label, button and choice)


# ------------------------------------------------------------------ 15
def test_trap15_probes_over_the_deformed_view_carry_a_hint(make_napari_viewer_proxy, qtbot,
                                                           tmp_path, small_analysis):
    hint = "reference configuration"
    viewer = make_napari_viewer_proxy()
    results = _show(viewer, small_analysis)
    dock = _dock_with_gauges(viewer, qtbot, tmp_path, [(50, 96, 140, 96)])
    assert hint not in dock.status_label.text()
    results.show(Display(deformed=True), results.image)
    dock.recompute()
    assert hint in dock.status_label.text()


# ------------------------------------------------------------------ live mode
def test_live_status_says_live_and_no_two_analyses_at_once(make_napari_viewer_proxy, qtbot,
                                                           tmp_path, speckle_stack):
    from napari_aldic._qt import DICWidget

    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, (96, 96)), name="speckle")
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
    w.method.value, w.subset.value, w.step.value = "local", 21, 16
    (tmp_path / "cam").mkdir()
    w.live.folder.value, w.live.run_dir.value = str(tmp_path / "cam"), str(tmp_path / "run")
    assert "Ready." in w.status.value and w.run_button.enabled
    w.live.start()
    assert w.live.model.running
    assert "Ready." not in w.status.value and "Live" in w.status.value
    assert not w.run_button.enabled
    w.run()  # a script's run is refused too
    assert not w.running
    w.live.stop()
    qtbot.waitUntil(lambda: not w.live.model.running and w.live.start_button.enabled,
                    timeout=20_000)
    assert "Ready." in w.status.value and w.run_button.enabled
    w.run_button.clicked()  # a run: live cannot start beside it
    assert w.running and not w.live.start_button.enabled
    w.live.start()
    assert not w.live.model.running
    qtbot.waitUntil(lambda: not w.running, timeout=60_000)
    assert w.live.start_button.enabled


# ------------------------------------------------------------------ 5
def test_trap05_a_reopened_dock_keeps_the_analysis(make_napari_viewer_proxy, small_analysis):
    from dataclasses import replace

    from napari_aldic._qt import DICWidget

    viewer = make_napari_viewer_proxy()
    seeded = replace(small_analysis, params=small_analysis.params.replace(
        init="seeds", seeds=((100.0, 100.0),)))
    results = _show(viewer, seeded)
    results.image.name = seeded.source
    first = DICWidget(viewer)
    assert first.analysis is seeded  # the dock takes up what the viewer shows
    # the language changes: the user closes the dock and opens a new one
    first.native.close()
    again = DICWidget(viewer)
    assert again.analysis is not None and again.analysis.params == seeded.params
    assert again.analysis.frames == seeded.frames and again._results.image.name == "speckle"
    assert again.exports.export_button.enabled
    assert again.correlation.init.value == "seeds" == again.model.init
