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
"""BLAS thread pools, sized by the programs (``pmba``, ``pmba_node``, the benchmarks).

Most of a solve's linear algebra is small: 3x3 feature blocks, 6x6 pose blocks, a reduced
camera system of a few hundred columns. OpenBLAS wakes its whole pool for such products, and
its threads spin against the solver's own thread (and, on a shared machine, against other
processes), so a multi-threaded pool makes small solves several times slower. A program calls
:func:`limit_blas_threads` once at start-up: BLAS then runs on one thread, and only the
factorization of a large reduced camera system (:func:`blas_threads_for`) borrows the cores
that are idle at that moment. Importing the library changes nothing: without the start-up
call, :func:`blas_threads_for` leaves the pools as the user set them.
"""

from __future__ import annotations

from collections.abc import Iterator
import contextlib
from dataclasses import dataclass
import logging
import os
from typing import Any

logger = logging.getLogger(__name__)

#: Columns of a dense factorization from which more than one BLAS thread pays: below it,
#: waking the pool costs more than the split saves.
PARALLEL_MIN_DIM = 1200


@dataclass
class _Pools:
    """The process's BLAS pools once :func:`limit_blas_threads` took them over."""

    controller: Any = None
    cores: int = 1


_POOLS = _Pools()


def available_cores() -> int:
    """Return the number of cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def limit_blas_threads() -> bool:
    """Run BLAS on one thread from now on; return whether it was applied.

    Loads scipy.linalg first, so that its own OpenBLAS copy is among the pools; libraries
    loaded later get one thread through ``OPENBLAS_NUM_THREADS`` unless the user set it.
    """
    try:
        import scipy.linalg  # noqa: F401  (its BLAS must be loaded to be limited)
        from threadpoolctl import ThreadpoolController
    except ImportError:
        logger.debug('threadpoolctl is not installed: BLAS thread pools left as they are')
        return False
    # Pools loaded later (OpenCV bundles its own OpenBLAS) read the variable when they load.
    os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
    controller = ThreadpoolController()
    controller.limit(limits=1, user_api='blas')
    _POOLS.controller = controller
    _POOLS.cores = available_cores()
    return True


def threads_for(dim: int) -> int:
    """Return the BLAS threads worth using on a dense factorization of ``dim`` columns.

    One below :data:`PARALLEL_MIN_DIM`; above it, the cores not busy with other work (the
    one-minute load average, this process's own thread counted as idle).
    """
    if dim < PARALLEL_MIN_DIM or _POOLS.cores < 2:
        return 1
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float(_POOLS.cores)
    return max(1, min(_POOLS.cores, int(_POOLS.cores - load + 1.0)))


@contextlib.contextmanager
def blas_threads_for(dim: int) -> Iterator[None]:
    """Let BLAS use :func:`threads_for` ``(dim)`` threads inside the block.

    Does nothing unless :func:`limit_blas_threads` took the pools over (a library user's
    settings are left alone) or when one thread is the answer.
    """
    controller = _POOLS.controller
    n_threads = threads_for(dim) if controller is not None else 1
    if n_threads == 1:
        yield
        return
    with controller.limit(limits=n_threads, user_api='blas'):
        yield
