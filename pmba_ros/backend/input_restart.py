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
"""Input whose time started again: a recording played in a loop, a replayed front-end.

``ros2 bag play --loop`` publishes the recording again with its original stamps, and a
front-end re-run over a dataset does the same: every keyframe after the restart is older than
the last one processed. They were all rejected as out of order, and the back-end showed WARN
for the rest of the run with its first pass frozen. A late or reordered message is one or two
messages out of order; a restart is a stretch of them, in order among themselves, with nothing
newer in between. After :attr:`InputRestarts.RUN` such keyframe poses (or tracks messages) in
a row, the back-end starts over (as ``~/reset``) and takes the stretch as the new run's start.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class _Stream:
    run: int = 0          # messages in a row older than the back-end's, in order among themselves
    run_last_ns: int = 0  # the newest of them


@dataclass
class InputRestarts:
    """Watches the keyframe-pose and tracks streams for a restart of their stamps.

    Every message is shown to :meth:`see` before the back-end judges it (it still is: one
    message out of order is rejected and counted as before). The messages of a stretch that
    may be a restart are kept, in arrival order, to be taken again once it is one. Old is
    judged against the newest stamp the back-end took on the same stream, not the newest
    seen: a message stamped far ahead by a clock glitch is dropped, and those after it are
    not a restart; and the streams' delays differ (VINS publishes a keyframe's pose about a
    second after its tracks).
    """

    RUN = 5
    """Keyframe poses or tracks messages older than their stream's newest taken, in order
    among themselves and with none newer in between, that make a restart."""
    max_kept: int = 1000
    """Messages kept while a stretch may be a restart (the oldest go first)."""
    _streams: dict[str, _Stream] = field(default_factory=dict, init=False, repr=False)
    _kept: list[tuple[str, Any]] = field(default_factory=list, init=False, repr=False)

    def see(self, stream: str, stamp_ns: int | None, taken_ns: int, msg: Any) -> bool:
        """Note a message of ``stream``; True if the input restarted.

        Args:
            stream: 'keyframes' or 'tracks'.
            stamp_ns: Its stamp (None: not judged).
            taken_ns: The newest stamp the back-end took on that stream: the message is old
                at or before it.
            msg: The message, kept while a stretch may be a restart.

        Returns:
            True when the stretch is a restart: the caller starts over and takes
            :meth:`stretch` (this message last).
        """
        if stamp_ns is None:
            return False
        s = self._streams.setdefault(stream, _Stream())
        if stamp_ns > taken_ns:
            s.run = 0
            if any(other.run for other in self._streams.values()):
                self._keep(stream, msg)   # past the old run already: the new run's
            else:
                self._kept.clear()
            return False
        if s.run and stamp_ns <= s.run_last_ns:   # not in order with the stretch: a new one
            s.run = 0
            self._kept = [(name, m) for name, m in self._kept if name != stream]
        s.run += 1
        s.run_last_ns = stamp_ns
        self._keep(stream, msg)
        return s.run >= self.RUN

    def _keep(self, stream: str, msg: Any) -> None:
        """Keep a message of the stretch; past ``max_kept`` the oldest goes."""
        self._kept.append((stream, msg))
        if len(self._kept) > self.max_kept:
            self._kept.pop(0)

    def stretch(self) -> list[tuple[str, Any]]:
        """Return the messages kept since the restart began, in arrival order, and forget all."""
        kept = self._kept
        self._kept = []
        self._streams.clear()
        return kept
