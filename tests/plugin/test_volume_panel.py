"""The dock's "Volume (DVC)" section (issue 28): two 3-D image layers (or two volumes
of a 4-D stack) and a 3-D Labels ROI in, the result layers out, in a worker thread;
bad choices give one line, Cancel drops the result."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair

SHAPE = (40, 44, 48)  # (nz, ny, nx)
SHIFT = (0.8, -0.5, 0.3)  # (u, v, w)


@pytest.fixture(scope="module")
def pair():
    return speckle_volume_pair(SHAPE, VolumeMotion.make(shift=SHIFT), seed=11)


def _layer(data, name):
    return SimpleNamespace(data=data, name=name)


def test_choice_reads_3d_and_4d_layers_and_names_bad_input(pair, tmp_path):
    import tifffile

    from napari_aldic._qt.volume import VolumeChoice
    from napari_aldic._reader import get_reader

    ref, dfm = pair
    # 3-D TIFFs opened by the plugin's reader (lazy stacks) are volumes for the panel
    opened = []
    for name, vol in (("ref", ref), ("dfm", dfm)):
        path = str(tmp_path / f"{name}.tif")
        tifffile.imwrite(path, vol, photometric="minisblack")
        data, kwargs, _ = get_reader(path)(path)[0]
        opened.append(_layer(data, kwargs["name"]))
    a, b, _, _ = VolumeChoice(*opened, subset=15, step=6).inputs()
    assert isinstance(a, np.ndarray) and np.array_equal(a, ref) and np.array_equal(b, dfm)
    stack = _layer(np.stack([ref, dfm, ref]), "t-stack")
    a, b, roi, params = VolumeChoice(stack, stack, 0, 1, subset=15, step=6).inputs()
    assert a is not b and np.array_equal(a, ref) and np.array_equal(b, dfm) and roi is None
    assert (params.subset, params.step, params.method) == (15, 6, "local")
    labels = np.zeros(SHAPE, np.uint8)
    labels[5:35, 6:38, 4:44] = 2
    _, _, roi, _ = VolumeChoice(_layer(ref, "r"), _layer(dfm, "d"), roi=_layer(labels, "L"),
                                subset=15, step=6).inputs()
    assert roi.dtype == bool and roi.sum() == 30 * 32 * 40
    bad = {
        "outside 0..2": VolumeChoice(stack, stack, 0, 3),
        "same volume": VolumeChoice(stack, stack, 1, 1),
        "differ in shape": VolumeChoice(_layer(ref, "r"), _layer(dfm[:, :, :40], "d")),
        "3-D volume or a 4-D": VolumeChoice(_layer(ref[0], "flat"), _layer(dfm, "d")),
        "ROI labels have shape": VolumeChoice(_layer(ref, "r"), _layer(dfm, "d"),
                                              roi=_layer(labels[:, :, :10], "L")),
        "empty": VolumeChoice(_layer(ref, "r"), _layer(dfm, "d"),
                              roi=_layer(np.zeros(SHAPE, int), "L")),
        "Choose a reference": VolumeChoice(None, _layer(dfm, "d")),
        "odd": VolumeChoice(_layer(ref, "r"), _layer(dfm, "d"), subset=16),
    }
    for words, choice in bad.items():
        with pytest.raises(ValueError, match=words):
            choice.inputs()


@pytest.mark.slow
def test_volume_section_runs_in_a_worker(make_napari_viewer, qtbot, pair, tmp_path,
                                         save_screenshot, keep_for_docs, monkeypatch):
    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.volume import VOLUME_META, VolumePanel

    ref, dfm = pair
    monkeypatch.setenv("NAPARI_ALDIC_WARMUP", "0")  # the 2-D warm-up is not this test's
    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1600, 1000)
    viewer.add_image(ref[0], name="a 2-D image")  # not a volume: never offered
    # voxels 2 units deep, 1.5 wide, the volume moved: the results must follow
    geometry = {"scale": (2.0, 1.5, 1.5), "translate": (10.0, -5.0, 3.0)}
    viewer.add_image(ref, name="reference", colormap="gray", opacity=0.5, **geometry)
    viewer.add_image(dfm, name="deformed", colormap="gray", visible=False, **geometry)
    labels = np.zeros(SHAPE, np.uint8)
    labels[:, 8:36, :] = 1
    viewer.add_labels(labels, name="material", opacity=0.2, **geometry)
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, area="right", name="napari-aldic")
    panel = w.volume
    assert isinstance(panel, VolumePanel) and "Volume (DVC)" in w.sections
    names = [n for n, _ in panel._volume_layers()]
    assert names == ["reference", "deformed"]
    assert panel.reference.value.name == "reference" and panel.deformed.value.name == "deformed"
    assert panel.subset.value == 31 and panel.step.value == 8 and panel.method.value == "local"
    panel.subset.value, panel.step.value = 15, 6
    panel.roi.value = viewer.layers["material"]

    # an engine error is one line in the panel, and the panel is free again
    panel.subset.value = 41  # subset over the ROI's 28 voxels: no node fits
    panel.run()
    qtbot.waitUntil(lambda: not panel.running, timeout=60000)
    assert "\n" not in panel.state.value and panel.state.value, panel.state.value
    print(panel.state.value)
    panel.subset.value = 15

    # Cancel frees the panel at once and nothing is added
    n_layers = len(viewer.layers)
    panel.run()
    assert panel.running and not panel.run_button.enabled
    worker = panel._worker
    panel.cancel()
    assert not panel.running and panel.run_button.enabled and "Cancelled" in panel.state.value
    assert panel._stop.is_set()  # the engine is asked to stop, not only ignored
    qtbot.waitUntil(lambda: not worker.is_running, timeout=60000)
    qtbot.wait(100)
    assert len(viewer.layers) == n_layers

    panel.run()
    assert panel.running  # the call returned while the worker correlates
    qtbot.waitUntil(lambda: not panel.running, timeout=120000)
    assert panel.state.value.startswith("Done:"), panel.state.value
    res = panel.result
    assert res.n_valid >= 0.85 * len(res)
    # nodes only inside the ROI (y 8..35), and the layers carry the shift
    assert res.y.min() >= 8 and res.y.max() <= 35
    added = [lay for lay in viewer.layers if lay.metadata.get(VOLUME_META)]
    assert [lay.name for lay in added] == [
        "DVC u", "DVC v", "DVC w", "DVC |u|", "DVC von Mises strain", "DVC exx", "DVC eyy",
        "DVC ezz", "DVC displacement", "DVC untrusted nodes"]
    assert np.nanmax(np.abs(viewer.layers["DVC exx"].data)) < 2e-3  # a pure shift
    for lay, s in zip(added[:3], SHIFT):
        assert abs(np.nanmedian(lay.data) - s) < 0.03
    # a node of every layer sits on its voxel of the reference layer, in world space
    source = viewer.layers["reference"]
    node = np.array([res.grid_zs[1], res.grid_ys[2], res.grid_xs[3]])
    world = source.data_to_world(node)
    np.testing.assert_allclose(viewer.layers["DVC |u|"].data_to_world([1, 2, 3]), world)
    vec, pts = viewer.layers["DVC displacement"], viewer.layers["DVC untrusted nodes"]
    k = int(np.flatnonzero(res.valid)[0])
    np.testing.assert_allclose(vec.data_to_world(vec.data[0, 0]),
                               source.data_to_world([res.z[k], res.y[k], res.x[k]]))
    np.testing.assert_allclose(pts.data_to_world(pts.data[0]), source.data_to_world(pts.data[0]))
    assert "DVC u" not in [n for n, _ in panel._volume_layers()]  # results are not offered as input

    viewer.layers["material"].visible = False
    viewer.layers.remove("a 2-D image")
    viewer.dims.ndisplay = 3
    viewer.reset_view()
    viewer.scene.camera.angles = (15.0, -35.0, 130.0)
    w.sections["Volume (DVC)"].expand(animate=False)
    for title in ("1. Images and region", "2. Mesh and correlation", "5. Display", "Log"):
        w.sections[title].collapse(animate=False)
    qtbot.wait(300)
    w.scroll_area.ensureWidgetVisible(w.sections["Volume (DVC)"])
    qtbot.wait(300)
    shot = tmp_path / "volume_dock.png"
    save_screenshot(viewer, shot)
    keep_for_docs(shot)
