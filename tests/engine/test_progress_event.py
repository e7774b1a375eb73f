"""Progress as a typed event: stages, absolute frames, ETA; 0.1 callbacks still work."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_aldic.engine import ProgressEvent, correlate, synthetic as S, track
from napari_aldic.engine.core.progress import CORRELATE_STAGES

FAST = dict(subset=21, step=16, search=6)


@pytest.fixture(scope="module")
def stack():
    pat = S.make_pattern((96, 96), seed=3, margin=32)
    return np.stack([S.render(pat, (96, 96), None if k == 0 else S.Translation(0.3 * k, 0.0),
                              n_quad=2, seed=10 + k) for k in range(5)])


def test_correlate_reports_typed_events_in_stage_order(stack):
    seen: list[ProgressEvent] = []
    correlate(stack[0], stack[1], progress=seen.append, **FAST)
    assert all(isinstance(e, ProgressEvent) for e in seen)
    order = [CORRELATE_STAGES.index(e.stage) for e in seen]
    assert order == sorted(order) and seen[-1].stage == "done"
    fr = [e.fraction for e in seen]
    assert fr == sorted(fr) and fr[-1] == 1.0 and 0 < fr[0] < 0.2
    assert seen[0].frame is None and seen[0].n_frames == 1
    assert str(seen[0]).endswith("nodes") and str(seen[-1]) == "done"
    with pytest.raises(dataclasses.FrozenInstanceError):
        seen[0].fraction = 0.5


def test_track_events_carry_absolute_frames_fraction_and_eta(stack):
    seen: list[ProgressEvent] = []
    track(stack, frames=[0, 2, 4], progress=seen.append, **FAST)
    frames = [e for e in seen if e.stage.startswith("frame_")]
    assert [(e.stage, e.frame) for e in frames] == [
        ("frame_start", 2), ("frame_done", 2), ("frame_start", 4), ("frame_done", 4)]
    assert {e.n_frames for e in seen} == {2} and {e.reference for e in seen} == {0}
    # correlate's stages arrive inside each frame, as a share of the whole run
    inner = [e for e in seen if e.stage in CORRELATE_STAGES]
    assert {e.frame for e in inner} == {2, 4} and len(inner) >= 6
    fr = [e.fraction for e in seen]
    assert fr == sorted(fr) and fr[0] == 0.0 and fr[-1] == 1.0
    assert frames[1].fraction == 0.5 and frames[1].eta_s is not None and frames[1].eta_s >= 0
    assert frames[-1].eta_s == 0.0
    assert str(frames[0]) == "frame 2 against frame 0"
    assert str(frames[1]).startswith("frame 2 done: ") and str(frames[1]).endswith("valid")


def test_callbacks_of_0_1_get_the_text_with_a_deprecation_warning(stack):
    pair: list = []
    with pytest.warns(DeprecationWarning, match="ProgressEvent"):
        correlate(stack[0], stack[1], progress=lambda f, m: pair.append((f, m)), **FAST)
    assert pair[-1] == (1.0, "done") and all(isinstance(m, str) for _, m in pair)
    seq: list = []
    with pytest.warns(DeprecationWarning, match="ProgressEvent"):
        track(stack[:3], progress=lambda k, f, m: seq.append((k, f, m)), **FAST)
    # only track's own frame reports, as 0.1 gave them (no "IC-GN done" inside a frame)
    assert seq == [(1, 0.0, "frame 1 against frame 0"), seq[1], (2, 0.5, "frame 2 against "
                                                                  "frame 0"), seq[3]]
    assert seq[1][2].startswith("frame 1 done: ") and seq[3][:2] == (2, 1.0)
