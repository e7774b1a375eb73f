"""The dock's Live mode (issue 26): frames arrive in a folder while napari runs; the
frames layer grows, the result layers and the probe curves follow, the slider follows
the newest frame unless the user moved it, Stop ends the watch, the run folder loads."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
DOC_IMAGES = os.environ.get("NAPARI_ALDIC_DOC_IMAGES", "") not in ("", "0")


@pytest.mark.slow
def test_live_mode_grows_follows_and_stops(make_napari_viewer, qtbot, tmp_path,
                                           save_screenshot):
    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.live import LIVE_LAYER
    from napari_aldic._qt.plot_dock import ProbePlotDock
    from napari_aldic.engine import load_run
    from napari_aldic.engine.synthetic.camera import render_frames, write_frame

    frames = render_frames(5, (160, 160), rate=0.004, drift=0.4)
    cam, run = tmp_path / "camera", tmp_path / "run"
    cam.mkdir()
    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1500, 950)
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, area="right", name="napari-aldic")
    w.method.value, w.subset.value, w.step.value = "local", 21, 8
    w.sections["Live (watch a camera folder)"].expand(animate=False)
    w.live.folder.value, w.live.run_dir.value = str(cam), str(run)
    dock = ProbePlotDock(viewer)
    viewer.window.add_dock_widget(dock, area="right", name="Probes")
    dock.add_probe_layers()  # a line gauge along x
    dock.shapes_layer.add_lines(np.array([[80.0, 20.0], [80.0, 140.0]]), edge_color="yellow")
    w.live.start()
    for k in range(3):
        write_frame(cam / f"img_{k:02d}.tif", frames[k], "rename")
    model = w.live.model
    qtbot.waitUntil(lambda: len(model.results) == 3 and model.results[2] is not None,
                    timeout=120000)
    qtbot.waitUntil(lambda: viewer.layers[LIVE_LAYER].data.shape[0] == 3, timeout=5000)
    assert viewer.dims.current_step[0] == 2  # follows the newest frame
    u = next(lay for lay in viewer.layers if lay.name.startswith("DIC u"))
    assert u.data.shape[0] == 3 and np.isfinite(u.data[2]).any()
    qtbot.waitUntil(lambda: dock.table is not None and len(dock.table) == 3, timeout=10000)
    assert abs(dock.table["line1_strain"][2] - 2 * 0.004) < 1e-3  # the gauge along x

    viewer.dims.set_current_step(0, 1)  # the user looks back: the slider stays there
    assert not model.follow
    write_frame(cam / "img_03.tif", frames[3], "chunks")
    qtbot.waitUntil(lambda: len(model.results) == 4, timeout=60000)
    qtbot.waitUntil(lambda: viewer.layers[LIVE_LAYER].data.shape[0] == 4, timeout=5000)
    assert viewer.dims.current_step[0] == 1
    viewer.dims.set_current_step(0, 3)  # back on the newest: following again
    assert model.follow
    write_frame(cam / "img_04.tif", frames[4], "chunks")
    qtbot.waitUntil(lambda: len(model.results) == 5, timeout=60000)
    qtbot.waitUntil(lambda: viewer.dims.current_step[0] == 4, timeout=5000)
    qtbot.waitUntil(lambda: dock.table is not None and len(dock.table) == 5, timeout=10000)

    viewer.layers.selection.active = u
    for title in ("1. Images and region", "2. Mesh and correlation", "5. Display", "Log"):
        w.sections[title].collapse(animate=False)
    w.scroll_area.ensureWidgetVisible(w.sections["Live (watch a camera folder)"])
    qtbot.wait(200)
    shot = tmp_path / "live_dock.png"
    save_screenshot(viewer, shot)
    if DOC_IMAGES:
        save_screenshot(viewer, REPO / "docs" / "images" / "live_dock.png")
    w.live.stop()
    qtbot.waitUntil(lambda: not model.running and w.live.start_button.enabled, timeout=30000)
    assert "Watch ended: 4 frame(s)" in w.live.state.value
    seq = load_run(run)  # a normal run folder afterwards
    assert len(seq.frames) == 5 and np.allclose(seq[4].u[seq[4].valid],
                                                model.results[4].u[model.results[4].valid])
    assert w.analysis is not None and w.analysis.n_done == 5  # exports see the live run
