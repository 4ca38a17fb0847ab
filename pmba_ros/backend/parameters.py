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
"""The node's parameters as data: which may change at run time, and their descriptions."""

from __future__ import annotations

import inspect
import re

from pmba_ros.backend.config import BackendConfig

RUNTIME_PARAMETERS = frozenset({
    'max_iterations', 'max_time_s', 'loss', 'loss_scale_px', 'transform_tolerance_s',
    'covariance_position_m2', 'covariance_rotation_rad2', 'stamp_tolerance_s',
    'association_timeout_s', 'init_min_parallax_px', 'init_retry_every', 'init_max_iterations',
    'min_observations', 'max_observations_per_feature', 'max_fixed_keyframes', 'fixed_lookback',
    'deterministic', 'save_directory', 'tf_rate_hz', 'stale_input_s', 'publish_tf'})
"""Parameters ``ros2 param set`` may change while running; the others are read-only."""


def parameter_descriptions() -> dict[str, str]:
    """Return each :class:`BackendConfig` field's description (its docstring's Attributes)."""
    doc = inspect.cleandoc(BackendConfig.__doc__ or '').split('Attributes:', 1)[-1]
    descriptions: dict[str, str] = {}
    name = ''
    for line in doc.splitlines():
        match = re.match(r'    (\w+): (.*)', line)
        if match:
            name = match[1]
            descriptions[name] = match[2]
        elif name and line.strip():
            descriptions[name] += ' ' + line.strip()
    return descriptions


__all__ = ['RUNTIME_PARAMETERS', 'parameter_descriptions']
