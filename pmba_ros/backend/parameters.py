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

from dataclasses import fields
import inspect
import re
from typing import Any

from pmba_ros.backend import config as settings
from pmba_ros.backend.config import BackendConfig, implied_num_cams
from pmba_ros.backend.msg_backend import MsgBackend, RclpyBackend

_INT_MAX = 2**31 - 1

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


def parameter_descriptor(name: str, description: str, backend: MsgBackend) -> Any:
    """Return the ``rcl_interfaces/ParameterDescriptor`` of config field ``name``.

    Types are dynamic so that an integer is accepted for a float (``max_time_s: 1``);
    :class:`BackendConfig` checks every type and value and names the parameter.
    """
    desc = backend.new('rcl_interfaces/msg/ParameterDescriptor', name=name,
                       description=description, dynamic_typing=True,
                       read_only=name not in RUNTIME_PARAMETERS)
    if name in settings.CHOICES:
        allowed = settings.CHOICES[name]
        desc.additional_constraints = 'one of ' + ', '.join(repr(c) for c in allowed)
    elif name in settings.INT_MINIMUMS:
        desc.integer_range = [backend.new('rcl_interfaces/msg/IntegerRange',
                                          from_value=settings.INT_MINIMUMS[name],
                                          to_value=settings.INT_MAXIMUMS.get(name, _INT_MAX),
                                          step=1)]
    elif name in settings.POSITIVE_FLOATS or name in settings.NON_NEGATIVE_FLOATS:
        desc.floating_point_range = [backend.new('rcl_interfaces/msg/FloatingPointRange',
                                                 from_value=0.0, to_value=float('inf'),
                                                 step=0.0)]
        desc.additional_constraints = '> 0' if name in settings.POSITIVE_FLOATS else '>= 0'
    return desc


def declare_config(node: Any) -> BackendConfig:
    """Declare every :class:`BackendConfig` field as a parameter and build the config.

    Raises:
        ValueError: If a parameter value is invalid (the message names the parameter).
        rclpy.exceptions.InvalidParameterValueException: If a value is out of its range.
    """
    defaults = BackendConfig()
    descriptions = parameter_descriptions()
    backend = RclpyBackend()
    values: dict[str, Any] = {}
    # num_cams last: its default is the count camera_extrinsics / camera_info_topics list,
    # so a stereo rig's lists need no num_cams: 2 beside them, and the parameter still
    # reports the count in use (one set in the file wins, and is checked against them).
    names = sorted((f.name for f in fields(BackendConfig)), key=lambda n: n == 'num_cams')
    for name in names:
        default = getattr(defaults, name)
        if name == 'num_cams':
            default = implied_num_cams(values) or default
        value = node.declare_parameter(
            name, default, parameter_descriptor(name, descriptions.get(name, ''), backend)).value
        # An empty list in a parameter file has no type: rclpy leaves such a parameter unset.
        values[name] = default if value is None else value
    return BackendConfig.from_params(values)


__all__ = ['RUNTIME_PARAMETERS', 'declare_config', 'parameter_descriptions',
           'parameter_descriptor']
