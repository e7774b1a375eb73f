"""Traps of issue 24, one test each (each failed before its fix), and the dock model."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic._qt import DICWidget
from napari_aldic._qt.model import ROLE_KEY, DockModel, layer_role
from napari_aldic._qt.project import PROBE_KEY
from napari_aldic.engine import DICParams, StrainParams

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui

SHAPE = (96, 96)


def _dock(viewer):
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    return widget


def _rect(x0, y0, x1, y1):
    return np.array([[y0, x0], [y0, x1], [y1, x1], [y1, x0]], float)


# ------------------------------------------------------------------ the model
def test_the_model_is_qt_free_and_gives_the_run_its_job():
    code = ("import sys; import napari_aldic._qt.model as m; "
            "bad = [k for k in sys.modules if k.split('.')[0] in "
            "('qtpy', 'PyQt5', 'PyQt6', 'PySide6', 'magicgui', 'napari')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    model = DockModel()
    seen = []
    model.changed.connect(seen.append)
    model.update("params", DICParams(subset=41, mu=2e-3))
    model.update("params", DICParams(subset=41, mu=2e-3))  # no change: no signal
    model.update("tracking", {"reference": "incremental", "start": 1, "stop": 3, "stride": 2})
    assert seen == ["params", "tracking"]
    job = model.job(np.zeros((5, 64, 64)), None, source="img")
    assert job.params.subset == 41 and job.reference == "incremental"
    assert (job.start, job.stop, job.stride) == (1, 3, 2) and job.strain == StrainParams()
    assert "mu=0.002" in job.summary  # the hidden field kept from a file is said
    # what a project keeps; the remembered settings keep no frame range and no units
    kept = model.storable(frame_range=False)["settings"]
    assert "units" not in kept and kept["tracking"] == {"reference": "incremental",
                                                        "stride": 2}


def test_the_widget_fills_the_model_and_runs_its_job(make_napari_viewer_proxy, speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, SHAPE), name="speckle")
    w = _dock(viewer)
    w.subset.value, w.strain_window.value, w.method.value = 25, 7, "local"
    assert w.model.params.subset == 25 and w.model.params.method == "local"
    assert w.model.strain.window == 7
    job = w._job()
    assert job.params.subset == 25 and job.strain.window == 7 and job.stop == 2
    # the controls start from the engine's defaults (written once, in DICParams)
    fresh = DICWidget(make_napari_viewer_proxy())
    assert (fresh.subset.value, fresh.step.value, fresh.search.value) == (
        DICParams.subset, DICParams.step, DICParams.search)
    assert fresh.strain_window.value == StrainParams.window


# ------------------------------------------------------------------ 1
def test_trap01_a_shapes_layer_named_after_the_image_is_the_roi(make_napari_viewer_proxy,
                                                                speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, SHAPE), name="open_hole_tension")
    w = _dock(viewer)
    # napari's "New shapes layer" names it after the image: 'hole' in it means nothing
    roi = viewer.add_shapes([_rect(10, 10, 80, 80)], shape_type="rectangle",
                            name="open_hole_tension - Shapes")
    assert list(w.roi_add.value) == [roi] and list(w.roi_subtract.value) == []
    mask, _ = w.inputs.roi(SHAPE)
    assert mask.sum() == 71 * 71  # the rectangle is analysed, not the background
    crack = viewer.add_shapes([_rect(40, 40, 50, 50)], shape_type="rectangle",
                              name="crack from a notch (real) - Shapes")
    assert crack in w.roi_add.value and crack not in w.roi_subtract.value
    # the user chooses it as a hole: it leaves the ROI, and the choice stays with it
    w.roi_subtract.value = [crack]
    assert list(w.roi_add.value) == [roi] and layer_role(crack) == "roi_subtract"
    crack.name, roi.name = "ROI", "hole"  # renaming changes no role
    assert list(w.roi_add.value) == [roi] and list(w.roi_subtract.value) == [crack]
    # a new dock on the same viewer remembers the roles per layer
    w2 = DICWidget(viewer)
    assert list(w2.roi_add.value) == [roi] and list(w2.roi_subtract.value) == [crack]
    assert roi.metadata[ROLE_KEY] == "roi_add"


# ------------------------------------------------------------------ 2
def test_trap02_a_remembered_pixel_size_is_not_applied_to_another_image(
        make_napari_viewer_proxy, speckle_stack):
    from napari_aldic._qt import prefs

    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, SHAPE), name="first")
    w = _dock(viewer)
    w.unit.value, w.pixel_size.value = "mm", 0.02
    w._remember()
    assert "units" not in prefs.read_last_used()["settings"]
    # a file of 0.1 remembered the calibration: it is not applied either
    doc = prefs.read_last_used()
    doc["settings"]["units"] = {"pixel_size": 0.02, "unit": "mm"}
    prefs.write_last_used(doc)
    other = make_napari_viewer_proxy()
    img = other.add_image(speckle_stack(3, SHAPE), name="unrelated")
    w2 = _dock(other)
    assert tuple(img.scale)[-2:] == (1.0, 1.0) and w2.unit.value != "mm"
    assert w2.model.units is None or w2.model.units.pixel_size == 1.0


# ------------------------------------------------------------------ 3
def test_trap03_probe_layers_rescale_with_the_units(make_napari_viewer_proxy, speckle_stack):
    viewer = make_napari_viewer_proxy()
    img = viewer.add_image(speckle_stack(3, SHAPE), name="speckle")
    w = _dock(viewer)
    gauge = viewer.add_shapes([np.array([[20.0, 30.0], [70.0, 30.0]])], shape_type="line",
                              name="gauge", metadata={PROBE_KEY: {"kind": "line"}})
    points = viewer.add_points([[40.0, 40.0]], name="probe points",
                               metadata={PROBE_KEY: {"kind": "point"}})
    w.unit.value, w.pixel_size.value = "mm", 0.05
    for probe in (gauge, points):
        assert tuple(probe.scale)[-2:] == pytest.approx(tuple(img.scale)[-2:])
        assert [str(u) for u in probe.units][-2:] == [str(u) for u in img.units][-2:]
    # the probe still lies on the same pixels of the image
    world = gauge.data_to_world(gauge.data[0][0])
    assert np.allclose(img.world_to_data(world)[-2:], [20.0, 30.0])


# ------------------------------------------------------------------ 9
def test_trap09_the_status_is_not_ready_during_a_run(make_napari_viewer_proxy, qtbot,
                                                    speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(4, SHAPE), name="speckle")
    w = _dock(viewer)
    w.method.value, w.subset.value, w.step.value = "local", 21, 16
    assert "Ready." in w.status.value
    w.run_button.clicked()
    assert w.running
    assert "Ready." not in w.status.value and "Running" in w.status.value
    qtbot.waitUntil(lambda: not w.running, timeout=60_000)
    assert "Ready." in w.status.value


def test_trap09_a_run_that_compiles_says_so(make_napari_viewer_proxy, qtbot, speckle_stack,
                                            monkeypatch):
    """A first AL-DIC frame can spend a minute compiling kernels: the run's clock line
    says so (engine.is_compiling) instead of showing 0/N frames without a word."""
    import napari_aldic._qt.run as run_module

    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(4, SHAPE), name="speckle")
    w = _dock(viewer)
    w.method.value, w.subset.value, w.step.value = "local", 21, 16
    qtbot.waitUntil(lambda: not w.run_panel.preparing, timeout=120_000)
    monkeypatch.setattr(run_module, "is_compiling", lambda: True)
    w.run_button.clicked()
    w.run_panel._show_time()  # the clock's tick
    assert "compiling kernels" in w.run_panel.eta.value
    qtbot.waitUntil(lambda: not w.running, timeout=60_000)
    monkeypatch.setattr(run_module, "is_compiling", lambda: False)
    w.run_button.clicked()
    w.run_panel._show_time()
    assert "compiling" not in w.run_panel.eta.value
    qtbot.waitUntil(lambda: not w.running, timeout=60_000)


# ------------------------------------------------------------------ 18
CLOSE_SCRIPT = textwrap.dedent("""
    import sys, time
    import numpy as np
    import napari
    from qtpy.QtWidgets import QApplication
    from napari_aldic._qt import DICWidget
    from napari_aldic.engine import synthetic as S

    pat = S.make_pattern((96, 96), seed=1, margin=32)
    stack = np.stack([S.render(pat, (96, 96), None if k == 0 else S.Translation(0.3 * k, 0),
                               n_quad=2) for k in range(4)])

    def until(cond, seconds=60):
        t = time.time()
        while not cond() and time.time() - t < seconds:
            QApplication.processEvents()
            time.sleep(0.002)

    for when in ("run", "display"):
        viewer = napari.Viewer(show=False)
        viewer.add_image(stack, name="speckle")
        w = DICWidget(viewer)
        viewer.window.add_dock_widget(w, area="right")
        w.method.value, w.subset.value, w.step.value = "local", 21, 16
        w.run()
        panel = w.run_panel
        if when == "display":
            until(lambda: panel._steps is not None)
            assert panel._steps is not None, "the display never started"
        viewer.close()
        until(lambda: False, 1.5)  # timers and the worker would call into the closed dock
        print("closed mid-" + when, flush=True)
""")


@pytest.mark.slow  # ~15 s: napari in a subprocess (an abort would end the test run)
def test_trap18_closing_the_viewer_mid_run_or_mid_display_never_aborts(tmp_path):
    script = tmp_path / "close.py"
    script.write_text(CLOSE_SCRIPT, encoding="utf-8")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=300)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "closed mid-run" in out and "closed mid-display" in out
    assert "Fatal Python error" not in out and "wrapped C/C++ object" not in out


# ------------------------------------------------------------------ 6
def test_trap06_the_display_section_grows_with_its_legend(make_napari_viewer_proxy, qtbot,
                                                         speckle_stack):
    from napari_aldic.engine import Reason

    viewer = make_napari_viewer_proxy(show=True)
    viewer.add_image(speckle_stack(3, SHAPE), name="speckle")
    w = _dock(viewer)
    box = w.sections["5. Display"]
    assert box.isExpanded()
    qtbot.wait(50)
    w.display.set_legend({int(r): 10 + int(r) for r in list(Reason)[1:10]})  # 9 reasons
    content = box.content()  # superqt's content frame of the section
    # the open section is as tall as its panel needs (superqt fixes it when it opens)
    qtbot.waitUntil(lambda: content.maximumHeight() >= content.sizeHint().height(),
                    timeout=3000)
    legend = w.display.legend.native
    qtbot.waitUntil(lambda: legend.height() >= legend.heightForWidth(legend.width()),
                    timeout=3000)  # every reason shown, none clipped


# ------------------------------------------------------------------ 12
def test_trap11_12_a_reopened_analysis_in_its_units_and_in_view(make_napari_viewer_proxy, tmp_path,
                                                       speckle_stack):
    import tifffile

    tif = tmp_path / "stack.tif"
    tifffile.imwrite(tif, speckle_stack(3, SHAPE), photometric="minisblack")
    viewer = make_napari_viewer_proxy()
    viewer.open(str(tif), plugin="napari-aldic")
    w = _dock(viewer)
    viewer.add_shapes([_rect(10, 10, 80, 80)], shape_type="rectangle", name="ROI")
    w.unit.value, w.pixel_size.value = "mm", 0.02
    assert "mm" in w.exports.units_note.value
    path = w.save_project(tmp_path / "analysis")
    other = make_napari_viewer_proxy()
    w2 = _dock(other)
    assert "px" in w2.exports.units_note.value
    assert w2.open_project(path)
    # trap 11: the restored layers in the image's unit, and the image in view
    img2, [roi2] = w2.image.value, w2.roi_add.value
    assert [str(u) for u in roi2.units] == [str(u) for u in img2.units][-2:]
    assert "mm" in str(roi2.units[-1]) or "millimeter" in str(roi2.units[-1])
    centre = np.asarray(other.scene.camera.center)[-2:]
    assert np.allclose(centre, 0.02 * (SHAPE[0] - 1) / 2, atol=0.05)
    assert w2.model.units is not None and w2.model.units.unit == "mm"
    assert "mm" in w2.exports.units_note.value and "Lengths in px" not in \
        w2.exports.units_note.value


# ------------------------------------------------------------------ 17
def test_trap17_folded_sections_point_right(make_napari_viewer_proxy):
    from napari_aldic._qt.layout import COLLAPSED, EXPANDED

    w = DICWidget(make_napari_viewer_proxy())
    folded, open_ = w.sections["3. Strain"], w.sections["1. Images and region"]
    assert not folded.isExpanded() and open_.isExpanded()
    assert (COLLAPSED, EXPANDED) == ("▶", "▼")
    icon = folded.toggleButton().icon()
    assert not icon.isNull()
    # the icon superqt draws from the glyph: compare with one drawn from "▲"
    from superqt import QCollapsible

    up = QCollapsible("x", collapsedIcon="▲")
    right = QCollapsible("x", collapsedIcon="▶")
    img = lambda b: b.toggleButton().icon().pixmap(16, 16).toImage()  # noqa: E731
    assert img(folded) == img(right) and img(folded) != img(up)


# ------------------------------------------------------------------ 4
def test_trap04_a_long_load_description_never_widens_the_probes_dock(
        make_napari_viewer_proxy, qtbot, tmp_path, speckle_stack):
    from napari_aldic._qt.plot_dock import ProbePlotDock

    viewer = make_napari_viewer_proxy(show=True)
    viewer.add_image(speckle_stack(3, SHAPE), name="speckle")
    dock = ProbePlotDock(viewer)
    viewer.window.add_dock_widget(dock, area="right", name="Probes")
    before = dock.minimumSizeHint().width()
    load = tmp_path / ("testing_machine_export_of_the_long_fatigue_campaign_" * 4 + ".csv")
    load.write_text("Frame;Force\n(-);(kN)\n0;0,0\n1;1,2\n2;2,4\n", encoding="utf-8")
    assert dock.load_csv(load, area_mm2=12.0)
    assert len(dock.load_label.text()) > 60  # the description is long
    qtbot.wait(50)
    # the label's own minimum would be its longest word (~1500 px here): it is not asked for
    assert dock.load_label.minimumSizeHint().width() > 600
    assert dock.minimumSizeHint().width() < max(400, before + 60) and dock.width() < 600
