"""What a first-time user sees: the guided dock at 1280 x 720 and 1600 x 1000, the user
guide's analysis of the shipped crack sequence, and a viewer that never stalls.

The screenshots go to the test's own folder; with ``NAPARI_ALDIC_GUIDE_IMAGES=1`` they
are also copied to ``docs/images`` (the user guide's pictures).
"""

from __future__ import annotations

import os
import time

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import numpy as np
import pytest
import pytestqt  # noqa: F401

from napari_aldic._qt import DICWidget

# needs a display: without one these tests are skipped (tests/plugin/conftest.py)
pytestmark = pytest.mark.gui


@pytest.fixture(autouse=True)
def _fresh_notifications():
    """Start with an empty notification log (napari's manager is process-wide)."""
    from napari.utils.notifications import notification_manager

    notification_manager.records.clear()
    yield

#: the user guide's region of interest on the crack sample (x, y pixels): the specimen
#: without the notch and the background at the left
GUIDE_ROI = [(32, 70), (378, 70), (378, 378), (62, 378), (62, 272), (2, 272), (2, 207),
             (32, 207)]
#: the crack path from the notch (x, y pixels, reference frame)
GUIDE_CRACK = [(2, 245), (95, 245)]


def _open_guide(viewer):
    [image] = viewer.open_sample("napari-aldic", "crack_sequence")
    _, widget = viewer.window.add_plugin_dock_widget("napari-aldic",
                                                     "Digital image correlation (AL-DIC)")
    viewer.dims.set_current_step(0, 0)
    roi = viewer.add_shapes([np.array([(y, x) for x, y in GUIDE_ROI], float)],
                            shape_type="polygon", name="ROI", face_color="transparent",
                            edge_color="yellow", edge_width=2)
    crack = viewer.add_shapes([np.array([(y, x) for x, y in GUIDE_CRACK], float)],
                              shape_type="path", name="crack", edge_color="red", edge_width=3)
    widget.roi_subtract.value = [crack]  # the guide's step: the crack is chosen as a hole
    viewer.reset_view()
    return image, widget, roi, crack


def _inside(widget, window) -> bool:
    """Whether ``widget`` (a QWidget) is shown entirely inside the main window."""
    from qtpy.QtCore import QRect

    top_left = widget.mapTo(window, widget.rect().topLeft())
    box = QRect(top_left, widget.size())
    return widget.isVisible() and window.rect().contains(box)


@pytest.mark.slow  # ~20 s: a real 6-frame AL-DIC analysis and five screenshots
def test_guide_analysis_of_the_shipped_crack_sequence(make_napari_viewer, qtbot, tmp_path,
                                                      save_screenshot, keep_for_docs,
                                                      result_layer):
    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1600, 1000)
    image, w, roi, crack = _open_guide(viewer)
    assert isinstance(w, DICWidget) and w.image.value is image
    assert list(w.roi_add.value) == [roi] and list(w.roi_subtract.value) == [crack]
    assert "Ready." in w.status.value
    qtbot.wait(200)
    save_screenshot(viewer, tmp_path / "guide_1_inputs.png")

    w.method.value, w.subset.value, w.step.value = "aldic", 31, 8
    w.run_button.clicked()
    qtbot.waitUntil(lambda: not w.running, timeout=180_000)
    assert "finished" in w.log.value
    v = result_layer(viewer, "v")
    last = v.data[-1]
    sy, sx = v.scale[-2:]
    ty, tx = v.translate[-2:]

    def at(x, y):
        return last[int(round((y - ty) / sy)), int(round((x - tx) / sx))]

    def jump(x0):  # v across the crack line, median over a 24 px run of columns (a node
        # there may be flagged untrusted: its predicted uncertainty is close to the limit)
        return np.nanmedian([at(x, 248) - at(x, 208) for x in range(x0 - 12, x0 + 13, 4)])

    # the crack opens: v jumps across it near the notch (~7 px), not far from it
    opening = jump(70)
    assert opening > 3.0, opening
    assert abs(jump(330)) < 0.2 * opening
    assert np.nanmedian(last) < -50  # the specimen moved ~57 px up

    # rigid-body motion removed, fields on the deformed specimen: the opening stands out
    w.rigid.value = True
    w.deformed.value = True
    w.show_field.value = "v"
    viewer.dims.set_current_step(0, 5)
    qtbot.wait(200)
    save_screenshot(viewer, tmp_path / "guide_2_displacement.png")
    w.show_field.value = "eyy"
    w.vectors.value = False
    w.scroll_area.ensureWidgetVisible(w.display.legend.native)
    qtbot.wait(200)
    assert "Unreliable nodes (last frame)" in w.display.legend.value
    save_screenshot(viewer, tmp_path / "guide_3_strain.png")
    w.sections["6. Export"].expand(animate=False)
    w.exports.format.value = "csv"
    qtbot.wait(100)
    w.scroll_area.ensureWidgetVisible(w.exports.export_button.native)
    qtbot.wait(200)
    save_screenshot(viewer, tmp_path / "guide_4_export.png")
    written = w.exports.export(tmp_path / "crack.csv")
    assert written[0].exists()

    # the analysis saved and opened again in a fresh viewer
    project = w.save_project(tmp_path / "crack_analysis.json")
    again = make_napari_viewer()
    w2 = DICWidget(again)
    assert w2.open_project(project)
    assert w2.image.value.data.shape == image.data.shape
    assert len(w2.roi_add.value) == 1 and len(w2.roi_subtract.value) == 1
    assert (w2.method.value, w2.subset.value, w2.step.value) == ("aldic", 31, 8)
    assert w2.rigid.value and w2.deformed.value and w2.show_field.value == "eyy"
    for name in ("guide_1_inputs.png", "guide_2_displacement.png", "guide_3_strain.png",
                 "guide_4_export.png"):
        assert 20_000 < (tmp_path / name).stat().st_size < 800_000
        keep_for_docs(tmp_path / name)


@pytest.mark.parametrize("size", [(1280, 720), (1600, 1000)])
def test_dock_at_common_screen_sizes(make_napari_viewer, qtbot, tmp_path, size,
                                     save_screenshot, keep_for_docs, small_analysis):
    viewer = make_napari_viewer(show=True)
    viewer.window.resize(*size)
    viewer.add_image(np.zeros((3, 192, 192), np.uint8), name="speckle")
    from napari_aldic._qt.plot_dock import ProbePlotDock

    # both docks, as the user guide has them (issue 24, trap 10: the DIC dock kept one row);
    # at 1280 x 720 the two cannot stand one above the other: the DIC dock is a tab in
    # front of the probes
    tabs = size[1] < 800
    w = DICWidget(viewer)
    if tabs:
        viewer.window.add_dock_widget(ProbePlotDock(viewer), area="right", name="Probes")
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right", tabify=tabs)
    if not tabs:
        viewer.window.add_dock_widget(ProbePlotDock(viewer), area="right", name="Probes")
    w.show_analysis(small_analysis)
    qtbot.wait(300)
    window = viewer.window._qt_window
    assert (window.width(), window.height()) == size
    # the sections stay readable: several rows of controls in view, not one
    assert w.scroll_area.viewport().height() >= 0.2 * size[1], w.scroll_area.viewport().height()
    # Run, Cancel, the status line and the progress always in view
    for control in (w.run_button, w.cancel_button, w.status, w.progress):
        assert _inside(control.native, window), control
    # every section is reached by scrolling one area: the last one too
    area = w.scroll_area
    area.ensureWidgetVisible(w.sections["Log"])
    qtbot.wait(100)
    assert _inside(w.sections["Log"].toggleButton(), window)
    area.verticalScrollBar().setValue(0)
    qtbot.wait(100)
    # nothing cut off at the right: the scroll area's content fits its width
    assert area.widget().width() <= area.viewport().width()
    shot = tmp_path / f"widget_{size[0]}x{size[1]}.png"
    save_screenshot(viewer, shot)
    assert 10_000 < shot.stat().st_size < 800_000
    keep_for_docs(shot)


def _insertion_cost(viewer, qtbot) -> float:
    """Main-thread seconds napari itself takes here to insert (and draw) one
    layer: the most of an Image, a Points and a Vectors layer of the run's
    sizes, each the second of its kind (the first compiles its shaders)."""
    rng = np.random.default_rng(0)
    makers = (lambda: viewer.add_image(rng.random((48, 48)), name="_cal"),
              lambda: viewer.add_points(rng.random((400, 2)) * 190, name="_cal"),
              lambda: viewer.add_vectors(np.stack([rng.random((400, 2)) * 190,
                                                   rng.random((400, 2))], 1), name="_cal"))
    costs = []
    for make in makers:
        for _ in range(2):
            c0 = time.thread_time()
            layer = make()
            qtbot.wait(1)
            costs.append(time.thread_time() - c0)
            viewer.layers.remove(layer)
    return max(costs[1::2])


def test_viewer_never_stalls_during_a_run(make_napari_viewer_proxy, qtbot, speckle_stack,
                                         monkeypatch):
    """A heartbeat timer every 10 ms while a run tracks frames and its result layers
    are added: no gap between two beats may exceed 0.2 s outside the canvas' drawing,
    and no drawing of the canvas may take 0.5 s (issue 24's goal for any stall).

    The run computes in worker threads and makes the result layers there; the main
    thread only adds them, one layer per turn of the event loop. Each such step (this
    plugin's code and napari's insertion of one layer) must take under 0.2 s of the
    main thread. The heartbeat gaps are wall-clock time, which also holds napari's
    drawing of the new layer after its step and whatever other programs on a loaded
    machine take: that limit is scaled by the machine's load (1-minute load average
    per CPU, at least 1) measured just before. All three limits are also scaled by
    what napari itself costs here: its insertion of one layer, measured before the
    run (:func:`_insertion_cost`), against the 0.1 s the limits were set with (at
    least 1). A slower machine or renderer scales napari's share and ours alike (a
    2-core cloud VM measured 0.15-0.2 s a step and drew a new layer kind in 0.64 s
    with Mesa's software renderer); the plugin doing its work on the main thread
    would still exceed them by far (a frame's analysis is seconds).
    The first drawing of a layer kind compiles its OpenGL shaders: Mesa's software
    renderer under Xvfb takes 0.1-0.2 s of the main thread for that (a GPU driver
    milliseconds), napari's and vispy's cost whatever shows the layer; the canvas'
    drawing (vispy's draw event) is timed apart and held to 0.5 s. A full garbage
    collection of Python (generation 2) stops every thread for a time set by the whole
    process' heap (~0.3 s for the ~400,000 objects of napari, Qt, vispy and Numba here);
    the run keeps the objects of before out of collections while it shows its results
    (about 0.02 s each then), and any beats around one are reported, not counted.
    """
    import gc

    from qtpy.QtCore import QTimer
    from vispy.scene import SceneCanvas

    draws: list[tuple[float, float]] = []  # [start, end] of the canvas' drawings
    on_draw = SceneCanvas.on_draw

    def timed_draw(self, event):
        t0 = time.perf_counter()
        try:
            return on_draw(self, event)
        finally:
            draws.append((t0, time.perf_counter()))

    monkeypatch.setattr(SceneCanvas, "on_draw", timed_draw)  # before the canvas exists
    viewer = make_napari_viewer_proxy(show=True)
    viewer.add_image(speckle_stack(4, (192, 192)), name="speckle")
    w = DICWidget(viewer)
    viewer.window.add_dock_widget(w, name="DIC (AL-DIC)", area="right")
    qtbot.waitUntil(lambda: "preparing" not in w.status.value.lower(), timeout=120_000)
    w.method.value, w.subset.value, w.step.value = "aldic", 21, 4
    beats: list[tuple[float, float]] = []
    timer = QTimer()
    timer.setInterval(10)
    timer.timeout.connect(lambda: beats.append((time.perf_counter(), time.thread_time())))
    collections: list[list[float]] = []  # [start, end] of full collections

    def on_gc(phase, info):
        if info["generation"] == 2:
            if phase == "start":
                collections.append([time.perf_counter(), np.inf])
            else:
                collections[-1][1] = time.perf_counter()

    napari_s = _insertion_cost(viewer, qtbot)
    env = max(1.0, napari_s / 0.1)
    load = max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1)) * env
    gc.callbacks.append(on_gc)
    try:
        timer.start()
        qtbot.wait(100)
        draws.clear()
        w.run_button.clicked()
        qtbot.waitUntil(lambda: not w.running, timeout=120_000)
        qtbot.wait(200)
        timer.stop()
    finally:
        gc.callbacks.remove(on_gc)
    t = np.array(beats)
    gaps, cpu = np.diff(t[:, 0]), np.diff(t[:, 1])
    in_gc = np.zeros(gaps.size, bool)
    for start, end in collections:
        in_gc |= (t[:-1, 0] <= end) & (t[1:, 0] >= start)
    drawing = np.zeros(gaps.size)  # seconds of each gap spent drawing the canvas
    for start, end in draws:
        drawing += np.clip(np.minimum(t[1:, 0], end) - np.maximum(t[:-1, 0], start), 0, None)
    rest = np.where(in_gc, 0.0, gaps - drawing)
    assert "finished" in w.log.value

    def no_gc(start, end) -> bool:
        return not any(s <= end and e >= start for s, e in collections)

    steps = [cpu_s for start, end, cpu_s in w.run_panel.display_steps if no_gc(start, end)]
    # a layer a step
    assert len(w.run_panel.display_steps) >= 9 and max(steps) < 0.2 * env, (steps, napari_s)
    assert draws, "the canvas was never drawn during the run"
    longest_draw = max(end - start for start, end in draws if no_gc(start, end))
    assert longest_draw < 0.5 * load, f"one drawing of the canvas took {longest_draw:.3f} s"
    gc_s = [round(end - start, 3) for start, end in collections]
    k = int(np.argmax(rest))
    assert rest[k] < 0.2 * load, (f"event loop stalled {rest[k]:.3f} s outside drawing "
                                  f"(gap {gaps[k]:.3f} s, main thread {cpu[k]:.3f} s of it; "
                                  f"load and napari factor {load:.1f}; full garbage collections "
                                  f"{gc_s} s)")
