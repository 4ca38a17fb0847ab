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
"""Tests of the split of the compiled loops between threads (core.compiled.chunks)."""

from __future__ import annotations

import threading

import numpy as np
from pmba_ros.core.compiled import chunks
from pmba_ros.core.solve import solve, SolveOptions
import pytest

from .helpers import engine_named, forward_problem


def test_bounds_split_the_cost_evenly() -> None:
    """Ranges cover every item once, in order, and carry about equal cost."""
    rng = np.random.default_rng(0)
    cost = np.sort(rng.integers(1, 50, 1000)).astype(float) ** 2
    cut = chunks.bounds(cost, 4)
    assert cut[0] == 0 and cut[-1] == cost.shape[0] and np.all(np.diff(cut) >= 0)
    shares = np.add.reduceat(cost, cut[:-1]) / cost.sum()
    assert np.all(np.abs(shares - 0.25) < cost.max() / cost.sum() + 1e-12)
    np.testing.assert_array_equal(chunks.bounds(cost, 1), [0, 1000])
    np.testing.assert_array_equal(chunks.bounds(np.zeros(0), 3), [0, 0])


def test_cuts_form_the_costs_only_for_several_chunks() -> None:
    """One chunk takes every item without asking for the costs; several split them."""
    def no_cost() -> np.ndarray:
        raise AssertionError('costs formed for one chunk')

    np.testing.assert_array_equal(chunks.cuts(1, 7, no_cost), [0, 7])
    cost = np.arange(1.0, 11.0)
    np.testing.assert_array_equal(chunks.cuts(3, 10, lambda: cost), chunks.bounds(cost, 3))
    np.testing.assert_array_equal(chunks.cuts(4, 10), [0, 2, 5, 7, 10])


def test_bounds_leave_ranges_empty_when_one_item_carries_the_cost() -> None:
    """One heavy item: the other ranges may be empty, but the split stays a partition."""
    cut = chunks.bounds(np.array([1.0, 1e9, 1.0]), 3)
    assert cut[0] == 0 and cut[-1] == 3 and np.all(np.diff(cut) >= 0)


def test_run_keeps_chunk_order_and_uses_other_threads() -> None:
    """Results come back in chunk order; chunks after the first run off the calling thread."""
    seen: dict[int, int] = {}

    def work(t: int) -> int:
        seen[t] = threading.get_ident()
        return 10 * t

    assert chunks.run(work, 3) == [0, 10, 20]
    assert seen[0] == threading.get_ident()
    assert seen[1] != threading.get_ident() and seen[2] != threading.get_ident()


def test_errors_in_a_chunk_reach_the_caller() -> None:
    """An exception in a pool thread is raised by run, not lost."""
    def work(t: int) -> int:
        if t == 2:
            raise ValueError('chunk 2 failed')
        return t

    with pytest.raises(ValueError, match='chunk 2 failed'):
        chunks.run(work, 3)


def test_each_takes_every_item_once_costliest_first_and_ticks_on_the_caller() -> None:
    """Every item runs once; the calling thread's ticks count the items taken so far."""
    cost = np.array([3, 9, 1, 7, 5, 2, 8])
    ran: list[int] = []
    ticks: list[tuple[int, int, str]] = []
    lock = threading.Lock()

    def fn(i: int) -> None:
        with lock:
            ran.append(i)

    chunks.each(fn, cost, 2, lambda k, n: ticks.append((k, n, threading.current_thread().name)))
    assert sorted(ran) == list(range(7))
    assert ticks and {t[2] for t in ticks} == {threading.current_thread().name}
    assert all(t[1] == 7 for t in ticks)
    assert [t[0] for t in ticks] == sorted(t[0] for t in ticks)
    one: list[int] = []
    chunks.each(one.append, cost, 1)
    assert one == [1, 6, 3, 4, 0, 5, 2]   # costliest first


def test_a_tick_that_raises_stops_the_loop() -> None:
    """A tick's exception (a cancelled update) reaches the caller; the loop stops there."""
    ran: list[int] = []

    def stop(taken: int, total: int) -> None:
        if taken == 2:
            raise RuntimeError('cancelled')

    with pytest.raises(RuntimeError, match='cancelled'):
        chunks.each(ran.append, np.ones(10), 1, stop)
    assert len(ran) == 2


@pytest.mark.parametrize('bad', [0, -1, 1.5, True])
def test_thread_limit_must_be_a_positive_integer(bad: object) -> None:
    """set_max_threads names a wrong limit instead of running with it."""
    with pytest.raises(ValueError, match='positive integer'):
        chunks.set_max_threads(bad)  # type: ignore[arg-type]


def test_thread_limit_caps_the_threads(monkeypatch: pytest.MonkeyPatch) -> None:
    """The cap applies to large problems; small ones stay on one thread."""
    monkeypatch.setattr(chunks, 'available_cores', lambda: 8)
    try:
        chunks.set_max_threads(3)
        assert chunks.threads_for(10 * chunks.CHUNK_OBSERVATIONS) == 3
        assert chunks.threads_for(2 * chunks.CHUNK_OBSERVATIONS - 1) == 1
        chunks.set_max_threads(None)
        assert chunks.threads_for(10 * chunks.CHUNK_OBSERVATIONS) == 8
        # No chunk smaller than CHUNK_OBSERVATIONS.
        assert chunks.threads_for(5 * chunks.CHUNK_OBSERVATIONS) == 5
    finally:
        chunks.set_max_threads(None)


def test_a_solve_split_between_threads_ends_where_one_thread_does(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """PMBA-Dogleg with its loops in three chunks: the same iterations and result to rounding."""
    engine = engine_named('compiled')
    problem = forward_problem(3, n_cams=8, n_points=60)
    options = SolveOptions(engine=engine.name, max_iterations=10)
    one = solve(problem, options)
    monkeypatch.setattr(chunks, 'CHUNK_OBSERVATIONS', 1)
    monkeypatch.setattr(chunks, 'max_threads', lambda: 3)
    calls: list[int] = []
    run = chunks.run
    monkeypatch.setattr(chunks, 'run', lambda fn, n: calls.append(n) or run(fn, n))
    three = solve(problem, options)
    assert calls and set(calls) == {3}
    assert three.iterations == one.iterations
    assert three.final_cost == pytest.approx(one.final_cost, rel=1e-9)
    np.testing.assert_allclose(three.centers_w, one.centers_w, atol=1e-7)


def test_private_copies_stay_within_their_memory_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    """Many cores and large pose blocks: fewer chunks, so that the copies fit the budget."""
    monkeypatch.setattr(chunks, 'available_cores', lambda: 64)
    big = chunks.COPY_BUDGET_BYTES // 4
    many = 100 * chunks.CHUNK_OBSERVATIONS
    n = chunks.threads_for(many, big)
    assert n == 5 and (n - 1) * big <= chunks.COPY_BUDGET_BYTES
    assert chunks.threads_for(many, 2 * chunks.COPY_BUDGET_BYTES) == 1
    assert chunks.threads_for(many) == 64
