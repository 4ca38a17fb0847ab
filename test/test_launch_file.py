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

"""Check launch/pmba.launch.py without ROS launch (not on PyPI).

It compiles, and its pairings name real parameters, valid values and the node's remappable
input topics.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.frontends import PAIRINGS
import pytest

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'launch' / 'pmba.launch.py'
EXPECTED_LAYOUTS = {'vins_mono': 'vins_mono', 'vins_fusion': 'per_point',
                    'vins_fusion_ros2': 'per_point', 'openvins': 'per_point'}


def pairings() -> dict[str, Any]:
    """Return the pairings the launch file uses (it imports them from the package)."""
    assert 'from pmba_ros.backend.frontends import PAIRINGS' in LAUNCH.read_text(encoding='utf-8')
    return PAIRINGS


def test_launch_file_compiles_and_is_installed() -> None:
    """The file compiles, defines generate_launch_description, and setup.py installs it."""
    source = LAUNCH.read_text(encoding='utf-8')
    tree = compile(source, str(LAUNCH), 'exec', ast.PyCF_ONLY_AST)
    assert 'generate_launch_description' in {
        n.name for n in tree.body if isinstance(n, ast.FunctionDef)}  # type: ignore[attr-defined]
    assert "glob('launch/*.launch.py')" in (ROOT / 'setup.py').read_text(encoding='utf-8')


@pytest.mark.parametrize('frontend', sorted(EXPECTED_LAYOUTS))
def test_pairing_names_real_parameters_and_topics(frontend: str) -> None:
    """Parameters are config fields with valid values; remaps start from the input topics."""
    pairing = pairings()[frontend]
    config = BackendConfig.from_params(pairing['parameters'])   # unknown names raise
    assert config.feature_layout == EXPECTED_LAYOUTS[frontend]
    defaults = BackendConfig()
    inputs = {defaults.features_topic, defaults.keyframe_topic, defaults.camera_info_topic,
              defaults.extrinsic_topic}
    sources = [src for src, _ in pairing['remappings']]
    assert set(sources) <= inputs and len(set(sources)) == len(sources)
    # Each names its poses, its tracks and its own body -> camera topic (no TF names its body).
    assert {defaults.features_topic, defaults.keyframe_topic, defaults.extrinsic_topic} <= set(
        sources)
    assert all(dst.startswith('/') for _, dst in pairing['remappings'])
    if config.feature_layout == 'per_point' and frontend == 'openvins':
        # OpenVINS tracks carry raw pixels only: the intrinsics topic must be wired.
        assert defaults.camera_info_topic in sources
