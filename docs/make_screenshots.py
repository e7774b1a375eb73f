"""Regenerate the screenshots of docs/user_guide.md (a real analysis in napari).

Run from the repository root, with a display or under Xvfb::

    xvfb-run -a -s "-screen 0 1600x1200x24" python docs/make_screenshots.py [crack_sequence.tif]

It does what the guide describes: open the crack stack with the plugin's
reader, draw the ROI and the crack, run AL-DIC from the dock widget and look at
the result layers. The images go to docs/images/guide_*.png.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "images"
DEFAULT = HERE.parents[1] / "shared" / "data" / "crack_sequence" / "crack_sequence.tif"


def save(viewer, name: str) -> None:
    from PIL import Image

    rgba = viewer.screenshot(canvas_only=False, flash=False)
    img = Image.fromarray(np.asarray(rgba)[..., :3])
    img = img.resize((img.width * 4 // 5, img.height * 4 // 5), Image.Resampling.LANCZOS)
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(OUT / name, optimize=True)
    print("wrote", OUT / name)


def wait(widget, app, timeout: float = 600.0) -> None:
    t0 = time.time()
    while widget.running and time.time() - t0 < timeout:
        app.processEvents()
        time.sleep(0.02)
    app.processEvents()


def main(path: Path) -> None:
    import napari
    from qtpy.QtWidgets import QApplication

    OUT.mkdir(exist_ok=True)
    viewer = napari.Viewer()
    viewer.window.resize(1500, 1000)
    app = QApplication.instance()
    [stack] = viewer.open(str(path), plugin="napari-aldic")
    _, widget = viewer.window.add_plugin_dock_widget("napari-aldic",
                                                     "Digital image correlation (AL-DIC)")
    # 1. the region of interest: the speckled specimen, and the crack path (reference frame)
    roi = viewer.add_shapes([np.array([[10, 235], [10, 795], [1190, 795], [1190, 235]], float)],
                            shape_type="rectangle", name="ROI", face_color="transparent",
                            edge_color="yellow", edge_width=6)
    viewer.add_shapes([np.array([[590, 200], [588, 330]], float)], shape_type="path",
                      name="crack", edge_color="red", edge_width=10, opacity=1.0)
    widget.method.value = "aldic"
    widget.subset.value = 31
    widget.step.value = 12
    widget.strain_window.value = 7
    viewer.layers.selection.active = roi
    viewer.dims.set_current_step(0, 0)
    viewer.reset_view()
    app.processEvents()
    save(viewer, "guide_1_inputs.png")

    # 2. run, then look at the last frame
    widget.run()
    wait(widget, app)
    last = stack.data.shape[0] - 1
    viewer.dims.set_current_step(0, last)
    for name in ("DIC u", "DIC |u|", "DIC v", "DIC exx", "DIC eyy", "DIC exy", "DIC von Mises"):
        viewer.layers[name].visible = name == "DIC u"
    viewer.layers["crack"].visible = False
    viewer.layers.selection.active = viewer.layers["DIC u"]
    u = viewer.layers["DIC u"]
    u.colorbar.visible = True
    u.contrast_limits = (-12.0, 12.0)  # what a user does in the layer controls
    viewer.scene.camera.center = (600, 480)
    viewer.scene.camera.zoom = viewer.scene.camera.zoom * 1.7
    app.processEvents()
    save(viewer, "guide_2_displacement.png")

    # 3. strain on the deformed configuration, zoomed on the crack tip
    viewer.layers["DIC u"].visible = False
    viewer.layers["DIC displacement"].visible = False
    roi.visible = False
    widget.deformed.value = True
    eyy = viewer.layers["DIC eyy"]
    eyy.visible = True
    eyy.colorbar.visible = True
    viewer.layers.selection.active = eyy
    viewer.scene.camera.center = (560, 420)
    viewer.scene.camera.zoom = viewer.scene.camera.zoom * 1.3
    app.processEvents()
    save(viewer, "guide_3_strain.png")
    print(widget.log.value)
    viewer.close()


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT)
