"""``correlate_volume``'s progress events and cancellation (as 2-D ``correlate``)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from napari_aldic.engine import Cancelled, ProgressEvent, correlate_volume
from napari_aldic.engine.synthetic.volume import VolumeMotion, speckle_volume_pair


@pytest.fixture(scope="module")
def pair():
    # 32^3, subset 11, step 1: 8000 nodes, so the IC-GN goes in several batches
    return speckle_volume_pair((32, 32, 32), VolumeMotion.make(shift=(0.4, -0.3, 0.2)), seed=5)


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_progress_runs_through_the_stages_to_done(pair, method):
    events = []
    res = correlate_volume(*pair, subset=11, step=2 if method == "aldic" else 1,
                           method=method, progress=events.append)
    assert all(isinstance(e, ProgressEvent) for e in events)
    stages = [e.stage for e in events]
    want = ["setup", "prefilter", "initial_guess", "icgn", "repair"]
    want += ["aldic", "done"] if method == "aldic" else ["done"]
    assert [s for i, s in enumerate(stages) if s not in stages[:i]] == want
    fr = [e.fraction for e in events]
    assert fr == sorted(fr) and fr[0] == 0.0 and fr[-1] == 1.0
    assert events[-1].message == f"{res.n_valid}/{len(res)} valid"
    if method == "local":  # batches of nodes report how many are done
        batches = [e for e in events if e.stage == "icgn" and "/" in e.message]
        assert len(batches) >= 3 and batches[-1].message.split("/")[0] == \
            batches[-1].message.split("/")[1].split()[0]


def test_cancel_event_stops_within_one_batch(pair):
    stop = threading.Event()
    events = []

    def progress(event):
        events.append(event)
        if event.stage == "icgn" and "/" in event.message:
            stop.set()  # after the first batch of nodes

    with pytest.raises(Cancelled):
        correlate_volume(*pair, subset=11, step=1, progress=progress, cancel=stop)
    assert [e.stage for e in events].count("icgn") == 2  # the stage start, one batch
    assert events[-1].stage == "icgn"


def test_cancel_callable_stops_the_admm(pair):
    seen = []
    with pytest.raises(Cancelled):
        correlate_volume(*pair, subset=11, step=4, method="aldic",
                         progress=lambda e: seen.append(e.stage),
                         cancel=lambda: "aldic" in seen)
    assert "done" not in seen


def test_cancel_of_another_kind_is_refused(pair):
    with pytest.raises(TypeError, match="threading.Event"):
        correlate_volume(*pair, subset=11, step=8, cancel=True)


def test_cancel_never_set_changes_nothing(pair):
    a = correlate_volume(*pair, subset=11, step=4)
    b = correlate_volume(*pair, subset=11, step=4, cancel=threading.Event(),
                         progress=lambda e: None)
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.valid, b.valid)
