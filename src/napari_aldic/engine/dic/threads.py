"""Serial Numba kernels run side by side on Python threads.

A kernel whose outer loop is a ``prange`` costs Numba's parallel passes on
its first compilation: 1.5-3.5 s each of the engine's kernels (issue 25, the
first run). The node-parallel kernels are serial instead, take a range
``first, stop`` of their items (nodes, or chunks of nodes) and release the
GIL; :func:`in_threads` splits the items between ``numba.get_num_threads()``
threads (the run's ``n_threads``). The kernels write disjoint items, so the
results do not depend on the split.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

__all__ = ["in_threads", "side_by_side", "beside", "TASKS_PER_THREAD"]

#: ranges of items per thread (several: a range of slow items, e.g. nodes that
#: hit the iteration cap, does not hold the others up)
TASKS_PER_THREAD = 4


def side_by_side(fn, items, workers: int | None = None) -> list:
    """``[fn(item) for item in items]``, the calls on ``workers`` threads
    (default ``numba.get_num_threads()``; ``fn`` releases the GIL for this to
    pay: a serial kernel, SuperLU, scipy's filters). ``items`` is read on this
    thread as the calls run, so a generator may make the next item meanwhile.
    With one worker (or one item) the calls run here, in order."""
    workers = numba.get_num_threads() if workers is None else workers
    if hasattr(items, "__len__"):
        workers = min(workers, len(items))
    if workers <= 1:
        return [fn(item) for item in items]
    with ThreadPoolExecutor(workers) as pool:
        jobs = [pool.submit(fn, item) for item in items]
        return [job.result() for job in jobs]


def in_threads(kernel, items: int, *args, grain: int = 1) -> None:
    """``kernel(first, stop, *args)`` over ``items`` items, in ranges of at
    least ``grain`` items side by side on ``numba.get_num_threads()``
    threads (one call on this thread when that is a single range)."""
    tasks = min(TASKS_PER_THREAD * numba.get_num_threads(), items // max(grain, 1))
    if tasks <= 1:
        kernel(0, items, *args)
        return
    edges = np.linspace(0, items, tasks + 1).astype(np.int64)
    side_by_side(lambda ab: kernel(int(ab[0]), int(ab[1]), *args), zip(edges[:-1], edges[1:]),
                 min(numba.get_num_threads(), tasks))


def beside(first, second) -> tuple:
    """``(first(), second())``: ``first`` on a thread of its own while this
    thread runs ``second``, with this thread's ``numba.get_num_threads()`` (the
    run's; a new thread would see Numba's default). When ``second`` raises,
    ``first`` is still waited for (it must not wait on ``second`` then)."""
    threads = numba.get_num_threads()

    def run():
        numba.set_num_threads(threads)
        return first()
    with ThreadPoolExecutor(1) as aside:
        job = aside.submit(run)
        other = second()
    return job.result(), other
