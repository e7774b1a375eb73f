"""The twelve traps of issue 14, one test each (every one failed before its fix)."""

from __future__ import annotations

import dataclasses
import time

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic._analysis import Analysis, Job, zero_field
from napari_aldic._layers import Display, Geometry, analysis_layers
from napari_aldic._qt import DICWidget
from napari_aldic._roi import shape_mask

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui

SHAPE = (192, 192)


def _dock(viewer):
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    return widget


def _rect(x0, y0, x1, y1):
    return np.array([[y0, x0], [y0, x1], [y1, x1], [y1, x0]], float)


def _tuples(layers) -> dict:
    return {kw["metadata"]["napari_aldic"]["field"]: (data, kw) for data, kw, _ in layers}


# ------------------------------------------------------------------ 1
def test_bug01_renamed_layers_stay_chosen_and_names_are_read_again(make_napari_viewer_proxy,
                                                                   speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(), name="speckle")
    w = _dock(viewer)
    roi = viewer.add_shapes([_rect(30, 30, 160, 160)], shape_type="rectangle", name="Shapes")
    labels = viewer.add_labels(np.ones(SHAPE, np.uint8), name="roi labels")
    seeds = viewer.add_points([[60.0, 60.0]], name="seeds")
    brush = viewer.add_labels(np.zeros(SHAPE, np.uint8), name="refine")
    assert list(w.roi_add.value) == [roi] and w.roi_labels.value == labels
    assert w.seeds.value == seeds and w.brush.value == brush
    for layer, name in ((roi, "specimen outline"), (labels, "painted area"),
                        (seeds, "start points"), (brush, "painted detail")):
        layer.name = name
    assert list(w.roi_add.value) == [roi]
    assert w.roi_labels.value == labels and w.seeds.value == seeds and w.brush.value == brush
    mask, _ = w.inputs.roi(SHAPE)
    rect = shape_mask("rectangle", _rect(30, 30, 160, 160), SHAPE)
    np.testing.assert_array_equal(mask, rect)  # the ROI, not the whole image
    assert "Ready." in w.status.value

    # a layer renamed like a hole keeps its role (issue 24: roles are the user's choice,
    # never read from a name); one renamed 'refine' is picked up
    other = viewer.add_shapes([_rect(80, 80, 100, 100)], shape_type="rectangle", name="Shapes")
    assert other in w.roi_add.value
    other.name = "hole 1"
    assert other in w.roi_add.value and other not in w.roi_subtract.value
    w.brush.value = None
    painted = viewer.add_labels(np.zeros(SHAPE, np.uint8), name="Labels")
    assert w.brush.value is None
    painted.name = "refine here"
    assert w.brush.value == painted


# ------------------------------------------------------------------ 2
def test_bug02_roi_outside_the_image_is_empty_not_the_whole_image(make_napari_viewer_proxy,
                                                                 speckle_stack):
    from napari_aldic._roi import build_roi

    viewer = make_napari_viewer_proxy()
    image = viewer.add_image(speckle_stack(), name="speckle")
    w = _dock(viewer)
    outside = viewer.add_shapes([_rect(300, 300, 400, 380)], shape_type="rectangle", name="ROI")
    mask, _ = build_roi(image, SHAPE, add_shapes=[outside])
    assert mask is not None and not mask.any()
    assert "The ROI is empty" in w.status.value
    assert not w.run_button.enabled


# ------------------------------------------------------------------ 3
def test_bug03_results_saved_with_the_builtin_npz_are_explained(make_napari_viewer_proxy,
                                                                tmp_path, small_analysis):
    from napari_aldic._reader import get_reader
    from napari_aldic._writer import write_results

    viewer = make_napari_viewer_proxy()
    viewer.add_image(np.zeros((3, *SHAPE), np.uint8), name="speckle")
    w = _dock(viewer)
    w.show_analysis(small_analysis)
    from napari_aldic._qt.results import find_result_layer

    u = find_result_layer(viewer.layers, "u")
    # File > Save Selected Layers... with 'results.npz' and the default file type
    written = napari.save_layers(str(tmp_path / "results.npz"), [u])
    assert written and not (tmp_path / "results").is_dir()  # napari's pixels, not results
    reader = get_reader(str(tmp_path / "results.npz"))
    assert reader is not None
    with pytest.raises(ValueError, match="Export"):
        reader(str(tmp_path / "results.npz"))
    # the Export panel's first choice writes the result folder, which reopens
    paths = w.exports.export(tmp_path / "run.npz", "npz")
    assert (tmp_path / "run").is_dir() and len(paths) == 3
    reopened = get_reader(str(tmp_path / "run"))(str(tmp_path / "run"))
    assert any(kw["metadata"]["napari_aldic"]["field"] == "u" for _, kw, _ in reopened)
    assert callable(write_results)


# ------------------------------------------------------------------ 4
def test_bug04_choosing_none_checks_the_inputs_again(make_napari_viewer_proxy, speckle_stack):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(), name="speckle")
    w = _dock(viewer)
    empty = viewer.add_labels(np.zeros(SHAPE, np.uint8), name="other labels")
    w.roi_labels.value = empty
    assert "The ROI is empty" in w.status.value and not w.run_button.enabled
    w.roi_labels.value = None
    assert "Ready." in w.status.value and w.run_button.enabled

    seeds = viewer.add_points([[60.0, 60.0]], name="seeds")
    assert w.seeds.value == seeds and w.init.value == "seeds"
    assert w.run_button.enabled
    w.seeds.value = None
    assert "needs a Points layer" in w.status.value and not w.run_button.enabled
    w.seeds.value = seeds
    w.reference.value = "incremental"
    w.brush.value = empty
    assert "accumulative" in w.status.value and not w.run_button.enabled
    w.brush.value = None
    assert "Ready." in w.status.value and w.run_button.enabled


# ------------------------------------------------------------------ 5
def test_bug05_display_toggles_keep_the_users_colours_and_show_acts_at_once(
        make_napari_viewer_proxy, small_analysis, result_layer):
    viewer = make_napari_viewer_proxy()
    viewer.add_image(np.zeros((3, *SHAPE), np.uint8), name="speckle")
    w = _dock(viewer)
    w.show_analysis(small_analysis)
    u = result_layer(viewer, "u")
    u.colormap = "viridis"
    u.contrast_limits = (-0.1, 0.2)
    for control in (w.mesh, w.deformed, w.vectors):
        control.value = not control.value
        u = result_layer(viewer, "u")
        assert u.colormap.name == "viridis"
        assert tuple(u.contrast_limits) == pytest.approx((-0.1, 0.2))
    # 'Show' makes the chosen field the visible (and active) layer right away
    w.show_field.value = "exx"
    assert result_layer(viewer, "exx").visible
    assert not result_layer(viewer, "|u|").visible
    assert viewer.layers.selection.active == result_layer(viewer, "exx")


# ------------------------------------------------------------------ 6
def test_bug06_colour_limits_follow_the_data_and_rigid_motion_can_be_removed(small_analysis):
    res = small_analysis.results[2]
    cy = float(np.median(res.y))
    jump = np.where(res.y > cy, 7.0, 0.0)
    moved = dataclasses.replace(res, u=-57.0 + jump, v=np.zeros_like(res.v))
    a = dataclasses.replace(small_analysis, results=[small_analysis.results[0], None, moved],
                            strains=[None, None, None])
    geo = Geometry((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    data, kw = _tuples(analysis_layers(a, geo, Display()))["u"]
    lo, hi = kw["contrast_limits"]
    assert -58.0 < lo < -56.0 and -51.0 < hi < -49.0  # from the data, not +-57
    assert 7.0 / (hi - lo) > 0.8  # the jump spans the colour scale

    # a rigid rotation and translation: nothing left once rigid motion is removed
    th = 0.01
    xc, yc = res.x - 96.0, res.y - 96.0
    rigid = dataclasses.replace(res, u=-57.0 + (np.cos(th) - 1) * xc - np.sin(th) * yc,
                                v=3.0 + np.sin(th) * xc + (np.cos(th) - 1) * yc)
    a = dataclasses.replace(a, results=[small_analysis.results[0], None, rigid])
    layers = _tuples(analysis_layers(a, geo, Display(rigid=True)))
    for key in ("u", "v", "|u|"):
        values = layers[key][0][2]
        assert np.isfinite(values).sum() > 100
        assert np.nanmax(np.abs(values)) < 1e-6, key
    assert np.abs(layers["displacement"][1]["features"]["u"]).max() < 1e-6


# ------------------------------------------------------------------ 7
def test_bug07_labels_of_another_sample_are_not_chosen_for_the_first_image(
        make_napari_viewer_proxy):
    viewer = make_napari_viewer_proxy()
    w = _dock(viewer)
    [first] = viewer.open_sample("napari-aldic", "translation_pair")
    oht = viewer.open_sample("napari-aldic", "open_hole_pair")
    assert w.image.value == first
    assert w.roi_labels.value is None
    assert "px but the image" not in w.status.value and "Ready." in w.status.value
    w.image.value = oht[0]  # the labels that fit the chosen image come with it
    assert w.roi_labels.value == oht[1]
    assert "Ready." in w.status.value


# ------------------------------------------------------------------ 8
def test_bug08_advice_for_separate_images_names_a_menu_that_exists(make_napari_viewer_proxy):
    viewer = make_napari_viewer_proxy()
    w = _dock(viewer)
    viewer.add_image(np.zeros((64, 64)), name="single image")
    assert "Layers > Stack" not in w.status.value
    assert "File > Open Files as Stack" in w.status.value
    texts = [a.text() for a in viewer.window.file_menu.actions()]
    assert "Open Files as Stack..." in texts


# ------------------------------------------------------------------ 9
def test_bug09_labels_made_while_shapes_are_active_are_matched_by_world_coordinates(
        make_napari_viewer, speckle_stack):
    viewer = make_napari_viewer()
    viewer.add_image(speckle_stack(), name="speckle")
    w = _dock(viewer)
    shapes = viewer.add_shapes([_rect(60, 50, 120, 100)], shape_type="rectangle", name="Shapes")
    viewer.layers.selection.active = shapes
    viewer._new_labels()  # the layer list's 'New labels layer' button
    labels = viewer.layers[-1]
    assert labels.data.shape[-2:] != SHAPE  # napari made it of the shapes' extent
    off = np.asarray(labels.translate)[-2:].astype(int)
    data = np.zeros(labels.data.shape, labels.data.dtype)
    data[..., 5:45, 5:55] = 1
    labels.data = data
    w.roi_labels.value = labels
    w.roi_add.value = []
    assert "Ready." in w.status.value, w.status.value
    mask, _ = w.inputs.roi(SHAPE)
    expect = np.zeros(SHAPE, bool)
    expect[off[0] + 5:off[0] + 45, off[1] + 5:off[1] + 55] = True
    np.testing.assert_array_equal(mask, expect)

    # the panel's own button makes labels of the image's size and chooses them
    made = w.inputs.new_labels("roi_labels")
    assert made.data.shape == SHAPE and w.roi_labels.value == made
    assert tuple(made.scale) == (1.0, 1.0)


# ------------------------------------------------------------------ 10
def test_bug10_refined_nodes_are_drawn_on_a_finer_grid(aldic_result):
    res = aldic_result
    a = Analysis(results=[zero_field(res), res], strains=[None, None], frames=[0, 1],
                 n_frames=2, params=res.params)
    data, kw = _tuples(analysis_layers(a, Geometry((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)),
                                       Display()))["u"]
    step = float(res.params.step)
    pitch = kw["scale"][-1]
    assert pitch < step and kw["scale"][-2] == pitch
    ty, tx = kw["translate"][-2:]
    off = (np.asarray(res.grid_ix) < 0) & np.asarray(res.valid)
    assert off.sum() > 10  # the quadtree added nodes between lattice points
    cols = np.rint((res.x[off] - tx) / pitch).astype(int)
    rows = np.rint((res.y[off] - ty) / pitch).astype(int)
    np.testing.assert_allclose(data[1][rows, cols], res.u[off], atol=1e-5)


# ------------------------------------------------------------------ 11
def test_bug11_names_carry_units_legend_explains_reasons_field_is_active(
        make_napari_viewer_proxy, small_analysis, result_layer):
    viewer = make_napari_viewer_proxy()
    image = viewer.add_image(np.zeros((3, *SHAPE), np.uint8), name="speckle")
    w = _dock(viewer)
    w.show_analysis(small_analysis)
    u = result_layer(viewer, "u")
    assert u.name == "DIC u [px]"
    assert result_layer(viewer, "exx").name == "DIC exx [-]"
    assert viewer.layers.selection.active == result_layer(viewer, "|u|")
    w.unit.value = "µm"
    w.pixel_size.value = 0.5
    u = result_layer(viewer, "u")
    assert u.name == "DIC u [µm]"
    status = u.get_status((2, 96, 96), world=True)
    assert "[µm]" in status["layer_name"]
    bad = result_layer(viewer, "unreliable nodes")
    reasons = set(bad.features["reason_text"])
    assert reasons  # nodes next to the ROI border fail the subset test
    for text in reasons:
        assert text in w.display.legend.value
    assert image.visible


# ------------------------------------------------------------------ 12
class _SlowJob(Job):
    """A job that takes ``seconds`` for its one frame, then gives ``analysis``."""

    def __init__(self, analysis, seconds):
        super().__init__(stack=np.zeros((3, 8, 8)), roi=None, params=analysis.params)
        self._analysis, self._seconds = analysis, seconds

    def run(self, progress=None, cancel=None):
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < self._seconds and not (cancel and cancel()):
            time.sleep(0.02)
        return self._analysis


def test_bug12_elapsed_time_moves_and_cancel_leaves_the_bar_at_the_frames_done(
        make_napari_viewer_proxy, qtbot, speckle_stack, small_analysis):
    from napari_aldic._qt.run import RunPanel

    panel = RunPanel()
    qtbot.addWidget(panel.native)
    panel.start(_SlowJob(small_analysis, 2.5))
    qtbot.waitUntil(lambda: "0:01 elapsed" in panel.eta.value, timeout=4000)
    assert panel.running  # no frame has finished, the clock moves anyway
    qtbot.waitUntil(lambda: not panel.running, timeout=10_000)

    viewer = make_napari_viewer_proxy()
    viewer.add_image(speckle_stack(8, (160, 160)), name="speckle")
    w = _dock(viewer)
    w.method.value, w.subset.value, w.step.value = "local", 21, 3
    # cancel as soon as the first frame is reported (the log line comes with it)
    w.log.native.textChanged.connect(
        lambda: "frame 1 done" in w.log.value and w.running and w.cancel_button.enabled
        and w.cancel_button.clicked())
    w.run_button.clicked()
    qtbot.waitUntil(lambda: not w.running, timeout=60_000)
    a = w.analysis
    n_done = a.n_done - 1
    assert a.cancelled and 1 <= n_done < 7
    assert w.progress.value == round(1000 * n_done / 7)
    # the fields lie on the reference frame unless 'deformed configuration' is ticked: said
    assert "reference" in w.display.note.value
    w.deformed.value = True
    assert "deformed" in w.display.note.value
