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
"""Playback pacing (``pmba play``) against a fake clock."""

from __future__ import annotations

from pmba_ros.io.playback import paced, Tick, wait_until


class FakeClock:
    """A monotonic clock that advances only when slept on."""

    def __init__(self) -> None:
        """Start at 100 s."""
        self.now = 100.0
        self.sleeps: list[float] = []

    def monotonic(self) -> float:
        """Return the current time."""
        return self.now

    def sleep(self, seconds: float) -> None:
        """Advance the time."""
        self.sleeps.append(seconds)
        self.now += seconds


MESSAGES = [('/a', 5_000_000_000, b'1'), ('/b', 5_500_000_000, b'2'), ('/a', 6_000_000_000, b'3')]


def test_messages_are_due_at_their_recorded_spacing_over_the_rate() -> None:
    """At rate 2 the messages half a second apart come out a quarter second apart."""
    clock = FakeClock()
    due = []
    for tick in paced(MESSAGES, 2.0, monotonic=clock.monotonic, sleep=clock.sleep):
        due.append((round(clock.now - 100.0, 9), tick))
    assert due == [(0.0, Tick(5_000_000_000, '/a', b'1')), (0.25, Tick(5_500_000_000, '/b', b'2')),
                   (0.5, Tick(6_000_000_000, '/a', b'3'))]


def test_a_recording_played_again_is_paced_again() -> None:
    """``pmba play --loop``: the second pass starts at once and keeps its spacing.

    Before, its first message was due at once and so was every other (all in the past).
    """
    clock = FakeClock()
    due = [round(clock.now - 100.0, 9) for _ in paced(
        MESSAGES + MESSAGES, 1.0, monotonic=clock.monotonic, sleep=clock.sleep)]
    assert due == [0.0, 0.5, 1.0, 1.0, 1.5, 2.0]


def test_clock_ticks_fill_the_waits_in_bag_time_and_never_pass_the_next_message() -> None:
    """With a clock period, ticks without a message carry bag time up to the next message."""
    clock = FakeClock()
    ticks = list(paced(MESSAGES[:2], 1.0, clock_period_s=0.2, monotonic=clock.monotonic,
                       sleep=clock.sleep))
    assert [t.topic for t in ticks] == ['/a', None, None, None, '/b']
    stamps = [t.stamp_ns for t in ticks]
    assert stamps == sorted(stamps)
    assert stamps[1:4] == [5_000_000_000, 5_200_000_000, 5_400_000_000]
    assert max(clock.sleeps) <= 0.2


def test_wait_until_stops_when_ready_and_then_settles() -> None:
    """The wait ends once the condition holds, then sleeps the settle time."""
    clock = FakeClock()
    assert wait_until(lambda: clock.now >= 100.1, 5.0, settle_s=2.0, monotonic=clock.monotonic,
                      sleep=clock.sleep)
    assert clock.sleeps[-1] == 2.0
    assert 100.1 <= clock.now - 2.0 < 100.13


def test_wait_until_gives_up_at_the_timeout() -> None:
    """A condition that never holds returns False after the timeout."""
    clock = FakeClock()
    assert not wait_until(lambda: False, 1.0, monotonic=clock.monotonic, sleep=clock.sleep)
    assert 101.0 <= clock.now < 101.03
