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
"""Recorded messages paced at their recorded timing (``pmba play``), without ROS."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
import time

CLOCK_PERIOD_S = 0.025
"""Period of ``/clock`` between messages when ``pmba play --clock``."""

MATCH_SETTLE_S = 2.0
"""Seconds from a publisher seeing its subscribers to the first message of ``pmba play``: the
reader matches the writer later (no API shows when) and, volatile, drops what comes before;
generous, as discovery is slow on a loaded machine."""

ACK_TIMEOUT_S = 10.0
"""Seconds ``pmba play`` waits, after its last message, for every reliable subscriber to
acknowledge what it was sent: a writer that goes away first cannot resend a lost sample."""


@dataclass(frozen=True)
class Tick:
    """One step of a playback.

    Attributes:
        stamp_ns: Bag time now, ns (for ``/clock``).
        topic: Topic of the message due now; None for a clock tick between messages.
        raw: The message (CDR bytes); None for a clock tick.
    """

    stamp_ns: int
    topic: str | None = None
    raw: bytes | None = None


def paced(messages: Iterable[tuple[str, int, bytes]], rate: float = 1.0, *,
          clock_period_s: float | None = None,
          monotonic: Callable[[], float] = time.monotonic,
          sleep: Callable[[float], None] = time.sleep) -> Iterator[Tick]:
    """Yield the messages at their recorded spacing divided by ``rate``.

    The first message is due at once; each later one when its log time, less the first's,
    divided by ``rate``, has passed. A message logged before its predecessor starts the
    timing over (a recording played again, ``pmba play --loop``): it is due at once.

    Args:
        messages: ``(topic, log_time_ns, CDR bytes)`` in log-time order.
        rate: Playback speed factor (2.0: twice as fast).
        clock_period_s: Also yield clock ticks (no message) at this period while waiting.
        monotonic: The clock to pace by (tests pass a fake one).
        sleep: Waits (tests pass a fake one).

    Yields:
        A :class:`Tick` per message when it is due, and clock ticks in between (bag time,
        never past the next message's).
    """
    start: tuple[float, int] | None = None
    last_ns = 0
    for topic, t_ns, raw in messages:
        if start is None or t_ns < last_ns:
            start = (monotonic(), t_ns)
        last_ns = t_ns
        target = start[0] + (t_ns - start[1]) * 1e-9 / rate
        while (wait := target - monotonic()) > 0:
            if clock_period_s is not None:
                bag_ns = start[1] + round((monotonic() - start[0]) * rate * 1e9)
                yield Tick(min(bag_ns, t_ns))
            sleep(min(wait, clock_period_s) if clock_period_s is not None else wait)
        yield Tick(t_ns, topic, raw)


def wait_until(ready: Callable[[], bool], timeout_s: float, *, settle_s: float = 0.0,
               poll_s: float = 0.02, monotonic: Callable[[], float] = time.monotonic,
               sleep: Callable[[float], None] = time.sleep) -> bool:
    """Wait until ``ready()`` or ``timeout_s`` has passed, then ``settle_s`` more.

    Returns:
        Whether ``ready()`` held.
    """
    deadline = monotonic() + timeout_s
    while not (ok := ready()) and monotonic() < deadline:
        sleep(poll_s)
    sleep(settle_s)
    return ok


__all__ = ['Tick', 'paced', 'wait_until']
