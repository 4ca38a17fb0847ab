"""The ``pmba`` command: one verb per module, imported lazily (evo's entry-point pattern).

Each verb module has ``add_arguments(parser)`` and ``run(args) -> int``. Library errors
(:class:`~pmba_ros.errors.PmbaError`, missing files) become one ``error:`` line and exit 1.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import importlib
import logging
import sys

from pmba_ros import __version__
from pmba_ros._heap import keep_freed_memory
from pmba_ros.errors import PmbaError

VERBS: dict[str, tuple[str, str]] = {
    'solve': ('pmba_ros.cli.solve', 'solve a BA problem (BAL, ParallaxBA, simulated scene)'),
    'simulate': ('pmba_ros.cli.simulate', 'write a simulated front-end bag or BA problem'),
    'replay': ('pmba_ros.cli.replay', 'run the back-end over recorded bags and evaluate'),
    'evaluate': ('pmba_ros.cli.evaluate', 'ATE / RPE of a trajectory against ground truth'),
    'import-tracks': ('pmba_ros.cli.import_tracks', 'turn KITTI-00 stereo tracks into a bag'),
    'play': ('pmba_ros.cli.play', 'publish a recording into a live ROS 2 graph (needs rclpy)'),
}


def build_parser(verbs: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """Return the argument parser with a subparser per verb."""
    parser = argparse.ArgumentParser(prog='pmba', description=__doc__.splitlines()[0])
    parser.add_argument('--version', action='version', version=f'pmba_ros {__version__}')
    parser.add_argument('-v', '--verbose', action='store_true', help='log debug messages')
    sub = parser.add_subparsers(dest='verb', required=True, metavar='VERB')
    for name in verbs or VERBS:
        module_name, help_text = VERBS[name]
        verb_parser = sub.add_parser(name, help=help_text, description=help_text,
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
        importlib.import_module(module_name).add_arguments(verb_parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``pmba`` command line and return its exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    keep_freed_memory()
    verb = next((a for a in argv if not a.startswith('-')), None)
    parser = build_parser([verb] if verb in VERBS else None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format='%(levelname)s %(name)s: %(message)s')
    module = importlib.import_module(VERBS[args.verb][0])
    try:
        return int(module.run(args))
    except (PmbaError, FileNotFoundError, IsADirectoryError) as err:
        print(f'error: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('error: interrupted', file=sys.stderr)
        return 130


def replay_main() -> int:
    """Entry point of the ``pmba_bag_replay`` script (``pmba replay``)."""
    return main(['replay', *sys.argv[1:]])
