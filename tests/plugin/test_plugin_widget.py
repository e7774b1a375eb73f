"""The dock widget end to end in a real (Xvfb) napari viewer."""

from __future__ import annotations

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic._qt import DICWidget

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui

TIMEOUT_MS = 120_000


def _dock(viewer, qtbot):
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    return widget


def _run(widget, qtbot):
    widget.run_button.clicked()
    assert widget.running
    qtbot.waitUntil(lambda: not widget.running, timeout=TIMEOUT_MS)


@pytest.fixture(autouse=True)
def _fresh_notifications():
    """Start every test with an empty notification log (other test files
    raise errors on purpose, and napari's manager is process-wide)."""
    from napari.utils.notifications import notification_manager

    notification_manager.records.clear()
    yield


def _errors():
    from napari.utils.notifications import NotificationSeverity, notification_manager

    return [n.message for n in notification_manager.records
            if n.severity == NotificationSeverity.ERROR]


def _lattice_xy(layer, t_index: int | None = None):
    """World (= image pixel, scale 1) x, y of every lattice pixel of an image layer."""
    rows, cols = layer.data.shape[-2:]
    sy, sx = layer.scale[-2:]
    ty, tx = layer.translate[-2:]
    yy, xx = np.mgrid[0:rows, 0:cols]
    return tx + xx * sx, ty + yy * sy


@pytest.mark.slow  # ~9 s
def test_widget_end_to_end_matches_truth(make_napari_viewer_proxy, qtbot, tmp_path, add_inputs,
                                         plugin_field, roi_rect, hole_circle, save_screenshot,
                                         speckle_stack, result_layer, keep_for_docs):
    viewer = make_napari_viewer_proxy(show=True)
    viewer.window.resize(1500, 1000)
    stack = speckle_stack()
    image, roi, hole, seeds = add_inputs(viewer, stack)
    widget = _dock(viewer, qtbot)

    # inputs chosen from the layer names: ROI rectangle added, ellipse subtracted, seeds
    assert widget.image.value == image
    assert list(widget.roi_add.value) == [roi]
    assert list(widget.roi_subtract.value) == [hole]
    assert widget.seeds.value == seeds and widget.init.value == "seeds"
    widget.subset.value = 21
    widget.step.value = 6
    widget.method.value = "aldic"
    assert widget.run_button.enabled, widget.status.value

    _run(widget, qtbot)
    assert not _errors()
    for key in ("u", "v", "|u|", "exx", "eyy", "exy", "von Mises", "displacement",
                "unreliable nodes"):
        result_layer(viewer, key)

    u_layer, v_layer = result_layer(viewer, "u"), result_layer(viewer, "v")
    assert u_layer.name == "DIC u [px]"
    assert u_layer.data.shape[0] == 3  # the stack's time axis: one field per frame
    assert tuple(u_layer.scale) == (1.0, 6.0, 6.0)
    lo, hi = u_layer.contrast_limits  # robust limits of the deformed frames' values
    moving = u_layer.data[1:][np.isfinite(u_layer.data[1:])]
    assert moving.min() <= lo < hi <= moving.max()
    x, y = _lattice_xy(u_layer)
    x0, y0, x1, y1 = roi_rect
    cx, cy, r = hole_circle
    for k in (1, 2):
        ut, vt = plugin_field(k).displacement(x, y)
        u, v = u_layer.data[k], v_layer.data[k]
        ok = np.isfinite(u)
        inside = (x >= x0 + 11) & (x <= x1 - 11) & (y >= y0 + 11) & (y <= y1 - 11) \
            & (np.hypot(x - cx, y - cy) > r + 11)
        assert ok[inside].mean() > 0.95  # nodes whose subset fits in the ROI are solved
        assert not ok[np.hypot(x - cx, y - cy) < r - 2].any()  # none inside the hole
        assert not ok[(x < x0 - 1) | (y < y0 - 1) | (x > x1 + 1) | (y > y1 + 1)].any()
        assert np.abs(u - ut)[ok].max() < 0.03
        assert np.abs(v - vt)[ok].max() < 0.03
        # strain: the Green-Lagrange strain of the affine field, away from the edges
        G = np.asarray(plugin_field(k).G)
        exx_true = G[0, 0] + 0.5 * (G[0, 0] ** 2 + G[1, 0] ** 2)
        exx = result_layer(viewer, "exx").data[k]
        good = np.isfinite(exx)
        assert good.sum() > 100
        assert np.median(np.abs(exx[good] - exx_true)) < 1e-3
    assert np.nanmax(np.abs(u_layer.data[0])) == 0.0  # reference frame: zero field

    vectors = result_layer(viewer, "displacement")
    feats = vectors.features
    assert {"frame", "u", "v", "magnitude", "zncc", "exx", "von_mises"} <= set(feats.columns)
    last = feats[feats["frame"] == 2]
    ut, vt = plugin_field(2).displacement(last["x_px"].to_numpy(), last["y_px"].to_numpy())
    assert np.abs(last["u"] - ut).max() < 0.03
    bad = result_layer(viewer, "unreliable nodes")
    assert "reason_text" in bad.features.columns

    # the frame slider shows that frame's field
    viewer.dims.set_current_step(0, 2)
    viewer.reset_view()
    # the whole window, dock widget included (in the test's own folder; copied to
    # docs/images with NAPARI_ALDIC_GUIDE_IMAGES=1)
    shot = tmp_path / "widget_synthetic_run.png"
    assert viewer.layers.selection.active == result_layer(viewer, "|u|")
    save_screenshot(viewer, shot)
    assert 10_000 < shot.stat().st_size < 400_000
    from PIL import Image

    pix = np.asarray(Image.open(shot).convert("L"), float)
    assert pix.shape[1] > 800 and pix.std() > 10  # a real, non-blank window
    keep_for_docs(shot)

    # re-running replaces the result layers, it never piles them up
    n_layers = len(viewer.layers)
    widget.mesh.value = True
    _run(widget, qtbot)
    assert len(viewer.layers) == n_layers + 1  # + the mesh layer only
    assert sum(layer.name == "DIC u [px]" for layer in viewer.layers) == 1
    mesh = result_layer(viewer, "mesh").data  # element edges chained into lattice lines
    assert len(mesh) > 20 and sum(len(p) for p in mesh) > 500

    # physical units: 0.5 um pixels scale every layer and the displayed lengths
    u_before = result_layer(viewer, "u").data.copy()
    widget.unit.value = "µm"
    widget.pixel_size.value = 0.5
    widget.time_unit.value = "s"
    widget.frame_interval.value = 2.0
    u_layer = result_layer(viewer, "u")
    assert u_layer.name == "DIC u [µm]"
    assert tuple(u_layer.scale) == (2.0, 3.0, 3.0)
    assert tuple(image.scale) == (2.0, 0.5, 0.5)
    assert tuple(roi.scale)[-2:] == (0.5, 0.5)
    assert str(u_layer.units[-1]) == "micrometer" and str(u_layer.units[0]) == "second"
    np.testing.assert_allclose(u_layer.data, 0.5 * u_before, equal_nan=True, rtol=1e-6)
    exx2 = result_layer(viewer, "exx").data[2]
    np.testing.assert_allclose(exx2[np.isfinite(exx2)].mean(), 0.01, atol=2e-3)  # no unit
    assert result_layer(viewer, "displacement").features["u"].abs().max() < 1.0
    # the deformed configuration moves the field with the material
    widget.deformed.value = True
    moved = result_layer(viewer, "u")
    assert moved.metadata["napari_aldic"]["deformed"]
    assert np.isfinite(moved.data[2]).sum() > 100
    assert not _errors()


def test_cancel_stops_and_keeps_finished_frames(make_napari_viewer_proxy, qtbot, speckle_stack,
                                                result_layer):
    viewer = make_napari_viewer_proxy()
    stack = speckle_stack(12, (224, 224))
    viewer.add_image(stack, name="speckle")
    widget = _dock(viewer, qtbot)
    widget.method.value = "local"
    widget.subset.value = 21
    widget.step.value = 2
    widget.run_button.clicked()
    qtbot.waitUntil(lambda: "frame 1 done" in widget.log.value, timeout=TIMEOUT_MS)
    widget.cancel_button.clicked()
    assert not widget.cancel_button.enabled
    qtbot.waitUntil(lambda: not widget.running, timeout=TIMEOUT_MS)
    analysis = widget.analysis
    assert analysis is not None and analysis.cancelled
    done = [r is not None for r in analysis.results]
    assert done[0] and done[1] and not all(done)  # finished frames kept, the rest skipped
    u = result_layer(viewer, "u").data
    assert np.isfinite(u[1]).any()
    assert not np.isfinite(u[11]).any()
    assert "cancelled" in widget.log.value
    assert widget.run_button.enabled and not _errors()


def test_bad_input_is_explained_and_viewer_stays_usable(make_napari_viewer_proxy, qtbot,
                                                        speckle_stack):
    from napari.utils.notifications import notification_manager

    viewer = make_napari_viewer_proxy()
    widget = _dock(viewer, qtbot)
    assert not widget.run_button.enabled
    assert "Choose an image stack" in widget.status.value
    viewer.add_image(np.zeros((64, 64)), name="single image")
    assert "at least two frames" in widget.status.value

    stack = speckle_stack()
    viewer.layers.remove("single image")
    image = viewer.add_image(stack, name="speckle")
    widget.image.value = image
    small = viewer.add_shapes([np.array([[50, 50], [50, 70], [70, 70], [70, 50]], float)],
                              shape_type="rectangle", name="roi small")
    assert widget.roi_add.value == [small]
    widget.subset.value = 31
    assert "larger than the ROI bounding box" in widget.status.value
    assert not widget.run_button.enabled
    n_before = len(notification_manager.records)
    widget.run()  # refused with a warning notification, nothing starts
    assert not widget.running
    assert len(notification_manager.records) > n_before

    widget.init.value = "seeds"
    assert "needs a Points layer" in widget.status.value

    # an error inside the engine: two ROI regions, one seed -> notification, no crash
    viewer.layers.remove(small)
    two = viewer.add_shapes([np.array([[20, 20], [20, 80], [170, 80], [170, 20]], float),
                             np.array([[20, 110], [20, 170], [170, 170], [170, 110]], float)],
                            shape_type="rectangle", name="ROI two parts")
    widget.roi_add.value = [two]
    seeds = viewer.add_points([[90.0, 50.0]], name="seeds")
    widget.seeds.value = seeds
    widget.subset.value = 21
    assert widget.run_button.enabled, widget.status.value
    _run(widget, qtbot)
    errors = _errors()
    assert errors and "has no seed" in errors[-1]
    assert "ERROR" in widget.log.value
    # still usable: fix the input and run again
    seeds.add([[90.0, 140.0]])
    _run(widget, qtbot)
    assert "DIC u [px]" in [layer.name for layer in viewer.layers]
    assert len(_errors()) == len(errors)


def test_plugin_contributions_load_in_napari(make_napari_viewer_proxy, qtbot, tmp_path,
                                             speckle_stack):
    import tifffile

    stack = speckle_stack()
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, stack, photometric="minisblack")
    viewer = make_napari_viewer_proxy()
    layers = viewer.open(str(path), plugin="napari-aldic")
    assert len(layers) == 1 and layers[0].data.shape == stack.shape
    # the dock widget from the manifest, as the Plugins menu opens it
    dock, widget = viewer.window.add_plugin_dock_widget(
        "napari-aldic", "Digital image correlation (AL-DIC)")
    assert isinstance(widget, DICWidget)
    assert widget.image.value is not None and widget.image.value.name == "stack"
    assert widget.stop.value == 2
    # closing the dock unhooks the widget: later layer changes do not reach it
    viewer.window.remove_dock_widget(dock)
    qtbot.wait(50)
    viewer.add_points([[10.0, 10.0]], name="seeds after close")
    viewer.layers["stack"].name = "renamed"
