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
"""Shared fixtures: seeded generators and the location of ../shared/data."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

if TYPE_CHECKING:
    from pmba_ros.core.engine import Engine


def pytest_configure(config: pytest.Config) -> None:
    """Size the BLAS pools once, as every program of the package does at start-up.

    Several tests run the CLI in-process, which does it too: without this, a test's numbers
    would depend on whether such a test ran before it (BLAS' summation order changes with its
    thread count).
    """
    del config
    from pmba_ros._threads import limit_blas_threads
    limit_blas_threads()


#: The read-only datasets live beside the repository (CI clones it with shared/ next to it).
SHARED_DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def shared_file(*parts: str) -> Path:
    """Return a file under ../shared/data, skipping the test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f'shared data not available: {path}')
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    """Return a seeded random generator."""
    return np.random.default_rng(12345)


@pytest.fixture(params=['numpy', 'compiled'])
def engine(request: pytest.FixtureRequest) -> Engine:
    """Return the numpy engine, then the compiled one (where numba is there)."""
    from .core.helpers import engine_named
    return engine_named(str(request.param))


def run_python(code: str, timeout_s: float = 600.0) -> None:
    """Run ``code`` in a fresh interpreter (no module imported yet); fail with its stderr."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=timeout_s, check=False)
    assert proc.returncode == 0, proc.stderr
