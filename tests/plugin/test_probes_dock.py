"""The probe plot dock in napari: probes from Shapes/Points layers, live curves, load
data, the current frame, clicking the plot, and probes from layers in pixels."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
#: set to write the screenshots of docs/probes.md into docs/images
DOC_IMAGES = os.environ.get("NAPARI_ALDIC_DOC_IMAGES", "") not in ("", "0")


def _truth_strain(field, x0, y0, x1, y1):
    u, v = field.displacement(np.array([x0, x1], float), np.array([y0, y1], float))
    L = np.hypot(x1 - x0, y1 - y0)
    return np.hypot(x1 - x0 + u[1] - u[0], y1 - y0 + v[1] - v[0]) / L - 1


@pytest.fixture(scope="module")
def analysis(speckle_stack):
    from napari_aldic._analysis import run_analysis
    from napari_aldic.engine import DICParams

    return run_analysis(speckle_stack(), None, DICParams(subset=21, step=8))


def _show(viewer, analysis, image):
    from napari_aldic._layers import Display
    from napari_aldic._qt.results import ResultLayers

    results = ResultLayers(viewer)
    results.analysis, results.image = analysis, image
    results.show(Display(), image)
    return results


def _click(qtbot, dock, ax, x, y):
    from qtpy.QtCore import QPoint, Qt

    dock.canvas.draw()
    px, py = ax.transData.transform((x, y))
    ratio = dock.canvas.device_pixel_ratio or 1.0
    qt_y = dock.canvas.height() - py / ratio
    qtbot.mouseClick(dock.canvas, Qt.MouseButton.LeftButton,
                     pos=QPoint(int(round(px / ratio)), int(round(qt_y))))


@pytest.mark.slow  # ~15 s: a shown viewer, result layers made twice, screenshots
def test_probe_dock_curves_follow_probes_results_and_frames(
        make_napari_viewer, qtbot, speckle_stack, analysis, plugin_field, tmp_path,
        save_screenshot):
    from napari_aldic._qt.plot_dock import ProbePlotDock

    viewer = make_napari_viewer(show=True)
    viewer.window.resize(1400, 900)
    image = viewer.add_image(speckle_stack(), name="speckle")
    partial = replace(analysis, results=[*analysis.results[:2], None],
                      strains=[*analysis.strains[:2], None])
    results = _show(viewer, partial, image)  # a run half way: frame 2 not done yet
    line = (40.0, 96.0, 150.0, 96.0)  # x0, y0, x1, y1
    shapes = viewer.add_shapes([np.array([[line[1], line[0]], [line[3], line[2]]])],
                               shape_type="line", name="probes", edge_color="yellow",
                               edge_width=2)
    shapes.add_rectangles(np.array([[60.0, 60.0], [130.0, 130.0]]), edge_color="cyan")
    viewer.add_points([[70.0, 120.0]], name="probe points", size=8, face_color="magenta")
    dock = ProbePlotDock(viewer)
    viewer.window.add_dock_widget(dock, area="right", name="Probes")
    assert dock.shapes_combo.currentText() == "probes"  # picked by name
    assert dock.points_combo.currentText() == "probe points"
    dock.recompute()
    assert list(dock.table.frames) == [0, 1]
    assert {"line1_strain", "area1_u_mean", "point1_u"} <= set(dock.table.columns)

    # the run finishes: the result layers update and the curves follow
    results.analysis = analysis
    results.show(results_display(), image)
    qtbot.waitUntil(lambda: dock.table is not None and len(dock.table) == 3, timeout=3000)
    for k in range(3):
        truth = _truth_strain(plugin_field(k), *line)
        assert abs(dock.table["line1_strain"][k] - truth) < 2e-4
    area = dock.table.probes.areas[0]
    assert area.params == pytest.approx((60.0, 60.0, 130.0, 130.0))

    # moving the gauge updates its curve
    shapes.data = [np.array([[50.0, 30.0], [150.0, 160.0]]), shapes.data[1]]
    qtbot.waitUntil(lambda: dock.table.probes.lines[0].x0 == pytest.approx(30.0), timeout=3000)
    truth = _truth_strain(plugin_field(2), 30.0, 50.0, 160.0, 150.0)
    assert abs(dock.table["line1_strain"][2] - truth) < 2e-4

    # load data (frame column) gives the stress-strain curve
    load = tmp_path / "machine.csv"
    load.write_text("Frame;Force\n(-);(kN)\n0;0,0\n1;1,2\n2;2,4\n", encoding="utf-8")
    assert dock.load_csv(load, area_mm2=12.0)
    np.testing.assert_allclose(dock.table["stress_MPa"], [0.0, 100.0, 200.0])
    assert "stress" in dock.axes

    # the current frame is marked; clicking the plot moves the frame slider
    viewer.dims.set_current_step(0, 1)
    assert dock.current_frame() == 1
    _click(qtbot, dock, dock.axes["lines"], 2.0, dock.table["line1_strain"][2])
    assert viewer.dims.current_step[0] == 2
    _click(qtbot, dock, dock.axes["stress"], 0.0, 0.0)
    assert viewer.dims.current_step[0] == 0

    viewer.dims.set_current_step(0, 2)
    viewer.layers.selection.active = next(lay for lay in viewer.layers
                                          if lay.name.startswith("DIC |u|"))
    shot = tmp_path / "probes_dock.png"
    save_screenshot(viewer, shot)
    plot = tmp_path / "probes_dock_panel.png"
    dock.grab().save(str(plot))
    from PIL import Image

    pix = np.asarray(Image.open(plot).convert("L"), float)
    assert pix.shape[0] > 300 and pix.std() > 10
    if DOC_IMAGES:
        save_screenshot(viewer, REPO / "docs" / "images" / "probes_dock.png")
        dock.grab().save(str(REPO / "docs" / "images" / "probes_dock_panel.png"))
    # exports from the dock
    assert dock.save_csv(tmp_path / "dock.csv").read_text().startswith("frame,line1_strain")
    assert dock.save_plot(tmp_path / "dock.png").stat().st_size > 5000


def results_display():
    from napari_aldic._layers import Display

    return Display()


def test_probes_from_layers_use_reference_pixels(make_napari_viewer, speckle_stack, analysis):
    """Scaled and shifted images: probes drawn in world units land on the right pixels."""
    from napari_aldic._qt.probes import find_analysis, probes_from_layers

    viewer = make_napari_viewer()
    image = viewer.add_image(speckle_stack(), name="speckle", scale=(1.0, 0.5, 0.5),
                             translate=(0.0, 10.0, 20.0))
    _show(viewer, analysis, image)
    view = find_analysis(viewer.layers)
    assert view is not None and view.t_scale == 1.0
    # world (row, col) = translate + 0.5 * (y, x)
    shapes = viewer.add_shapes([np.array([[10 + 0.5 * 96, 20 + 0.5 * 40],
                                          [10 + 0.5 * 96, 20 + 0.5 * 150]]),
                                np.array([[10 + 45, 20 + 40], [15.0, 10.0]])],  # centre, radii
                               shape_type=["line", "ellipse"], name="probes")
    points = viewer.add_points([[0.0, 10 + 0.5 * 120, 20 + 0.5 * 70]], name="pts")  # 3-D
    probes, notes = probes_from_layers(shapes, points, view)
    assert not notes
    ln = probes.lines[0]
    assert (ln.x0, ln.y0, ln.x1, ln.y1) == pytest.approx((40, 96, 150, 96))
    ell = probes.areas[0]
    assert ell.kind == "ellipse"
    assert ell.params == pytest.approx((80.0, 90.0, 20.0, 30.0, 0.0), abs=1e-9)
    assert (probes.points[0].x, probes.points[0].y) == pytest.approx((70.0, 120.0))


def test_added_probe_layers_are_marked_as_probes_not_roi(make_napari_viewer):
    from napari_aldic._qt.plot_dock import ProbePlotDock
    from napari_aldic._qt.project import is_probe_layer

    viewer = make_napari_viewer()
    dock = ProbePlotDock(viewer)
    dock.add_probe_layers()
    assert dock.shapes_layer is not None and dock.points_layer is not None
    assert is_probe_layer(dock.shapes_layer) and is_probe_layer(dock.points_layer)
    other = viewer.add_shapes(name="gauges", edge_color="red")
    dock.set_probe_layers(other, None)
    assert is_probe_layer(other)


def test_probe_layers_are_not_offered_as_roi_holes_or_seeds(make_napari_viewer):
    """The DIC dock's layer lists leave the probe layers out (they measure; a probe
    chosen as the ROI or as seeds would silently reshape the analysis)."""
    from napari_aldic._qt import DICWidget
    from napari_aldic._qt.plot_dock import ProbePlotDock

    viewer = make_napari_viewer()
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    ProbePlotDock(viewer).add_probe_layers()
    viewer.add_shapes(name="coupon", edge_color="red")
    viewer.add_points(np.array([[10.0, 10.0]]), name="seed points")
    widget.inputs.reset_choices()
    inp = widget.inputs

    shapes = {lay.name for lay in viewer.layers if lay.__class__.__name__ == "Shapes"}
    assert {"probes", "coupon"} <= shapes  # both exist, only one is offered
    for w in (inp.roi_add, inp.roi_subtract):
        got = {lay.name for lay in w.choices}
        assert "coupon" in got and "probes" not in got, (w.label, got)
    seeds = {lay.name for lay in inp.seeds.choices if lay is not None}
    assert "seed points" in seeds and "probe points" not in seeds, seeds
