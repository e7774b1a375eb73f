"""The "Advise subset" button: advice off the GUI thread, logged, the viewer usable."""

from __future__ import annotations

import napari  # noqa: F401  (testing extra: missing, these tests fail, not skip)
import pytest
import pytestqt  # noqa: F401

from napari_aldic._qt import DICWidget
from napari_aldic.engine import advise_subset

pytestmark = pytest.mark.gui


def test_advise_button_logs_the_engine_advice(make_napari_viewer_proxy, qtbot, add_inputs,
                                              speckle_stack):
    viewer = make_napari_viewer_proxy()
    stack = speckle_stack()
    add_inputs(viewer, stack)
    widget = DICWidget(viewer)
    viewer.window.add_dock_widget(widget, name="DIC (AL-DIC)", area="right")
    widget.correlation.target_noise.value = 0.02
    widget.correlation.advise.clicked()
    qtbot.waitUntil(lambda: "recommended subset" in widget.log.value
                    or "no tried subset" in widget.log.value, timeout=60_000)
    roi, _ = widget.inputs.roi(stack.shape[-2:], 0)
    adv = advise_subset(stack[0], roi, 0.02)
    if adv.recommended is None:
        assert "no tried subset" in widget.log.value
    else:
        assert f"recommended subset: {adv.recommended} px" in widget.log.value
    for r in adv.rows:
        assert f"subset {r['subset']} px: median {r['median_std_px']:.4f} px" in widget.log.value
    qtbot.waitUntil(lambda: widget.correlation.advise.enabled, timeout=10_000)


def test_advise_without_an_image_says_so(make_napari_viewer_proxy, qtbot):
    viewer = make_napari_viewer_proxy()
    widget = DICWidget(viewer)
    widget.correlation.advise.clicked()
    assert "choose an image first" in widget.log.value
