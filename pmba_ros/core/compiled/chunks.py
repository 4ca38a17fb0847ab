# Copyright 2026 pmba_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""The compiled loops on several cores: features split into chunks, one thread per chunk.

The loops release the GIL (:func:`pmba_ros.core.jit.jit`), so plain threads run them side by
side. A chunk is a contiguous range of features (observations are stored feature by
feature) with about an equal share of the work. Where features add into blocks they share
(the pose blocks of J^T J and of the Schur complement), each chunk adds into its own copy and
the copies are summed in chunk order afterwards: the result does not depend on which thread
finishes first, only on the number of chunks.

Large problems use every core this process may run on (:func:`max_threads`), as a BLAS
library would; :func:`set_max_threads` (``pmba solve --threads``) caps that.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
import itertools
import threading
from typing import TypeVar

import numpy as np
from pmba_ros._threads import available_cores
from pmba_ros._typing import FloatArray, IntArray

T = TypeVar('T')

CHUNK_OBSERVATIONS = 10_000
"""The fewest observations a chunk gets: a problem needs twice as many for two threads. A
sliding window (a few thousand observations) stays on one thread: its loops take a few
milliseconds, and handing half to another thread and summing its copy of the pose blocks
would save too little of that."""


class _State:
    """The thread limit and the worker pool, shared by every solve of the process."""

    limit: int | None = None
    pool: ThreadPoolExecutor | None = None
    pool_size = 0
    lock = threading.Lock()


def set_max_threads(n: int | None) -> None:
    """Cap the threads of the compiled loops at ``n`` (None: every available core).

    Raises:
        ValueError: If ``n`` is not a positive integer or None.
    """
    if n is not None and (not isinstance(n, int) or isinstance(n, bool) or n < 1):
        msg = f'the thread limit must be a positive integer or None, got {n!r}'
        raise ValueError(msg)
    _State.limit = n


def max_threads() -> int:
    """Return the most threads a large problem's loops use."""
    cores = available_cores()
    return cores if _State.limit is None else min(cores, _State.limit)


#: Memory the chunks' private copies of the pose blocks may take together: on a machine with
#: many cores and a problem with many covisible pose pairs, fewer chunks.
COPY_BUDGET_BYTES = 1 << 30


def threads_for(n_obs: int, copy_bytes: int = 0) -> int:
    """Return the threads worth using on loops over ``n_obs`` observations.

    ``copy_bytes`` is the size of the private copy each chunk after the first needs.
    """
    if n_obs < 2 * CHUNK_OBSERVATIONS:
        return 1    # a sliding window's case: no need to ask for the cores
    return max(1, min(max_threads(), n_obs // CHUNK_OBSERVATIONS,
                      1 + COPY_BUDGET_BYTES // max(copy_bytes, 1)))


def bounds(cost: FloatArray, n: int) -> IntArray:
    """Return n + 1 indices that split items of ``cost`` (per item) into n equal-cost ranges.

    Ranges may be empty when a few items carry most of the cost.
    """
    total = np.cumsum(cost, dtype=float)
    if n <= 1 or total.shape[0] == 0:
        return np.array([0, total.shape[0]], dtype=np.int64)
    inner = np.searchsorted(total, total[-1] * np.arange(1, n) / n, side='right')
    return np.concatenate([[0], inner, [total.shape[0]]]).astype(np.int64)


def cuts(n: int, size: int, cost: Callable[[], FloatArray] | None = None) -> IntArray:
    """Return n + 1 bounds of chunks of ``size`` items: :func:`bounds` of ``cost()``.

    ``cost`` None: equal numbers of items. With one chunk the costs are not formed.
    """
    if n <= 1:
        return np.array([0, size], dtype=np.int64)
    if cost is None:
        return np.linspace(0, size, n + 1).astype(np.int64)
    return bounds(cost(), n)


def run(fn: Callable[[int], T], n: int) -> list[T]:
    """Return [fn(0), ..., fn(n - 1)], chunk 0 on the calling thread, the others in the pool."""
    if n <= 1:
        return [fn(0)]
    with _State.lock:
        if _State.pool is None or _State.pool_size < n - 1:
            if _State.pool is not None:
                _State.pool.shutdown(wait=False)
            _State.pool = ThreadPoolExecutor(max_workers=n - 1,
                                             thread_name_prefix='pmba-loops')
            _State.pool_size = n - 1
        pool = _State.pool
    futures = [pool.submit(fn, t) for t in range(1, n)]
    first = fn(0)
    return [first, *(f.result() for f in futures)]


def each(fn: Callable[[int], None], cost: IntArray, n_threads: int,
         tick: Callable[[int, int], None] | None = None) -> None:
    """Call ``fn(i)`` for every item i of ``cost`` (its cost), on ``n_threads`` threads.

    Threads take the next item as they finish one (the count's next() is atomic under the
    GIL), costliest first: a fixed split leaves a core idle when the other is slowed down,
    and the cost given is only an estimate. ``fn`` must write item i's result to its own
    place, so that the results do not depend on which thread ran it. ``tick(taken, total)``
    is called on the calling thread after each of its items (the items taken so far by all
    threads); an exception it raises (a cancelled update) is raised here, and the other
    threads stop after the item they are on.
    """
    queue = np.argsort(-np.asarray(cost), kind='stable')
    taken = itertools.count()
    total = int(queue.shape[0])
    stop = threading.Event()

    def work(thread: int) -> None:
        while not stop.is_set() and (i := next(taken)) < total:
            fn(int(queue[i]))
            if tick is not None and thread == 0:
                try:
                    tick(i + 1, total)
                except BaseException:
                    stop.set()
                    raise

    run(work, n_threads)
