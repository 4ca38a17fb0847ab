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
"""``pmba warmup``: compile the solver's loops now (after an install or an upgrade).

``scripts/setup_venv`` runs it after installing; a ROS install can run it once after
``colcon build``. Without it, the first command that solves compiles them, after saying so.
"""

from __future__ import annotations

import argparse
import sys
from typing import TextIO


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the verb's options (none)."""
    del parser


def ensure_compiled(stream: TextIO, *, verbose: bool = False) -> None:
    """Compile or load the loops before the work, saying so on ``stream`` when it is long.

    A command's own timings (a replay's speed) then measure its work, the first keyframe as
    the others, not numba setting itself up or the initialization's modules loading.

    Args:
        stream: Where the messages go (stderr for commands whose output is data).
        verbose: Also say how long loading already compiled loops took (the ``warmup`` verb);
            otherwise that is said only when it took over a second.
    """
    from pmba_ros.core import warmup
    from pmba_ros.init import import_initialization

    import_initialization()
    if not warmup.is_warm():
        print('compiling the solver loops (once per install; expected '
              f'{warmup.expected_compile_text()}) ...', file=stream, flush=True)
        seconds = warmup.warm_up()
        print(f'compiled in {seconds:.1f} s', file=stream, flush=True)
        return
    seconds = warmup.warm_up()
    if verbose or seconds > 1.0:
        print(f'solver loops ready ({seconds:.1f} s)', file=stream, flush=True)


def run(args: argparse.Namespace) -> int:
    """Compile the loops (or check they load) and report how long it took."""
    del args
    from pmba_ros.core.engine import compiled_available

    if not compiled_available():
        print('compiled loops off (numba not installed, or PMBA_NUMBA=0): nothing to compile')
        return 0
    ensure_compiled(sys.stdout, verbose=True)
    return 0
