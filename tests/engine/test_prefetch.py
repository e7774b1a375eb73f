"""Work on the reference alone started ahead on a background thread
(``Images.prefetch``, issue 22, speed): the results are those of computing
it in place; a job not started when it is needed is computed there and
then, a started one is waited for a while (``RUNNING_WAIT``) and then computed
there too (a loaded machine starves the low-priority thread; the analysis
must never wait on it for long)."""

import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from napari_aldic.engine import Reason, correlate, synthetic
from napari_aldic.engine.dic import images as images_mod
from napari_aldic.engine.dic.images import Images

FIELD = synthetic.Affine.strain_rotation(exx=0.005, center=(128, 128), t=(1.3, -0.6))


@pytest.fixture(scope="module")
def pair_with_bar():
    """Speckle with a static dark bar (the flat-pixel windows are used) and a
    periodic patch (the tiles' candidate lags are used)."""
    r, d = synthetic.speckle_pair((256, 256), FIELD, noise=0.5, seed=11)
    r, d = r.astype(np.float64), d.astype(np.float64)
    r[:, 100:116] = d[:, 100:116] = 20.0
    yy, xx = np.mgrid[0:60, 0:60]
    patch = 100 + 60 * np.sin(2 * np.pi * xx / 6) * np.sin(2 * np.pi * yy / 6)
    r[180:240, 20:80] = patch
    d[180:240, 21:81] = patch
    return r, d


def _without_prefetch(monkeypatch):
    monkeypatch.setattr(images_mod.Images, "prefetch", lambda self, key, compute, keep=True: None)


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_prefetched_work_gives_the_results_computed_in_place(monkeypatch, pair_with_bar,
                                                            method):
    seen = []
    real = Images.memo

    def memo(self, key, compute, keep=True):  # every job finished first: its value is used
        job = self.pending.get(key)
        if job is not None:
            job.result()
        seen.append((key[0], job is not None))
        return real(self, key, compute, keep)
    monkeypatch.setattr(Images, "memo", memo)
    ahead = correlate(*pair_with_bar, subset=31, step=8, method=method)
    used = {k for k, done in seen if done}
    # AL-DIC: the probe sums are used by the prefetched maps made of them
    expect = ({"peaks", "flat_var", "flat_var_g", "speckle"}
              | ({"probe maps"} if method == "aldic" else set()))
    assert expect <= used, seen
    _without_prefetch(monkeypatch)
    here = correlate(*pair_with_bar, subset=31, step=8, method=method)
    for name in ("u", "v", "dudx", "dvdy", "zncc", "reason", "iterations", "sssig", "mig"):
        assert np.array_equal(getattr(ahead, name), getattr(here, name), equal_nan=True), name
    # AL-DIC's propagated u_std varies by ~1e-16 from run to run
    for name in ("u_std", "v_std"):
        np.testing.assert_allclose(getattr(ahead, name), getattr(here, name), rtol=1e-12,
                                   atol=0, equal_nan=True)
    # the bar and the periodic patch flag nodes: the prefetched work was used
    assert np.isin(ahead.reason, [Reason.STATIC_FEATURE, Reason.AMBIGUOUS_MATCH]).any()


def test_a_started_job_not_done_in_time_is_computed_in_place():
    release = threading.Event()

    def slow():
        release.wait(10.0)
        return "from the background"
    im = Images(np.zeros((4, 4)), np.zeros((4, 4)), None, None, None)
    with ThreadPoolExecutor(1) as pool:
        im.background = pool
        im.prefetch(("k",), slow)
        t = time.perf_counter()
        value = im.memo(("k",), lambda: "computed here")
        waited = time.perf_counter() - t
        release.set()
    assert value == "computed here"
    assert images_mod.RUNNING_WAIT - 0.05 < waited < images_mod.RUNNING_WAIT + 0.5
    assert im.pending == {}


def test_a_running_job_that_ends_soon_is_waited_for_not_computed_twice():
    started = threading.Event()

    def soon():
        started.set()
        time.sleep(0.05)
        return "from the background"
    im = Images(np.zeros((4, 4)), np.zeros((4, 4)), None, None, None)
    calls = []
    with ThreadPoolExecutor(1) as pool:
        im.background = pool
        im.prefetch(("k",), soon)
        started.wait(5.0)
        value = im.memo(("k",), lambda: calls.append(1) or "computed here")
    assert value == "from the background" and not calls and im.pending == {}


def test_a_queued_job_is_computed_in_place_at_once():
    gate = threading.Event()
    im = Images(np.zeros((4, 4)), np.zeros((4, 4)), None, None, None)
    with ThreadPoolExecutor(1) as pool:
        im.background = pool
        pool.submit(gate.wait, 10.0)  # the thread is busy: the job waits
        im.prefetch(("k",), lambda: "from the background")
        t = time.perf_counter()
        value = im.memo(("k",), lambda: "computed here")
        waited = time.perf_counter() - t
        gate.set()
    assert value == "computed here" and waited < 0.1


def test_a_done_job_is_used_and_kept_for_the_next_pair():
    cache = {}
    im = Images(np.zeros((4, 4)), np.zeros((4, 4)), None, None, None, ref_cache=cache)
    calls = []
    with ThreadPoolExecutor(1) as pool:
        im.background = pool
        im.prefetch(("k",), lambda: calls.append(1) or 42)
        im.pending[("k",)].result()
        assert im.memo(("k",), lambda: calls.append(2) or -1) == 42
        im.prefetch(("k",), lambda: calls.append(3) or -1)  # kept: not started again
    assert calls == [1] and cache[("k",)] == 42 and im.pending == {}


def test_a_job_built_on_a_claimed_one_is_computed_in_place_not_raised():
    """The propagation's maps are a job built on the speckle job's future. On a
    loaded machine ``memo`` may claim the speckle job before it starts (computed
    in place, the job cancelled); the maps job then fails in the background.
    Its failure must not reach the analysis: the maps are computed in place."""
    gate = threading.Event()
    im = Images(np.zeros((4, 4)), np.zeros((4, 4)), None, None, None)
    with ThreadPoolExecutor(1) as pool:
        im.background = pool
        pool.submit(gate.wait, 10.0)  # the thread is busy: the jobs below wait
        im.prefetch(("speckle",), lambda: "q from the background")
        first = im.pending[("speckle",)]
        im.prefetch(("maps",), lambda: "maps of " + first.result())
        assert im.memo(("speckle",), lambda: "q here") == "q here"  # claimed, cancelled
        gate.set()
        done = im.pending[("maps",)]
        with pytest.raises(Exception):  # noqa: B017 - CancelledError from the claimed job
            done.result(10.0)
        assert im.memo(("maps",), lambda: "maps here") == "maps here"
    assert im.pending == {}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values: Linux")
def test_the_background_thread_runs_at_a_low_priority():
    from napari_aldic.engine.dic.correlate import _yielding

    def nice_of_this_thread():
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    with ThreadPoolExecutor(1, initializer=_yielding) as pool:
        background = pool.submit(nice_of_this_thread).result()
    here = nice_of_this_thread()
    assert background >= min(here + 15, 19)
    assert here == os.getpriority(os.PRIO_PROCESS, 0)  # this thread left as it was
