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

__all__ = ["in_threads", "TASKS_PER_THREAD"]

#: ranges of items per thread (several: a range of slow items, e.g. nodes that
#: hit the iteration cap, does not hold the others up)
TASKS_PER_THREAD = 4


def in_threads(kernel, items: int, *args, grain: int = 1) -> None:
    """``kernel(first, stop, *args)`` over ``items`` items, in ranges of at
    least ``grain`` items side by side on ``numba.get_num_threads()``
    threads (one call on this thread when that is a single range)."""
    tasks = min(TASKS_PER_THREAD * numba.get_num_threads(), items // max(grain, 1))
    if tasks <= 1:
        kernel(0, items, *args)
        return
    edges = np.linspace(0, items, tasks + 1).astype(np.int64)
    with ThreadPoolExecutor(min(numba.get_num_threads(), tasks)) as pool:
        jobs = [pool.submit(kernel, int(a), int(b), *args)
                for a, b in zip(edges[:-1], edges[1:])]
        for job in jobs:
            job.result()
