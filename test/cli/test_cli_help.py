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
"""The ``pmba`` help texts: every option documented, defaults only where they mean something."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import subprocess
import sys

from pmba_ros.cli.main import build_parser, VERBS
from pmba_ros.cli.progress import iteration_printer, stage_printer
from pmba_ros.core.solve import IterationRecord
import pytest


def _verb_parsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


@pytest.mark.parametrize('verb', sorted(VERBS))
def test_every_option_of_every_verb_has_help(verb: str) -> None:
    """Each argument of a verb, positional or option, has a help text."""
    for action in _verb_parsers()[verb]._actions:
        assert action.help and action.help != argparse.SUPPRESS, (
            f'pmba {verb}: {"/".join(action.option_strings) or action.dest} has no help')


@pytest.mark.parametrize('verb', sorted(VERBS))
def test_required_options_and_flags_show_no_default(verb: str) -> None:
    """'(default: None)' and '(default: False)' never appear in a verb's help."""
    text = _verb_parsers()[verb].format_help()
    assert '(default: None)' not in text and '(default: False)' not in text
    assert '==SUPPRESS==' not in text


def test_defaults_are_shown_where_they_exist() -> None:
    """An option with a real default still shows it."""
    text = ' '.join(_verb_parsers()['solve'].format_help().split())
    assert '(default: dogleg)' in text and '(default: 100)' in text


def test_top_level_help_is_written_for_users() -> None:
    """The top-level help describes the tool and shows examples, not a module docstring."""
    text = build_parser().format_help()
    assert 'bundle adjustment' in text and 'examples:' in text
    assert '``' not in text and 'evo' not in text


def test_progress_numbers_every_iteration(capsys: pytest.CaptureFixture[str]) -> None:
    """Iterations without a usable step get a line of their own: the numbers run on."""
    show = iteration_printer('pmba-dogleg')
    for it, accepted in ((0, True), (1, True), (4, False)):
        show(IterationRecord(it, 1.0, 1.0, accepted, 1.0, 0.0, 0.5, it, 0.1 * it))
    lines = capsys.readouterr().err.splitlines()
    assert [int(line.split(' it ')[1].split()[0]) for line in lines] == [0, 1, 2, 3, 4]
    assert lines[0].endswith('start') and lines[1].endswith('accepted')
    assert 'no usable step' in lines[2] and lines[4].endswith('rejected')


def test_stage_lines_report_a_long_stage_at_most_every_few_seconds(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A running stage prints only when the interval has passed; a finished one always."""
    show = stage_printer(every_s=3600.0)
    show('pairs', {'running': True, 'pairs_taken': 5, 'pairs_to_estimate': 10})
    show('pairs', {'pairs_found': 10})
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and 'pairs' in lines[0] and 'done' in lines[0]
    show = stage_printer(every_s=0.0)
    show('pairs', {'running': True, 'pairs_taken': 5, 'pairs_to_estimate': 10})
    assert '5 of 10 pairs' in capsys.readouterr().err


def test_no_terminal_escape_after_a_command_that_loads_compiled_code(tmp_path: Path) -> None:
    """The colorama reset numba installs is not written to the terminal at exit."""
    pytest.importorskip('numba')
    pty = pytest.importorskip('pty')
    main_fd, child_fd = pty.openpty()
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join(sys.path)}
    proc = subprocess.run([sys.executable, '-m', 'pmba_ros', 'warmup'], stdout=child_fd,
                          stderr=child_fd, stdin=subprocess.DEVNULL, env=env, timeout=600,
                          check=False)
    os.close(child_fd)
    chunks = []
    while True:
        try:
            data = os.read(main_fd, 4096)
        except OSError:  # the terminal is closed once everything is read
            break
        if not data:
            break
        chunks.append(data)
    os.close(main_fd)
    assert proc.returncode == 0
    output = b''.join(chunks)
    assert b'\x1b' not in output, output
