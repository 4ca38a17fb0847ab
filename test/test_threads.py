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
"""BLAS thread pools: one thread after start-up, more only for large factorizations."""

from __future__ import annotations

from pmba_ros import _threads
import pytest

from .conftest import run_python

pytest.importorskip('threadpoolctl')


def test_start_up_limits_numpy_and_scipy_blas_to_one_thread() -> None:
    """Every BLAS pool (numpy's and scipy's OpenBLAS) runs one thread after the call."""
    run_python(
        'from threadpoolctl import threadpool_info, threadpool_limits\n'
        'import numpy, scipy.linalg\n'
        'threadpool_limits(limits=2, user_api="blas")\n'
        'from pmba_ros._process import tune_process\n'
        'tune_process()\n'
        'pools = [p for p in threadpool_info() if p["user_api"] == "blas"]\n'
        'assert pools, "no BLAS pool found"\n'
        'assert all(p["num_threads"] == 1 for p in pools), pools\n'
        'import importlib.util\n'
        'if importlib.util.find_spec("cv2"):  # loads its own OpenBLAS after the call\n'
        '    import cv2\n'
        '    pools = [p for p in threadpool_info() if p["user_api"] == "blas"]\n'
        '    assert all(p["num_threads"] == 1 for p in pools), pools\n')


def test_large_factorization_borrows_idle_cores_and_gives_them_back() -> None:
    """Inside blas_threads_for(large) the pools grow to the idle cores, then return to one."""
    run_python(
        'import os\n'
        'from threadpoolctl import threadpool_info\n'
        'from pmba_ros import _threads\n'
        'assert _threads.limit_blas_threads()\n'
        '_threads._POOLS.cores = 2\n'
        'os.getloadavg = lambda: (0.5, 0.5, 0.5)\n'
        'def counts():\n'
        '    return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}\n'
        'with _threads.blas_threads_for(_threads.PARALLEL_MIN_DIM - 1):\n'
        '    assert counts() == {1}, counts()\n'
        'with _threads.blas_threads_for(_threads.PARALLEL_MIN_DIM):\n'
        '    assert counts() == {2}, counts()\n'
        'assert counts() == {1}, counts()\n')


@pytest.mark.parametrize(('cores', 'load', 'dim', 'expected'), [
    (2, 0.3, 5000, 2),      # idle machine, large system: both cores
    (2, 1.2, 5000, 1),      # another process busy: only our own thread
    (8, 3.0, 5000, 6),      # three busy cores of eight
    (8, 0.0, 5000, 8),      # never more than the cores
    (8, 0.0, 300, 1),       # a window's system: one thread whatever the load
    (1, 0.0, 5000, 1),
])
def test_threads_for_counts_idle_cores_on_large_systems(
        monkeypatch: pytest.MonkeyPatch, cores: int, load: float, dim: int,
        expected: int) -> None:
    """The thread count is the idle cores (load average) for large systems, else one."""
    monkeypatch.setattr(_threads._POOLS, 'cores', cores)
    monkeypatch.setattr(_threads.os, 'getloadavg', lambda: (load, load, load))
    assert _threads.threads_for(dim) == expected


def test_library_use_leaves_the_pools_alone() -> None:
    """Without the start-up call, a large factorization does not touch the user's setting."""
    run_python(
        'from threadpoolctl import threadpool_info, threadpool_limits\n'
        'import numpy, scipy.linalg\n'
        'from pmba_ros import _threads\n'
        'threadpool_limits(limits=1, user_api="blas")\n'
        '_threads._POOLS.cores = 2\n'
        'with _threads.blas_threads_for(100_000):\n'
        '    counts = {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}\n'
        'assert counts == {1}, counts\n')
