"""Saving and loading the dock widget's analysis settings (JSON parameter files)."""

from __future__ import annotations

import json

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic._qt import DICWidget
from napari_aldic.engine import DICParams, Settings, Units, read_settings, write_settings

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui


#: every control a parameter file sets
CONTROLS = ("method", "subset", "step", "search", "refine", "smooth", "smooth_px", "init",
            "reference", "start",
            "stop", "stride", "strain_window", "strain_method", "strain_measure", "unit",
            "pixel_size", "time_unit", "frame_interval")
#: non-default values (the length unit before the pixel size: 'px' needs a size of 1)
CUSTOM = {"method": "local", "subset": 41, "step": 6, "search": 30, "refine": "medium",
          "smooth": "fixed", "smooth_px": 7.5, "init": "fft", "reference": "incremental",
          "start": 1, "stop": 3, "stride": 2,
          "strain_window": 7, "strain_method": "fem", "strain_measure": "infinitesimal",
          "unit": "µm", "pixel_size": 0.25, "time_unit": "ms", "frame_interval": 2.5}
OTHER = {"method": "aldic", "subset": 21, "step": 10, "search": 12, "refine": "strong",
         "smooth": "off", "smooth_px": 10.0, "init": "fft", "reference": "accumulative",
         "start": 0, "stop": 4, "stride": 1,
         "strain_window": 3, "strain_method": "plane_fit", "strain_measure": "euler_almansi",
         "unit": "mm", "pixel_size": 0.01, "time_unit": "s", "frame_interval": 0.5}


def _dock(viewer):
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    return widget


def _records():
    from napari.utils.notifications import notification_manager

    return notification_manager.records


def _errors_since(n0: int) -> list[str]:
    from napari.utils.notifications import NotificationSeverity

    return [n.message for n in _records()[n0:] if n.severity == NotificationSeverity.ERROR]


def _values(widget) -> dict:
    return {name: getattr(widget, name).value for name in CONTROLS}


def _set(widget, values: dict) -> None:
    for name, value in values.items():
        getattr(widget, name).value = value
    assert {k: v for k, v in _values(widget).items() if k in values} == values


def _stack_widget(viewer, speckle_stack, n_frames: int = 5):
    image = viewer.add_image(speckle_stack(n_frames, (96, 96)), name="speckle")
    widget = _dock(viewer)
    assert widget.image.value == image
    return widget, image


def test_save_change_load_restores_every_control(make_napari_viewer_proxy, qtbot, tmp_path,
                                                 speckle_stack):
    viewer = make_napari_viewer_proxy()
    widget, image = _stack_widget(viewer, speckle_stack)
    n0 = len(_records())
    _set(widget, CUSTOM)
    assert tuple(image.scale) == pytest.approx((2.5, 0.25, 0.25))

    path = widget.save_settings(tmp_path / "analysis")  # .json is appended
    assert path == tmp_path / "analysis.json" and path.exists()
    doc = json.loads(path.read_text(encoding="utf-8"))  # readable, plain JSON
    assert doc["format"] == "napari-aldic-settings"
    assert doc["params"]["subset"] == 41 and doc["params"]["method"] == "local"
    assert doc["params"]["smooth"] == 7.5
    assert doc["units"] == {"pixel_size": 0.25, "unit": "µm", "frame_interval": 2.5,
                            "time_unit": "ms"}
    assert "parameters saved" in widget.log.value

    _set(widget, OTHER)
    assert tuple(image.scale) == pytest.approx((0.5, 0.01, 0.01))
    assert widget.load_settings(path) is True
    assert _values(widget) == CUSTOM
    # the loaded units are applied to the image like typed ones
    assert tuple(image.scale) == pytest.approx((2.5, 0.25, 0.25))
    assert str(image.units[-1]) == "micrometer" and str(image.units[0]) == "millisecond"
    assert "parameters loaded from" in widget.log.value
    assert not _errors_since(n0)


def test_saved_file_reads_with_the_engine(make_napari_viewer_proxy, qtbot, tmp_path, speckle_stack):
    viewer = make_napari_viewer_proxy()
    widget, _ = _stack_widget(viewer, speckle_stack)
    _set(widget, CUSTOM)
    path = widget.save_settings(tmp_path / "analysis.json")

    s = read_settings(path)
    assert s.params == DICParams(method="local", subset=41, step=6, search=30,
                                 refine="medium", init="fft", smooth=7.5)
    assert s.units == Units(0.25, "µm", 2.5, "ms")
    assert s.strain == {"window": 7, "method": "fem", "measure": "infinitesimal"}
    assert s.tracking == {"reference": "incremental", "start": 1, "stop": 3, "stride": 2}
    assert widget.current_settings() == {"params": s.params, "units": s.units,
                                         "strain": s.strain, "tracking": s.tracking}

    # frame numbers only (time unit 'frame'): no frame interval in the file
    widget.time_unit.value = "frame"
    s = read_settings(widget.save_settings(tmp_path / "frames.json"))
    assert s.units == Units(0.25, "µm") and s.units.frame_interval is None
    widget.time_unit.value = "s"
    assert widget.load_settings(tmp_path / "frames.json")
    assert widget.time_unit.value == "frame" and widget.frame_interval.value == 1.0


BAD_FILES = {
    "broken.json": '{"format": "napari-aldic-settings", "params": {"subset": 41, "step":',
    "unknown_param.json": {"params": {"subset": 41, "wobble": 3}},
    "even_subset.json": {"params": {"subset": 40}},
    "unknown_section.json": {"format": "napari-aldic-settings", "params": {"subset": 41},
                             "colours": {"u": "red"}},
    "strain_window.json": {"params": {"subset": 41}, "strain": {"window": 4}},
    "strain_measure.json": {"params": {"subset": 41}, "strain": {"measure": "true"}},
    "unit.json": {"params": {"subset": 41}, "units": {"pixel_size": 2.0, "unit": "furlong"}},
    "tracking.json": {"params": {"subset": 41}, "tracking": {"reference": "sideways"}},
    "frames.json": {"params": {"subset": 41}, "tracking": {"start": 3, "stop": 1}},
    "widget_range.json": {"params": {"subset": 41, "step": 5000}},
    "not_an_object.json": [31, 8],
    "not_utf8.json": b"\xff\xfe{\x00}",
}


def test_invalid_file_shows_an_error_and_changes_nothing(make_napari_viewer_proxy, qtbot,
                                                         tmp_path, speckle_stack):
    viewer = make_napari_viewer_proxy()
    widget, image = _stack_widget(viewer, speckle_stack)
    _set(widget, CUSTOM)
    scale = tuple(image.scale)
    for name, content in [*BAD_FILES.items(), ("missing.json", None)]:
        path = tmp_path / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        elif isinstance(content, str):
            path.write_text(content)
        elif content is not None:
            path.write_text(json.dumps(content))
        n0 = len(_records())
        assert widget.load_settings(path) is False, name
        errors = _errors_since(n0)
        assert len(errors) == 1 and "could not load the parameters" in errors[0], name
        assert _values(widget) == CUSTOM, name  # nothing applied, not even the valid part
        assert tuple(image.scale) == scale
        assert f"ERROR loading parameters from {path}" in widget.log.value
    n0 = len(_records())
    widget.load_settings(tmp_path / "broken.json")
    assert "not valid JSON" in _errors_since(n0)[0]
    widget.load_settings(tmp_path / "unknown_param.json")
    assert "wobble" in _errors_since(n0)[1]

    # settings that cannot be saved are explained too, and no file is written
    widget.unit.value = "px"
    widget.pixel_size.value = 2.0
    n0 = len(_records())
    assert widget.save_settings(tmp_path / "px.json") is None
    assert "length unit 'px'" in _errors_since(n0)[0]
    assert not (tmp_path / "px.json").exists()
    widget.pixel_size.value = 1.0
    widget.init.value = "seeds"  # no seeds layer
    assert widget.save_settings(tmp_path / "seeds.json") is None
    assert "Seed points" in _errors_since(n0)[1]
    assert not (tmp_path / "seeds.json").exists()


def test_file_from_cli_or_engine_loads_and_keeps_advanced_fields(make_napari_viewer_proxy,
                                                                 qtbot, tmp_path, speckle_stack):
    viewer = make_napari_viewer_proxy()
    widget, image = _stack_widget(viewer, speckle_stack)
    path = write_settings(tmp_path / "engine.json", Settings(
        DICParams(method="aldic", subset=25, step=5, interpolation="quintic", mu=0.2,
                  search=16, search_max=40), Units(pixel_size=0.05, unit="um"),
        tracking={"reference": "incremental", "start": 1, "stop": None}))
    n0 = len(_records())
    assert widget.load_settings(path)
    assert not _errors_since(n0)
    assert (widget.method.value, widget.subset.value, widget.step.value) == ("aldic", 25, 5)
    assert widget.unit.value == "µm" and widget.pixel_size.value == pytest.approx(0.05)
    assert widget.time_unit.value == "frame"  # no frame interval in the file
    assert (widget.reference.value, widget.start.value, widget.stop.value) == \
        ("incremental", 1, 4)  # null stop: the last frame of the stack
    assert "interpolation='quintic'" in widget.log.value  # kept, though not shown
    params = widget.current_settings()["params"]
    assert params.interpolation == "quintic" and params.mu == 0.2 and params.search_max == 40
    again = widget.save_settings(tmp_path / "again.json")
    assert read_settings(again).params == DICParams(
        method="aldic", subset=25, step=5, interpolation="quintic", mu=0.2, search=16,
        search_max=40)

    # the older form, a plain object of DICParams fields; other sections stay
    (tmp_path / "plain.json").write_text(json.dumps({"subset": 33, "step": 7}))
    assert widget.load_settings(tmp_path / "plain.json")
    assert (widget.subset.value, widget.step.value, widget.method.value) == (33, 7, "local")
    assert widget.unit.value == "µm" and widget.reference.value == "incremental"
    assert widget.current_settings()["params"].interpolation == "auto"  # default again

    # a frame range beyond a shorter stack is clamped, with a note
    (tmp_path / "long.json").write_text(json.dumps(
        {"params": {}, "tracking": {"start": 2, "stop": 40}}))
    assert widget.load_settings(tmp_path / "long.json")
    assert (widget.start.value, widget.stop.value) == (2, 4)
    assert "last frame 40 of the file is beyond the stack" in widget.log.value
    assert not _errors_since(n0)

    # a pixel size finer than the spin box showed is kept exactly
    write_settings(tmp_path / "fine.json",
                   Settings(DICParams(), Units(0.000325, "mm", 0.0125, "s")))
    assert widget.load_settings(tmp_path / "fine.json")
    assert widget.pixel_size.value == pytest.approx(0.000325, rel=1e-9)
    assert widget.frame_interval.value == pytest.approx(0.0125, rel=1e-9)
    assert tuple(image.scale) == pytest.approx((0.0125, 0.000325, 0.000325))


def test_seed_points_round_trip(make_napari_viewer_proxy, qtbot, tmp_path, add_inputs,
                                speckle_stack):
    viewer = make_napari_viewer_proxy()
    image, roi, hole, seeds = add_inputs(viewer, speckle_stack())
    widget = _dock(viewer)
    assert widget.init.value == "seeds" and widget.seeds.value == seeds
    path = widget.save_settings(tmp_path / "seeds.json")
    doc = json.loads(path.read_text())
    assert doc["params"]["init"] == "seeds"
    assert doc["params"]["seeds"] == [[44.0, 40.0]]  # (x, y) image pixels

    viewer.layers.remove(seeds)
    widget.init.value = "fft"
    assert widget.load_settings(path)
    assert widget.init.value == "seeds"
    loaded = widget.seeds.value
    assert loaded is not None and loaded.name == "seeds (loaded)"
    np.testing.assert_allclose(loaded.data, [[40.0, 44.0]])
    assert widget.current_settings()["params"].seeds == ((44.0, 40.0),)
    assert widget.run_button.enabled, widget.status.value
    # a chosen seeds layer with points is kept: no second layer
    n_layers = len(viewer.layers)
    assert widget.load_settings(path)
    assert len(viewer.layers) == n_layers and widget.seeds.value == loaded


def test_buttons_use_file_dialogs(make_napari_viewer_proxy, qtbot, tmp_path, monkeypatch,
                                  speckle_stack):
    from qtpy.QtWidgets import QFileDialog

    viewer = make_napari_viewer_proxy()
    widget, _ = _stack_widget(viewer, speckle_stack)
    assert widget.save_params_button.text.startswith("Save parameters")
    assert widget.load_params_button.text.startswith("Load parameters")
    target = tmp_path / "dialog.json"
    asked = []

    def save_dialog(parent, caption, start, filters):
        asked.append(start)
        return str(target), filters

    monkeypatch.setattr(QFileDialog, "getSaveFileName", staticmethod(save_dialog))
    monkeypatch.setattr(QFileDialog, "getOpenFileName",
                        staticmethod(lambda *a: (str(target), "")))
    _set(widget, CUSTOM)
    widget.save_params_button.clicked()
    assert target.exists() and asked[0].endswith("speckle_parameters.json")
    _set(widget, OTHER)
    widget.load_params_button.clicked()
    assert _values(widget) == CUSTOM

    # a cancelled dialog does nothing
    monkeypatch.setattr(QFileDialog, "getOpenFileName", staticmethod(lambda *a: ("", "")))
    _set(widget, OTHER)
    widget.load_params_button.clicked()
    assert _values(widget) == OTHER


def test_saved_file_runs_with_the_cli(make_napari_viewer_proxy, qtbot, tmp_path, speckle_stack):
    import tifffile

    from napari_aldic.cli import main
    from napari_aldic.engine import load_result

    stack = speckle_stack()[:2]
    tif = tmp_path / "pair.tif"
    tifffile.imwrite(tif, stack, photometric="minisblack")
    viewer = make_napari_viewer_proxy()
    viewer.add_image(stack, name="pair")
    widget = _dock(viewer)
    _set(widget, {"method": "local", "subset": 21, "step": 8, "search": 10,
                  "refine": "none", "init": "fft", "unit": "µm", "pixel_size": 0.5,
                  "time_unit": "s", "frame_interval": 2.0})
    saved = widget.save_settings(tmp_path / "widget.json")

    out = tmp_path / "result.npz"
    assert main(["run", str(tif), "--params", str(saved), "-o", str(out)]) == 0
    res = load_result(out)
    assert res.params == read_settings(saved).params == widget.current_settings()["params"]
    assert (res.params.method, res.params.subset, res.params.step, res.params.search) == \
        ("local", 21, 8, 10)
    assert res.meta["units"] == Units(0.5, "µm", 2.0, "s").to_dict()
    assert res.n_valid > 0.8 * len(res)


def test_smoothing_controls_map_to_the_parameter(make_napari_viewer_proxy, qtbot, speckle_stack):
    viewer = make_napari_viewer_proxy()
    widget, _ = _stack_widget(viewer, speckle_stack)
    widget.method.value = "aldic"
    assert widget._current_params().smooth == "auto" and not widget.smooth_px.enabled
    widget.smooth.value = "fixed"
    widget.smooth_px.value = 12.5
    assert widget.smooth_px.enabled and widget._current_params().smooth == 12.5
    widget.smooth.value = "off"
    assert widget._current_params().smooth == 0.0 and not widget.smooth_px.enabled
    widget.method.value = "local"  # no AL-DIC, nothing to smooth
    assert not widget.smooth.enabled and not widget.smooth_px.enabled


def test_parameter_file_keeps_the_probes_in_image_pixels(make_napari_viewer_proxy, qtbot,
                                                         tmp_path, speckle_stack):
    import numpy as np

    from napari_aldic._qt.project import PROBE_KEY
    from napari_aldic.engine.io import read_settings
    from napari_aldic.engine.probes import ProbeSet

    viewer = make_napari_viewer_proxy()
    widget, _ = _stack_widget(viewer, speckle_stack)
    # napari (row, col): a gauge from (x=10, y=20) to (x=80, y=20), a point at (x=50, y=60)
    viewer.add_shapes([np.array([[20.0, 10.0], [20.0, 80.0]])], shape_type="line",
                      name="gauges", metadata={PROBE_KEY: True})
    viewer.add_points([[60.0, 50.0]], name="probe points", metadata={PROBE_KEY: True})
    path = widget.save_settings(tmp_path / "with_probes.json")
    s = read_settings(path)
    probes = ProbeSet.from_dict(s.probes)
    assert len(probes.lines) == 1 and len(probes.points) == 1
    line = probes.lines[0]
    assert (line.x0, line.y0, line.x1, line.y1) == (10.0, 20.0, 80.0, 20.0)
    assert (probes.points[0].x, probes.points[0].y) == (50.0, 60.0)


def test_the_automatic_vector_scale_says_so(make_napari_viewer, qtbot):
    """0 is the automatic arrow scale: the spin box says "automatic" (it showed
    "0.00"), in the chosen language too, and a set scale shows its number."""
    from napari_aldic._qt.language import switch_language

    viewer = make_napari_viewer()
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    box = widget.display.vector_length
    assert box.value == 0.0 and box.native.text() == "automatic"
    box.value = 2.5
    assert box.native.text() == "2.50"
    box.value = 0.0
    try:
        switch_language("de")
        assert box.native.text() == "automatisch"
    finally:
        switch_language("en")
    assert box.native.text() == "automatic"
