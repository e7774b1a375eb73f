"""Fixtures for the napari plugin tests, and the display check of the GUI tests.

GUI tests (those that use ``qtbot``, ``qapp`` or napari's ``make_napari_viewer*``
fixtures, or carry the ``gui`` marker) need a display: a desktop session (DISPLAY or
WAYLAND_DISPLAY) or the ``Xvfb`` binary, which pytest-xvfb starts for the session
(Debian: ``apt-get install xvfb``). Without one, Qt would abort the whole test run
("Fatal Python error: Aborted") when the first QApplication is made; these tests are
skipped instead, with the reason. ``NAPARI_ALDIC_NO_DISPLAY=1`` forces that skip.
The napari-free plugin tests (reader, writer, analysis, manifest, sample data) always run.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
#: fixtures that create a QApplication (pytest-qt, napari's pytest plugin)
GUI_FIXTURES = frozenset({"qapp", "qtbot", "make_napari_viewer", "make_napari_viewer_proxy"})

SHAPE = (192, 192)
CENTER = (96.0, 96.0)  # (x, y)
#: frame k is deformed by the affine field with these values times LOAD[k]
EXX, EYY, TX, TY = 0.01, -0.004, 0.6, -0.4
LOAD = (0.0, 0.5, 1.0)
ROI_RECT = (24, 24, 168, 168)  # x0, y0, x1, y1 (pixels)
HOLE = (96.0, 96.0, 18.0)  # ellipse hole: cx, cy, radius (pixels)

_PROBE = ("from qtpy.QtWidgets import QApplication; app = QApplication([]); "
          "print(app.platformName())")


# ------------------------------------------------------------------ display check
def display_problem() -> str | None:
    """Why no Qt display can be had here, or None when one can.

    Called after pytest-xvfb has started Xvfb (it sets DISPLAY in pytest_configure).
    A display variable alone is not trusted: a short subprocess opens a QApplication
    (a failure there aborts only the subprocess).
    """
    if os.environ.get("NAPARI_ALDIC_NO_DISPLAY", "") not in ("", "0"):
        return "GUI test skipped: NAPARI_ALDIC_NO_DISPLAY is set"
    have_var = any(os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"))
    if not have_var:
        if shutil.which("Xvfb"):
            return ("GUI test skipped: Xvfb is installed but no display was started "
                    "(pytest-xvfb disabled by --no-xvfb or -p no:xvfb?)")
        return ("GUI test skipped: no display (DISPLAY and WAYLAND_DISPLAY are unset and the "
                "Xvfb binary is not on PATH; install Xvfb, e.g. apt-get install xvfb, and "
                "pytest-xvfb starts it)")
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                              timeout=120)
    except subprocess.TimeoutExpired:
        return "GUI test skipped: opening a Qt application timed out (display not responding)"
    if proc.returncode != 0:
        where = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or "?"
        lines = [ln.strip() for ln in (proc.stderr or proc.stdout).splitlines() if ln.strip()]
        why = "; ".join(lines[:2])[:300] or f"exit status {proc.returncode}"
        return f"GUI test skipped: Qt cannot open the display {where!r}: {why}"
    return None


def needs_display(item: pytest.Item) -> bool:
    return bool(GUI_FIXTURES & set(getattr(item, "fixturenames", ()))
                or item.get_closest_marker("gui"))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    gui = [it for it in items if HERE in Path(it.path).resolve().parents and needs_display(it)]
    if not gui:
        return
    reason = display_problem()
    if reason is None:
        return
    skip = pytest.mark.skip(reason=reason)
    for item in gui:
        item.add_marker(skip)


# ------------------------------------------------------------------ synthetic data
def _field(k: int):
    from napari_aldic.engine import synthetic

    s = LOAD[k]
    return synthetic.Affine.strain_rotation(exx=EXX * s, eyy=EYY * s, center=CENTER,
                                           t=(TX * s, TY * s))


def _render_stack(n_frames: int, shape) -> np.ndarray:
    from napari_aldic.engine import synthetic

    pat = synthetic.make_pattern(shape, seed=7)
    frames = [synthetic.render(pat, shape, None, n_quad=2)]
    for k in range(1, n_frames):
        f = _field(k) if n_frames <= len(LOAD) else synthetic.Translation(0.3 * k, -0.2 * k)
        frames.append(synthetic.render(pat, shape, f, n_quad=2))
    return np.stack(frames)


@pytest.fixture(scope="session")
def plugin_field():
    """``plugin_field(k)``: the affine field of frame k (k < 3) of :func:`speckle_stack`."""
    return _field


@pytest.fixture(scope="session")
def speckle_stack():
    """``speckle_stack(n_frames=3, shape=(192, 192))``: a (n_frames, H, W) uint8 stack,
    made once per session for each (n_frames, shape); treat it as read-only.

    Frame k is deformed by ``plugin_field(k)`` for stacks of up to 3 frames, by a
    growing translation (0.3 k, -0.2 k) for longer stacks.
    """
    made: dict[tuple, np.ndarray] = {}

    def speckle_stack(n_frames: int = 3, shape=SHAPE) -> np.ndarray:
        key = (n_frames, tuple(shape))
        if key not in made:
            made[key] = _render_stack(n_frames, tuple(shape))
        return made[key]

    return speckle_stack


@pytest.fixture(scope="session")
def roi_rect() -> tuple:
    """The ROI rectangle of :func:`add_inputs`: x0, y0, x1, y1 (pixels)."""
    return ROI_RECT


@pytest.fixture(scope="session")
def hole_circle() -> tuple:
    """The ellipse hole of :func:`add_inputs`: cx, cy, radius (pixels)."""
    return HOLE


def rect_rc(x0, y0, x1, y1) -> np.ndarray:
    """Rectangle corners as napari (row, col) vertices."""
    return np.array([[y0, x0], [y0, x1], [y1, x1], [y1, x0]], float)


def _add_inputs(viewer, stack):
    image = viewer.add_image(stack, name="speckle")
    roi = viewer.add_shapes([rect_rc(*ROI_RECT)], shape_type="rectangle", name="ROI",
                            face_color="transparent", edge_color="yellow", edge_width=2)
    cx, cy, r = HOLE
    hole = viewer.add_shapes([np.array([[cy, cx], [r, r]])], shape_type="ellipse",
                             name="hole", face_color="transparent", edge_color="red",
                             edge_width=2, metadata={"napari_aldic_role": "roi_subtract"})  # chosen
    seeds = viewer.add_points([[40.0, 44.0]], name="seeds", size=6, face_color="cyan")
    return image, roi, hole, seeds


@pytest.fixture(scope="session")
def add_inputs():
    """``add_inputs(viewer, stack)``: image, ROI rectangle, ellipse hole and one seed
    point in the viewer; returns the four layers."""
    return _add_inputs


def _save_screenshot(viewer, path) -> None:
    from PIL import Image

    rgba = viewer.screenshot(canvas_only=False, flash=False)
    img = Image.fromarray(np.asarray(rgba)[..., :3])
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


@pytest.fixture(scope="session")
def save_screenshot():
    """``save_screenshot(viewer, path)``: full-window screenshot (dock widgets included)
    as a compact 256-colour PNG."""
    return _save_screenshot


# ------------------------------------------------------------------ widget helpers
@pytest.fixture(autouse=True)
def _own_config_dir(tmp_path_factory, monkeypatch):
    """Every test remembers its widget settings in a folder of its own (never the
    user's configuration folder), so no test sees another one's last parameters."""
    monkeypatch.setenv("NAPARI_ALDIC_CONFIG_DIR", str(tmp_path_factory.mktemp("config")))


def _small_analysis():
    from napari_aldic._analysis import run_analysis
    from napari_aldic.engine import DICParams

    stack = _render_stack(3, SHAPE)
    roi = np.zeros(SHAPE, bool)
    x0, y0, x1, y1 = ROI_RECT
    roi[y0:y1, x0:x1] = True
    return run_analysis(stack, roi, DICParams(method="local", subset=21, step=8), source="speckle")


@pytest.fixture(scope="session")
def small_analysis():
    """A 3-frame Analysis of the (3, 192, 192) speckle stack inside ROI_RECT (local,
    subset 21, step 8); read-only."""
    return _small_analysis()


def field_layer(viewer, key: str):
    """The result layer of field ``key`` ("u", "exx", "displacement" ...), found by
    its metadata (its name carries the unit)."""
    from napari_aldic._qt.results import find_result_layer

    layer = find_result_layer(viewer.layers, key)
    assert layer is not None, f"no result layer {key!r} in {[lay.name for lay in viewer.layers]}"
    return layer


@pytest.fixture(scope="session")
def result_layer():
    """``result_layer(viewer, key)``: the result layer of field ``key``."""
    return field_layer


@pytest.fixture(scope="session")
def keep_for_docs(repo_root):
    """``keep_for_docs(path)``: copy a screenshot to ``docs/images`` when the user
    guide's pictures are regenerated (``NAPARI_ALDIC_GUIDE_IMAGES=1``)."""
    import shutil

    def keep(path) -> None:
        if os.environ.get("NAPARI_ALDIC_GUIDE_IMAGES", "") not in ("", "0"):
            shutil.copy(path, repo_root / "docs" / "images" / Path(path).name)

    return keep
