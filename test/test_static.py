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
"""ruff and mypy over the package, as CI runs them (skipped where the tools are missing)."""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.linter
def test_ruff_is_clean() -> None:
    """Ruff finds nothing with the repository's ruff.toml."""
    pytest.importorskip('ruff')
    proc = subprocess.run([sys.executable, '-m', 'ruff', 'check', '--no-cache', '.'], cwd=ROOT,
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.linter
def test_mypy_is_clean() -> None:
    """Mypy finds nothing in the package (configuration in setup.cfg)."""
    pytest.importorskip('mypy')
    proc = subprocess.run([sys.executable, '-m', 'mypy', '--no-incremental', 'pmba_ros'],
                          cwd=ROOT, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_no_module_is_over_600_lines() -> None:
    """Every module of the package stays within 600 lines (one concept per module)."""
    package = ROOT / 'pmba_ros'
    sizes = {path.relative_to(package).as_posix(): len(path.read_text().splitlines())
             for path in package.rglob('*.py')}
    over = {name: n for name, n in sizes.items() if n > 600}
    assert not over, f'modules over 600 lines: {over}'


@pytest.mark.linter
def test_codespell_is_clean() -> None:
    """Codespell finds no misspelling in the sources, tests, docs and configuration."""
    pytest.importorskip('codespell_lib')
    paths = ['pmba_ros', 'test', 'docs', 'config', 'launch', 'scripts', 'benchmarks',
             'setup.py', 'setup.cfg', 'package.xml', 'README.md']
    proc = subprocess.run([sys.executable, '-m', 'codespell_lib', *paths], cwd=ROOT,
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
