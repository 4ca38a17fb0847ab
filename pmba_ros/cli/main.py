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
"""The ``pmba`` command: one verb per module, imported lazily (evo's entry-point pattern).

Each verb module has ``add_arguments(parser)`` and ``run(args) -> int``. Library errors
(:class:`~pmba_ros.errors.PmbaError`, ``OSError``) become one ``error:`` line and exit 1.
"""

from __future__ import annotations

import argparse
import atexit
from collections.abc import Sequence
import contextlib
import importlib
import logging
import signal
import sys
import traceback

from pmba_ros import __version__
from pmba_ros._process import tune_process
from pmba_ros.errors import PmbaError

VERBS: dict[str, tuple[str, str]] = {
    'solve': ('pmba_ros.cli.solve',
              'solve a bundle adjustment problem (BAL, ParallaxBA, COLMAP, Bundler, simulated)'),
    'simulate': ('pmba_ros.cli.simulate', 'write a simulated front-end bag or BA problem'),
    'replay': ('pmba_ros.cli.replay', 'run the back-end over recorded bags and evaluate'),
    'evaluate': ('pmba_ros.cli.evaluate', 'ATE / RPE of a trajectory against ground truth'),
    'import-tracks': ('pmba_ros.cli.import_tracks', 'turn KITTI-00 stereo tracks into a bag'),
    'play': ('pmba_ros.cli.play', 'publish a recording into a live ROS 2 graph (needs rclpy)'),
    'warmup': ('pmba_ros.cli.warmup', 'compile the solver loops now (after installing)'),
}
#: Verbs that solve: the compiled loops are made ready (with a message) before they start.
SOLVING_VERBS = frozenset({'solve', 'replay'})

DESCRIPTION = """\
Parallax bundle adjustment (PMBA) for visual SLAM back-ends: solve bundle adjustment
problems, run the ROS 2 back-end offline over recorded front-end bags, and evaluate
trajectories against ground truth."""

EPILOG = """\
examples:
  pmba solve sim:street --compare      compare PMBA with XYZ and inverse-depth BA
  pmba simulate --out street           write a simulated front-end bag
  pmba replay street --out result      run the back-end over it, with accuracy
  pmba evaluate est.tum gt.tum         ATE / RPE of a trajectory

'pmba VERB --help' describes a verb's options."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Show an option's default only where it has one (not for required options or flags)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        """Return the help text, with ``(default: ...)`` where a default means something."""
        if action.required or action.default in (None, False, argparse.SUPPRESS):
            return action.help
        return super()._get_help_string(action)


def build_parser(verbs: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """Return the argument parser with a subparser per verb."""
    parser = argparse.ArgumentParser(prog='pmba', description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--version', action='version', version=f'pmba_ros {__version__}')
    parser.add_argument('-v', '--verbose', action='store_true', help='log debug messages')
    sub = parser.add_subparsers(dest='verb', required=True, metavar='VERB',
                                help='what to do (one of the verbs below)')
    for name in verbs or VERBS:
        module_name, help_text = VERBS[name]
        verb_parser = sub.add_parser(name, help=help_text, description=help_text,
                                     formatter_class=HelpFormatter)
        importlib.import_module(module_name).add_arguments(verb_parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``pmba`` command line and return its exit code.

    Expected failures (bad input files, unwritable outputs, invalid parameter files, the
    package's :class:`~pmba_ros.errors.PmbaError`) print one ``error:`` line and return 1;
    usage errors exit 2 (argparse); an interrupt returns 130. Anything else is a bug: its
    traceback is printed with a line asking to report it, and 1 is returned.
    """
    return _program(list(sys.argv[1:] if argv is None else argv), as_program=argv is None)


def _program(argv: list[str], *, as_program: bool) -> int:
    """Run ``argv``; ``as_program``: this is the process's command, not a library call."""
    if as_program:
        # SIGTERM too: killed by it, a verb wrote no report and left its bag's temporary
        # folder (`pmba simulate`: .BAG.partial), where an interrupt cleans up.
        with contextlib.suppress(ValueError):  # not the main thread
            signal.signal(signal.SIGINT, _interrupt_once)
            signal.signal(signal.SIGTERM, _interrupt_once)
    try:
        return _run(argv)
    except KeyboardInterrupt:
        _ignore_sigint(as_program)
        print('error: interrupted', file=sys.stderr)
        return 130
    finally:
        # A further Ctrl-C during interpreter shutdown would print an atexit traceback.
        _ignore_sigint(as_program)
        _drop_terminal_reset()


def _run(argv: list[str]) -> int:
    """Parse ``argv`` and run the verb, turning expected errors into one line."""
    tune_process()
    verb = next((a for a in argv if not a.startswith('-')), None)
    parser = build_parser([verb] if verb in VERBS else None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format='%(levelname)s %(name)s: %(message)s')
    module = importlib.import_module(VERBS[args.verb][0])
    try:
        if args.verb in SOLVING_VERBS:
            from pmba_ros.cli.warmup import ensure_compiled
            ensure_compiled(sys.stderr)
        return int(module.run(args))
    except (PmbaError, OSError) as err:
        print(f'error: {_one_line(err)}', file=sys.stderr)
        return 1
    except Exception:  # anything else is a bug: show it and ask for a report
        traceback.print_exc()
        print(f'error: internal error in pmba_ros {__version__} (a bug); please report it '
              f'with the command line and the traceback above: pmba {" ".join(argv)}',
              file=sys.stderr)
        return 1


MAX_ERROR_CHARS = 1000
"""Longest error line printed: a library's message may quote a whole damaged record."""


def _one_line(err: BaseException) -> str:
    """Return the error text on one line (OSErrors name their file), its middle cut if long."""
    if isinstance(err, OSError) and err.filename is not None and err.strerror:
        text = f'{err.filename}: {err.strerror}'
    else:
        text = str(err) or type(err).__name__
    text = ' '.join(text.split())
    if len(text) <= MAX_ERROR_CHARS:
        return text
    cut = len(text) - MAX_ERROR_CHARS
    head = MAX_ERROR_CHARS * 3 // 4
    return f'{text[:head]} ... ({cut} characters left out) ... {text[head + cut:]}'


def _drop_terminal_reset() -> None:
    """Cancel the terminal reset colorama would write at exit, after the command's output.

    numba's error formatting calls ``colorama.init()`` when compiled code is loaded; colorama
    then writes an ANSI reset (ESC [0m) to a terminal at exit: a stray escape sequence.
    """
    initialise = sys.modules.get('colorama.initialise')
    if initialise is not None:
        atexit.unregister(initialise.reset_all)


def _interrupt_once(signum: int, frame: object) -> None:
    """Raise KeyboardInterrupt for the first SIGINT or SIGTERM and ignore the ones that follow.

    Repeated Ctrl-C would otherwise interrupt the clean-up of the first one (finalizing
    outputs, finalizers of compiled code) and print tracebacks from there.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt


def _ignore_sigint(as_program: bool) -> None:
    """Ignore SIGINT from now on when running as the program (never inside a caller)."""
    if as_program:
        with contextlib.suppress(ValueError):  # not the main thread
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def replay_main() -> int:
    """Entry point of the ``pmba_bag_replay`` script (``pmba replay``)."""
    return _program(['replay', *sys.argv[1:]], as_program=True)
