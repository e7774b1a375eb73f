"""Serial kernels run side by side on threads (``dic.threads``): every item
exactly once, results in order, and an analysis that does not depend on the
thread count."""

import numba
import numpy as np
import pytest

from napari_aldic.engine import correlate, synthetic
from napari_aldic.engine.dic import threads


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
@pytest.mark.parametrize("items,grain", [(0, 1), (1, 1), (7, 1), (97, 1), (1000, 64),
                                         (130, 64)])
def test_in_threads_covers_every_item_once(monkeypatch, workers, items, grain):
    monkeypatch.setattr(numba, "get_num_threads", lambda: workers)
    seen = np.zeros(items, int)
    ranges = []

    def kernel(first, stop, out):
        ranges.append((first, stop))
        out[first:stop] += 1

    threads.in_threads(kernel, items, seen, grain=grain)
    assert np.all(seen == 1)
    # no more ranges than the threads are given, none smaller than the grain
    # unless there is only one
    assert len(ranges) <= max(1, threads.TASKS_PER_THREAD * workers)
    if len(ranges) > 1:
        assert min(b - a for a, b in ranges) >= grain


def test_side_by_side_keeps_order_and_reads_a_generator(monkeypatch):
    monkeypatch.setattr(numba, "get_num_threads", lambda: 3)
    drawn = []

    def items():
        for i in range(10):
            drawn.append(i)
            yield i

    assert threads.side_by_side(lambda i: i * i, items()) == [i * i for i in range(10)]
    assert drawn == list(range(10))
    assert threads.side_by_side(lambda i: -i, [5], workers=4) == [-5]


@pytest.mark.parametrize("method", ["local", "aldic"])
def test_results_do_not_depend_on_the_thread_count(method, monkeypatch):
    """One thread and two give the same bits: the kernels write disjoint
    nodes, the probe moments and factor columns are split, never summed
    across threads. So do the smoothing choice's trial smoothers and the
    u_std propagation's probe groups when they see five threads (both
    scale with the run's threads, at least two)."""
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("Numba has a single thread here (NUMBA_NUM_THREADS=1)")
    f = synthetic.Affine.strain_rotation(exx=0.003, angle_deg=0.3, center=(128, 128),
                                         t=(0.7, -0.4))
    ref, dfm = synthetic.speckle_pair((256, 256), f, noise=2.0, seed=3)
    one = correlate(ref, dfm, subset=21, step=6, method=method, n_threads=1)
    two = correlate(ref, dfm, subset=21, step=6, method=method, n_threads=2)
    assert one.valid.sum() > 0.9 * one.valid.size
    for name in ("u", "v", "u_std", "v_std", "zncc"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name), err_msg=name)
    np.testing.assert_array_equal(one.reason, two.reason)
    if method == "aldic":
        from types import SimpleNamespace

        import napari_aldic.engine.dic.regularise as R
        import napari_aldic.engine.dic.uncertainty_aldic as UA

        groups = []
        real = UA.side_by_side

        def spy(fn, items, workers=None):
            if "_propagate" in fn.__code__.co_names:  # the propagation's groups
                groups.append(len(items))
            return real(fn, items, workers)
        five = SimpleNamespace(get_num_threads=lambda: 5)
        monkeypatch.setattr(R, "numba", five)
        monkeypatch.setattr(UA, "numba", five)
        monkeypatch.setattr(UA, "side_by_side", spy)
        more = correlate(ref, dfm, subset=21, step=6, method=method, n_threads=2)
        assert groups == [5]  # the 16 probes in five groups
        for name in ("u", "v", "u_std", "v_std", "zncc"):
            np.testing.assert_array_equal(getattr(more, name), getattr(two, name), err_msg=name)
