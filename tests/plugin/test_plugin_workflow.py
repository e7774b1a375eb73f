"""Saved analyses (project files), remembered parameters, exports and the engine warm-up."""

from __future__ import annotations

import json

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401
import tifffile

from napari_aldic._qt import DICWidget, warmup
from napari_aldic._qt.project import PROBE_KEY

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui


@pytest.fixture(autouse=True)
def _fresh_notifications():
    """Start with an empty notification log (napari's manager is process-wide)."""
    from napari.utils.notifications import notification_manager

    notification_manager.records.clear()
    yield

SHAPE = (96, 96)


def _dock(viewer):
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    return widget


def _errors():
    from napari.utils.notifications import NotificationSeverity, notification_manager

    return [n.message for n in notification_manager.records
            if n.severity == NotificationSeverity.ERROR]


def _rect(x0, y0, x1, y1):
    return np.array([[y0, x0], [y0, x1], [y1, x1], [y1, x0]], float)


#: controls a project restores, with non-default values
CUSTOM = {"method": "local", "subset": 25, "step": 6, "search": 14, "refine": "light",
          "reference": "accumulative", "stride": 1, "start": 1, "stop": 3,
          "strain_window": 7, "strain_method": "fem", "strain_measure": "infinitesimal",
          "unit": "µm", "pixel_size": 0.5, "time_unit": "s", "frame_interval": 2.0,
          "show_field": "exx", "vectors": False, "mesh": True, "deformed": True,
          "rigid": True}


def _set(widget, values):
    for name, value in values.items():
        getattr(widget, name).value = value


def _values(widget, names):
    return {name: getattr(widget, name).value for name in names}


def test_project_saves_and_reopens_layers_and_controls(make_napari_viewer_proxy, tmp_path,
                                                       speckle_stack):
    tif = tmp_path / "stack.tif"
    tifffile.imwrite(tif, speckle_stack(4, SHAPE), photometric="minisblack")
    viewer = make_napari_viewer_proxy()
    [image] = viewer.open(str(tif), plugin="napari-aldic")
    w = _dock(viewer)
    roi = viewer.add_shapes([_rect(10, 10, 86, 86)], shape_type="rectangle", name="ROI")
    hole = viewer.add_shapes([np.array([[40.0, 40.0], [56.0, 56.0]])], shape_type="ellipse",
                             name="hole")
    w.roi_subtract.value = [hole]  # the user's choice (never by its name)
    painted = np.zeros(SHAPE, np.uint8)
    painted[5:90, 8:92] = 1
    labels = viewer.add_labels(painted, name="roi labels")
    refine = np.zeros(SHAPE, np.uint8)
    refine[30:40, 30:40] = 1
    brush = viewer.add_labels(refine, name="refine")
    seeds = viewer.add_points([[20.0, 24.0]], name="seeds")
    probe = viewer.add_shapes([np.array([[20.0, 30.0], [70.0, 30.0]])], shape_type="line",
                              name="gauge", metadata={PROBE_KEY: {"kind": "line"}})
    assert list(w.roi_add.value) == [roi] and list(w.roi_subtract.value) == [hole]
    assert w.roi_labels.value == labels and w.brush.value == brush and w.seeds.value == seeds
    _set(w, CUSTOM)
    path = w.save_project(tmp_path / "analysis")
    assert path == tmp_path / "analysis.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    # the image path is stored relative to the project file (issue 23)
    assert doc["format"] == "napari-aldic-project" and doc["image"]["path"] == "stack.tif"
    assert {r["role"] for r in doc["layers"]} == {"roi_add", "roi_subtract", "roi_labels",
                                                   "brush", "seeds", "probe"}

    other = make_napari_viewer_proxy()
    w2 = _dock(other)
    assert w2.open_project(path) is True
    assert not _errors()
    img2 = w2.image.value
    np.testing.assert_array_equal(np.asarray(img2.data), np.asarray(image.data))
    assert tuple(img2.scale) == pytest.approx((2.0, 0.5, 0.5))  # units applied once
    assert _values(w2, CUSTOM) == CUSTOM
    assert w2.init.value == "seeds"
    [roi2], [hole2] = w2.roi_add.value, w2.roi_subtract.value
    np.testing.assert_allclose(roi2.data[0], roi.data[0])
    assert list(hole2.shape_type) == ["ellipse"]
    np.testing.assert_array_equal(w2.roi_labels.value.data, painted)
    np.testing.assert_array_equal(w2.brush.value.data, refine)
    np.testing.assert_allclose(w2.seeds.value.data, seeds.data)
    # the stored layers sit on the rescaled image, not rescaled twice
    assert tuple(roi2.scale) == pytest.approx(tuple(img2.scale)[-2:])
    gauge = [lay for lay in other.layers if PROBE_KEY in lay.metadata]
    assert len(gauge) == 1 and gauge[0].metadata[PROBE_KEY] == {"kind": "line"}
    np.testing.assert_allclose(gauge[0].data[0], probe.data[0])
    mask2, _ = w2.inputs.roi(SHAPE, 1)
    mask1, _ = w.inputs.roi(SHAPE, 1)
    np.testing.assert_array_equal(mask2, mask1)

    # a project whose image went missing changes nothing and says why
    tif.rename(tmp_path / "moved.tif")
    third = make_napari_viewer_proxy()
    w3 = _dock(third)
    assert w3.open_project(path) is False
    assert "stack.tif" in _errors()[-1] and "not there" in _errors()[-1]
    assert len(third.layers) == 0 and w3.subset.value == 31


def test_probe_layers_are_not_inputs_and_are_saved_with_the_project(make_napari_viewer_proxy,
                                                                    tmp_path, speckle_stack):
    tif = tmp_path / "stack.tif"
    tifffile.imwrite(tif, speckle_stack(3, SHAPE), photometric="minisblack")
    viewer = make_napari_viewer_proxy()
    viewer.open(str(tif), plugin="napari-aldic")
    w = _dock(viewer)
    probes = viewer.add_shapes([np.array([[20.0, 30.0], [70.0, 30.0]])], shape_type="line",
                               name="probes")  # the probe dock's layer
    points = viewer.add_points([[40.0, 40.0]], name="probe points")
    assert list(w.roi_add.value) == [] and w.seeds.value is None
    assert "Ready." in w.status.value  # a gauge line does not cut the ROI
    doc = json.loads(w.save_project(tmp_path / "p.json").read_text(encoding="utf-8"))
    stored = {r["name"]: r for r in doc["layers"] if r["role"] == "probe"}
    assert set(stored) == {"probes", "probe points"}
    np.testing.assert_allclose(stored["probes"]["data"][0], probes.data[0])
    np.testing.assert_allclose(stored["probe points"]["data"], points.data)


def test_project_of_an_image_without_a_file_is_refused_with_advice(make_napari_viewer_proxy,
                                                                   tmp_path, speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, SHAPE), name="from the console")
    w = _dock(viewer)
    assert w.save_project(tmp_path / "p.json") is None
    assert "not opened from a file" in _errors()[-1]
    assert not (tmp_path / "p.json").exists()


def test_last_used_parameters_come_back_and_defaults_restore(make_napari_viewer_proxy, qtbot,
                                                             speckle_stack, monkeypatch,
                                                             tmp_path):
    monkeypatch.setenv("NAPARI_ALDIC_CONFIG_DIR", str(tmp_path / "config"))
    used = {"method": "local", "subset": 21, "step": 12, "strain_window": 3,
            "strain_measure": "euler_almansi", "reference": "incremental",
            "unit": "µm", "pixel_size": 0.25, "show_field": "v", "rigid": True}
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, SHAPE), name="speckle")
    w = _dock(viewer)
    _set(w, used)
    w.run()
    qtbot.waitUntil(lambda: not w.running, timeout=60_000)
    stored = json.loads((tmp_path / "config" / "last_used.json").read_text(encoding="utf-8"))
    assert stored["settings"]["params"]["subset"] == 21

    # napari started again: a new viewer and widget
    again = make_napari_viewer_proxy()
    again.add_image(speckle_stack(3, SHAPE), name="speckle")
    w2 = _dock(again)
    # every setting comes back but the calibration: it belongs to one image (issue 24)
    assert _values(w2, used) == {**used, "unit": "px", "pixel_size": 1.0}
    assert "units" not in stored["settings"]
    assert "last session" in w2.log.value
    w2.restore_defaults()
    assert _values(w2, used) == {"method": "aldic", "subset": 31, "step": 8,
                                 "strain_window": 5, "strain_measure": "green_lagrange",
                                 "reference": "accumulative", "unit": "px", "pixel_size": 1.0,
                                 "show_field": "|u|", "rigid": False}
    assert w2.stop.value == 2  # the whole stack

    # a broken file is ignored: the defaults stay
    (tmp_path / "config" / "last_used.json").write_text("{not json", encoding="utf-8")
    third = make_napari_viewer_proxy()
    w3 = _dock(third)
    assert w3.subset.value == 31 and not _errors()


@pytest.mark.slow  # ~8 s: a PDF report and a video
def test_export_panel_writes_every_engine_format_with_units(make_napari_viewer_proxy, qtbot,
                                                            tmp_path, small_analysis):
    from napari_aldic.engine.io import load_mat, read_csv, read_vtu

    viewer = make_napari_viewer_proxy()
    viewer.add_image(np.zeros((3, 192, 192), np.uint8), name="speckle")
    w = _dock(viewer)
    w.show_analysis(small_analysis)
    w.unit.value = "µm"
    w.pixel_size.value = 0.5
    out = {}
    for fmt, name in (("npz", "r.npz"), ("csv", "r.csv"), ("mat", "r.mat"),
                      ("vtu", "r.vtu"), ("davis", "r.txt"), ("png", "r.png"),
                      ("gif", "r.gif"), ("mp4", "r.mp4"), ("pdf", "r.pdf")):
        out[fmt] = w.exports.export(tmp_path / name, fmt)
        assert out[fmt] and all(p.exists() and p.stat().st_size > 100 for p in out[fmt]), fmt
    res = small_analysis.results[2]
    table = read_csv(out["csv"][0])
    assert table["units"]["u"] == "µm"
    last = table["columns"]["frame"] == 2
    ok = np.asarray(res.valid, bool)
    np.testing.assert_allclose(table["columns"]["u"][last][ok], 0.5 * res.u[ok], rtol=1e-6)
    mat = load_mat(out["mat"][0])
    assert mat is not None
    vtu = read_vtu([p for p in out["vtu"] if p.suffix == ".vtu"][-1])
    np.testing.assert_allclose(vtu["points"][:, 0], 0.5 * res.x)
    davis = [p for p in out["davis"] if p.name.endswith("02.txt")][0]
    assert davis.read_text().startswith("#DaVis")
    assert len(out["png"]) == 3  # one picture per frame (the reference frame too)
    # the button's export runs in a worker thread and reports in the log
    w.exports.format.value = "csv"
    with qtbot.waitSignal(w.exports.exported, timeout=30_000):
        w.exports.export_in_background(tmp_path / "bg.csv")
    assert (tmp_path / "bg.csv").exists() and "exported 1 file" in w.log.value
    assert not _errors()


def test_engine_is_prepared_in_the_background_and_said_so(make_napari_viewer_proxy, qtbot,
                                                          monkeypatch, speckle_stack):
    import threading

    release = threading.Event()
    real_warm_up = warmup.warm_up
    monkeypatch.setattr(warmup, "_warm", threading.Event())  # a fresh process, as it were
    monkeypatch.setattr(warmup, "warm_up", lambda: release.wait(10) and warmup._warm.set())
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, SHAPE), name="speckle")
    w = _dock(viewer)
    assert "preparing the correlation engine (first run only)" in w.status.value.lower()
    assert w.run_button.enabled  # a run may start: it waits for the engine
    release.set()
    qtbot.waitUntil(lambda: "preparing" not in w.status.value.lower(), timeout=5000)
    assert "Ready." in w.status.value
    warmup._warm.clear()
    real_warm_up()  # the real one: every kernel of a run, once per process
    assert warmup.is_warm()
