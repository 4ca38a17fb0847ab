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
"""``pmba warmup`` and the message a command that solves shows before compiling."""

from __future__ import annotations

from pmba_ros.cli.main import main
from pmba_ros.core import engine, warmup
import pytest


def test_warmup_verb_reports_the_loops_ready(capsys: pytest.CaptureFixture[str]) -> None:
    """The verb compiles or loads the loops and says how long it took."""
    pytest.importorskip('numba')
    assert main(['warmup']) == 0
    out = capsys.readouterr().out
    assert 'solver loops ready' in out or 'compiled in' in out, out
    assert warmup.is_warm()


def test_warmup_verb_without_compiled_loops(monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """With the loops off, it says there is nothing to compile."""
    monkeypatch.setattr(engine, 'compiled_available', lambda: False)
    assert main(['warmup']) == 0
    assert 'nothing to compile' in capsys.readouterr().out


def test_solve_announces_a_first_compilation_with_its_expected_time(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A cold cache: one line with the expected time before the solve, then the time taken."""
    pytest.importorskip('numba')
    calls = []
    monkeypatch.setattr(warmup, 'is_warm', lambda: False)
    monkeypatch.setattr(warmup, 'warm_up', lambda: calls.append(1) or 12.5)
    assert main(['solve', 'sim:street:0', '--quiet']) == 0
    err = capsys.readouterr().err
    assert f'expected {warmup.expected_compile_text()}' in err, err
    assert 'compiled in 12.5 s' in err
    assert calls == [1]


@pytest.mark.parametrize(('seconds', 'said'), [(0.3, False), (2.5, True)])
def test_solve_with_a_warm_cache_loads_the_loops_first(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], seconds: float,
        said: bool) -> None:
    """Warm cache: the loops are loaded before the work, said only when it takes a while."""
    calls: list[int] = []
    monkeypatch.setattr(warmup, 'is_warm', lambda: True)
    monkeypatch.setattr(warmup, 'warm_up', lambda: calls.append(1) or seconds)
    assert main(['solve', 'sim:street:0', '--quiet']) == 0
    err = capsys.readouterr().err
    assert calls == [1]
    assert 'compil' not in err
    assert (f'solver loops ready ({seconds:.1f} s)' in err) is said
