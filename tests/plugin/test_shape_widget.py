"""The widget's subset-shape control: parameters, settings files and the log."""

from __future__ import annotations

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import pytest
import pytestqt  # noqa: F401

from napari_aldic._qt import DICWidget
from napari_aldic.engine import DICParams, Settings, read_settings, write_settings

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui


def test_shape_control_maps_saves_and_loads(make_napari_viewer_proxy, qtbot, tmp_path,
                                            speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(3, (96, 96)), name="speckle")
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    assert widget.shape_function.value == "affine"
    assert tuple(widget.shape_function.choices) == ("affine", "quadratic")
    widget.shape_function.value = "quadratic"
    path = widget.save_settings(tmp_path / "shape")
    assert read_settings(path).params.shape_function == "quadratic"

    widget.shape_function.value = "affine"
    assert widget.load_settings(path) is True
    assert widget.shape_function.value == "quadratic"
    # a file written by the engine sets the control too
    other = write_settings(tmp_path / "affine.json", Settings(DICParams(shape_function="affine")))
    assert widget.load_settings(other) is True
    assert widget.shape_function.value == "affine"
