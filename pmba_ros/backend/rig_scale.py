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
the rig's and the front-end's steps, ask of the map's scale. A keyframe stays in about
``window_size`` solves, so each solve takes ``1 / window_size`` of its step, bounded by its
share of ``fallback_max_scale_jump``: the measurements count about once, and a pull that
persists moves the scale all the way.
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


class RigScale:
    """The solves' scale steps not yet applied to the map."""

    def __init__(self) -> None:
        """Start with nothing pending."""
        self.pending = 0.0

    def take(self, slope: float, curvature: float, config: BackendConfig) -> float | None:
        """Add one solve's share of its scale step; return the factor to rescale by now, if any.

        ``slope``, ``curvature``: the solve's ``scale_tension``; NaN, or a curvature that is
        not positive (no metric measurement in the window), adds nothing.
        """
        if not (math.isfinite(slope) and math.isfinite(curvature) and curvature > 0):
            return None
        share = 1.0 / config.window_size
        bound = share * config.fallback_max_scale_jump
        self.pending += float(np.clip(-share * slope / curvature, -bound, bound))
        if abs(self.pending) < RESCALE_MIN:
            return None
        factor, self.pending = 1.0 + self.pending, 0.0
        return factor


def rescale_map(kf: KeyframeStore, features: FeatureMap, landmarks: LandmarkStore,
                run: RunScale, factor: float) -> None:
    """Scale every map position by ``factor`` about the newest keyframe, which stays."""
    n = kf.n
    center = kf.C_map[n - 1].copy()
    kf.C_map[:n] = center + factor * (kf.C_map[:n] - center)
    features.points = center + factor * (features.points - center)
    landmarks.scale_about(center, factor)
    run.rescale(factor)
