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
"""A relaunched front-end's feature ids, kept apart from those of its previous run.

Front-ends (VINS-Mono/Fusion, OpenVINS) number their features upwards from 0, and a relaunch
starts at 0 again. Without a ``~/reset`` the new run's ids 0, 1, ... joined the old run's
tracks of the same ids still in the window: their landmarks got observations of other points,
every window solve exploded and was rolled back, and the new segment ended about 3x worse in
ATE than with distinct ids.
"""

from __future__ import annotations

from dataclasses import replace
import logging

import numpy as np
from pmba_ros.backend.types import TrackFrame

logger = logging.getLogger(__name__)


class FeatureIdRestarts:
    """Shifts the ids of a front-end whose id counter started again past every id seen.

    A front-end numbering upwards gives a message the ids of its continued tracks (those of
    the previous message) and new ids above all earlier ones. A message of which more than
    half the ids are neither is a restarted counter (a few old tracks may still carry ids of
    the new run's range): from it on, ids are shifted past the largest id handed out so far.
    """

    def __init__(self) -> None:
        """Start without a previous message and without a shift."""
        self._previous: np.ndarray | None = None   # the previous message's raw ids, sorted
        self._offset = 0
        self._next_free = 0   # one past the largest shifted id handed out

    def shift(self, frame: TrackFrame) -> tuple[TrackFrame, bool]:
        """Return ``frame`` with its ids shifted, and whether it starts a restarted count."""
        ids = np.unique(frame.feature_ids)
        if not ids.size:   # an empty message says nothing about the counter
            return frame, False
        prev = self._previous
        restarted = False
        if prev is not None and prev.size:
            at = np.minimum(np.searchsorted(prev, ids), prev.size - 1)
            fresh = (prev[at] != ids) & (ids < prev[-1])
            restarted = 2 * int(fresh.sum()) > ids.size
        if restarted:
            self._offset = self._next_free
            logger.warning('feature ids start again at %d (most below the previous '
                           "message's, not in it): a relaunched front-end? its ids are taken as "
                           'new features, shifted by %d', int(ids[0]), self._offset)
        self._previous = ids
        self._next_free = max(self._next_free, int(ids[-1]) + self._offset + 1)
        if not self._offset:
            return frame, restarted
        return replace(frame, feature_ids=frame.feature_ids + self._offset), restarted


__all__ = ['FeatureIdRestarts']
