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
"""Imports point downward only, and ROS / bag libraries stay in the modules that need them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'pmba_ros'

#: Rank of each top-level part of the package: a module may import ranks <= its own.
RANKS = {
    'errors': 0, '_typing': 0, '_json': 0, '_numbers': 0, '_heap': 0, '_threads': 0,
    '_process': 0, '': 0,
    'core': 1,
    'init': 2, 'eval': 2,
    'backend': 3,
    'io': 4,
    'sim': 5,
    'node': 6, 'replay': 6, 'replay_report': 6, 'plot': 6,
    'cli': 7, '__main__': 7,
}

#: Within the engine, the order of style.md §6.1: geometry -> problem -> residuals -> solver.
CORE_RANKS = {
    'so3': 0, 'sphere': 0, 'radial': 0, 'camera': 0, 'jit': 0,
    'problem': 1, 'gauge': 1, 'loss': 1, 'dogleg': 1, 'jacobian': 1,
    'residuals': 2, 'baselines': 2, 'anchor_search': 2, 'normal_equations': 2,
    'numpy_schur': 2, 'compiled': 2,
    'engine': 3,
    'conversions': 4, 'models': 4, 'refit': 4,
    'trust_step': 5, 'solve': 5,
    'warmup': 6,
}

#: Third-party modules allowed only in some places (top-level or lazy imports alike).
RESTRICTED = {
    'rclpy': {'node'},
    'rosbags': {'io.bags', 'io.typestores', 'io.bag_writer', 'io.salvage.ros1_file',
                'io.salvage.ros1_mcap', 'io.salvage.metadata', 'backend.msg_backend'},
    'mcap': {'io.bags', 'io.salvage.mcap_file'},
    'mcap_ros2': {'io.bags'},
    'apsw': {'io.bags', 'io.salvage.sqlite_file'},
    'matplotlib': {'plot'},
}


def _modules() -> list[tuple[str, Path]]:
    out = []
    for path in sorted(PACKAGE.rglob('*.py')):
        rel = path.relative_to(PACKAGE).with_suffix('')
        parts = [p for p in rel.parts if p != '__init__']
        out.append(('.'.join(parts), path))
    return out


def _imports(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
            if node.module == 'pmba_ros':
                names += [f'pmba_ros.{a.name}' for a in node.names]
    return names


def _rank(module: str) -> tuple[int, int]:
    top = module.split('.')[0]
    inner = CORE_RANKS.get(module.split('.')[1], -1) if top == 'core' and '.' in module else -1
    return RANKS[top], inner


@pytest.mark.parametrize(('module', 'path'), _modules(), ids=[m for m, _ in _modules()])
def test_imports_point_downward(module: str, path: Path) -> None:
    """A module imports only its own layer and the layers below it."""
    own = _rank(module)
    for name in _imports(path):
        if not name.startswith('pmba_ros.'):
            continue
        target = name[len('pmba_ros.'):]
        if target.split('.')[0] not in RANKS:
            continue
        other = _rank(target)
        assert other[0] <= own[0], f'{module} imports the higher layer {target}'
        if own[0] == other[0] == 1 and own[1] >= 0 and other[1] >= 0:
            assert other[1] <= own[1], f'{module} imports the higher engine module {target}'


@pytest.mark.parametrize(('module', 'path'), _modules(), ids=[m for m, _ in _modules()])
def test_ros_and_bag_libraries_stay_where_they_belong(module: str, path: Path) -> None:
    """Only node.py imports rclpy; bag libraries live in the bag I/O modules."""
    for name in _imports(path):
        top = name.split('.')[0]
        if top in RESTRICTED:
            assert module in RESTRICTED[top], f'{module} imports {name}'


def test_package_imports_without_ros() -> None:
    """Importing the package and its CLI pulls in neither rclpy nor the node."""
    import subprocess
    import sys
    code = ('import sys, pmba_ros, pmba_ros.cli.main, pmba_ros.backend.logic; '
            'assert "rclpy" not in sys.modules and "pmba_ros.node" not in sys.modules')
    subprocess.run([sys.executable, '-c', code], check=True)
