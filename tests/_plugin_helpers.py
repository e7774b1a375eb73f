"""Shared synthetic data for the napari plugin tests (imported by test_plugin_*.py)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

SHAPE = (192, 192)
CENTER = (96.0, 96.0)  # (x, y)
#: frame k is deformed by the affine field with these values times LOAD[k]
EXX, EYY, TX, TY = 0.01, -0.004, 0.6, -0.4
LOAD = (0.0, 0.5, 1.0)
ROI_RECT = (24, 24, 168, 168)  # x0, y0, x1, y1 (pixels)
HOLE = (96.0, 96.0, 18.0)  # ellipse hole: cx, cy, radius (pixels)


def field(k: int):
    from napari_aldic.engine import synthetic

    s = LOAD[k]
    return synthetic.Affine.strain_rotation(exx=EXX * s, eyy=EYY * s, center=CENTER,
                                           t=(TX * s, TY * s))


@lru_cache(maxsize=4)
def speckle_stack(n_frames: int = 3, shape=SHAPE) -> np.ndarray:
    """(n_frames, H, W) uint8 stack; frame k deformed by ``field(k)`` (k < 3), or by
    a growing translation for longer stacks."""
    from napari_aldic.engine import synthetic

    pat = synthetic.make_pattern(shape, seed=7)
    frames = [synthetic.render(pat, shape, None, n_quad=2)]
    for k in range(1, n_frames):
        f = field(k) if n_frames <= len(LOAD) else synthetic.Translation(0.3 * k, -0.2 * k)
        frames.append(synthetic.render(pat, shape, f, n_quad=2))
    return np.stack(frames)


def rect_rc(x0, y0, x1, y1) -> np.ndarray:
    """Rectangle corners as napari (row, col) vertices."""
    return np.array([[y0, x0], [y0, x1], [y1, x1], [y1, x0]], float)


def add_inputs(viewer, stack):
    """Image, ROI rectangle, ellipse hole and one seed point in the viewer."""
    image = viewer.add_image(stack, name="speckle")
    roi = viewer.add_shapes([rect_rc(*ROI_RECT)], shape_type="rectangle", name="ROI",
                            face_color="transparent", edge_color="yellow", edge_width=2)
    cx, cy, r = HOLE
    hole = viewer.add_shapes([np.array([[cy, cx], [r, r]])], shape_type="ellipse",
                             name="hole", face_color="transparent", edge_color="red",
                             edge_width=2)
    seeds = viewer.add_points([[40.0, 44.0]], name="seeds", size=6, face_color="cyan")
    return image, roi, hole, seeds


def save_screenshot(viewer, path) -> None:
    """Full-window screenshot (dock widgets included) as a compact 256-colour PNG."""
    from PIL import Image

    rgba = viewer.screenshot(canvas_only=False, flash=False)
    img = Image.fromarray(np.asarray(rgba)[..., :3])
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
