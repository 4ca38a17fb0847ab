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
"""The engine switch: names resolve once to the numpy or the compiled engine."""

from __future__ import annotations

from pmba_ros.core import engine
from pmba_ros.core.engine import COMPILED, EngineName, NUMPY, resolve
from pmba_ros.core.solve import SolveOptions
from pmba_ros.errors import SolverError
import pytest


def test_auto_is_compiled_where_numba_runs_else_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """'auto' follows numba's availability; 'numpy' is numpy either way."""
    monkeypatch.setattr(engine, 'compiled_available', lambda: False)
    assert resolve('auto') is NUMPY
    assert resolve(EngineName.NUMPY) is NUMPY
    monkeypatch.setattr(engine, 'compiled_available', lambda: True)
    assert resolve('auto') is COMPILED
    assert resolve('numpy') is NUMPY
    assert resolve('compiled') is COMPILED


def test_compiled_without_numba_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """Asking for the compiled engine without numba names what is missing."""
    monkeypatch.setattr(engine, 'compiled_available', lambda: False)
    with pytest.raises(SolverError, match='needs numba'):
        resolve('compiled')


def test_solve_options_take_an_engine_name() -> None:
    """The option is coerced to EngineName and an unknown name is refused up front."""
    assert SolveOptions(engine='numpy').engine is EngineName.NUMPY
    assert SolveOptions().engine is EngineName.AUTO
    with pytest.raises(ValueError, match='SolveOptions'):
        SolveOptions(engine='gpu')
