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
"""A rig's map takes its scale from the rig, not from the initialization.

The initialization is monocular and puts the map at the front-end's scale of the time; a
sliding window holds the older map fixed, and with it that scale: a rig whose baseline
hardly sees the scene's depth cannot move it window by window. A solve's scale tension (the
slope and curvature of its cost along a scaling of the whole problem, fixed keyframes too:
:func:`~pmba_ros.core.gauge.scale_tension`) gives the step the window's metric measurements,
the rig's and the front-end's steps, ask of the map's scale.

The steps are weighed as measurements of one constant, the map's scale error (a scalar
Kalman filter without process noise): it starts as uncertain as a front-end's scale
(``motion_prior_translation_rel``), a solve's step counts with the variance
``window_size / curvature``, and no solve takes more than ``1 / window_size`` of its step,
as a keyframe's measurements are in about ``window_size`` solves (the curvature is the
scale's information with the rest of the window held, more than it has with the rest free,
and the first solves after an initialization are far from converged). Early on a pull that
persists moves the scale all the way; later solves, each weighed less, cannot walk the
older map away with the window's local scale (a share that stayed constant summed every
later window's local pull into the first keyframes, and a long run's older map drifted off
its scale with them).
"""

from __future__ import annotations

import math

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.motion import RunScale
from pmba_ros.backend.window import FeatureMap, KeyframeStore, LandmarkStore

RESCALE_MIN = 1e-3
"""The map is rescaled once the pending steps add up to this (a tenth of a percent): every
rescaling moves each published pose, and the path is rebuilt whole."""

GATE_SIGMAS = 3.0
"""A solve's step beyond this many sigmas of what the filter expects (the scale's variance
plus the step's) measures something else than the map's scale, and is left out: a window
at rest turning on the spot sees its new features placed by the rig's baseline alone, and
its tension asks for steps of tens of percent, which the bound per solve would let
through a little at a time, stretching the whole map."""


class RigScale:
    """The map's scale error as a scalar Kalman filter (gains at most 1 / window_size).

    Steps wait until they add up to :data:`RESCALE_MIN`.

    Args:
        config: ``motion_prior_translation_rel`` (the first variance, 5 % if 0),
            ``window_size`` and ``fallback_max_scale_jump`` (the most a solve moves the
            scale is its share of that).
    """

    def __init__(self, config: BackendConfig) -> None:
        """Start as uncertain as a front-end's scale, with nothing pending."""
        rel = config.motion_prior_translation_rel
        self.variance = (rel if rel > 0 else 0.05) ** 2
        self.pending = 0.0
        self._window = config.window_size
        self._bound = config.fallback_max_scale_jump / config.window_size

    def take(self, slope: float, curvature: float) -> tuple[float | None, int]:
        """Weigh in one solve's scale step; return the factor to rescale by now, if any.

        ``slope``, ``curvature``: the solve's ``scale_tension``; NaN, or a curvature that is
        not positive (no metric measurement in the window), adds nothing. Also returns 1
        for a step left out beyond :data:`GATE_SIGMAS` (else 0).
        """
        if not (math.isfinite(slope) and math.isfinite(curvature) and curvature > 0):
            return None, 0
        noise = self._window / curvature
        if (slope / curvature) ** 2 > GATE_SIGMAS ** 2 * (self.variance + noise):
            return None, 1
        gain = min(self.variance / (self.variance + noise), 1.0 / self._window)
        self.variance = (1.0 - gain) ** 2 * self.variance + gain ** 2 * noise
        step = float(np.clip(-gain * slope / curvature, -self._bound, self._bound))
        self.pending += step
        if abs(self.pending) < RESCALE_MIN:
            return None, 0
        factor, self.pending = 1.0 + self.pending, 0.0
        return factor, 0


def rescale_map(kf: KeyframeStore, features: FeatureMap, landmarks: LandmarkStore,
                run: RunScale, factor: float) -> None:
    """Scale every map position by ``factor`` about the newest keyframe, which stays."""
    n = kf.n
    center = kf.C_map[n - 1].copy()
    kf.C_map[:n] = center + factor * (kf.C_map[:n] - center)
    features.scale_about(center, factor)
    landmarks.scale_about(center, factor)
    run.rescale(factor)
