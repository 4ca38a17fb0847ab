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
"""``pmba solve`` and ``pmba replay`` on files damaged at random.

Run::

    python benchmarks/bench_damaged_files.py [--runs 50]

Each run copies an input, damages one of its files (``pmba_ros.sim.damage``: cut short, bits
flipped, a span zeroed or repeated, a token such as ``nan`` written into it) and runs the
verb on it in this process: ``pmba solve MODEL --init file|global --out DIR`` for photo
collections (COLMAP text and binary from a simulated street, a COLMAP model with rigs from
pycolmap if installed, a BAL problem and, with ``../shared`` beside the repository, the
ParallaxBA fake-pile), ``pmba replay BAG --out DIR`` for recordings (a simulated 40-keyframe
street as MCAP, as SQLite and as a ROS 1 bag, converted by ``rosbags-convert``). A run ends
done (exit 0, or 3 for a recording read in part), refused (exit 1 with one ``error:`` line)
or with an internal error (a traceback: a bug). The exit status is 1 if any run ended with
an internal error.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import contextlib
import io
import logging
from pathlib import Path
import random
import shutil
import subprocess
import sys
import tempfile

from pmba_ros.cli.main import main
from pmba_ros.io import bal, colmap
from pmba_ros.sim.bag import write_sequence_bag
from pmba_ros.sim.damage import damage_bytes
from pmba_ros.sim.scenes import street_scene
from pmba_ros.sim.sequence import simulate_sequence

SHARED_PILE = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'parallaxba' / 'fake-pile'


def _colmap(binary: bool) -> Callable[[Path], Path]:
    def make(d: Path) -> Path:
        problem = street_scene(1, n_cams=12, n_points=300, max_track_length=5).start
        colmap.write_colmap(d, colmap.from_problem(problem), binary=binary)
        return d
    return make


def _rigs(d: Path) -> Path:
    import pycolmap
    options = pycolmap.SyntheticDatasetOptions()
    options.num_rigs, options.num_cameras_per_rig, options.num_frames_per_rig = 2, 2, 4
    options.num_points3D = 100
    pycolmap.set_random_seed(0)
    d.mkdir(parents=True)
    pycolmap.synthesize_dataset(options).write(str(d))   # noise-free: the damage is the test
    return d


def _bal(d: Path) -> Path:
    d.mkdir(parents=True)
    bal.write_bal(d / 'problem.txt', street_scene(2, n_cams=12, n_points=300).start)
    return d / 'problem.txt'


def _pile(d: Path) -> Path:
    shutil.copytree(SHARED_PILE, d)
    return d


def _recording(storage: str) -> Callable[[Path], Path]:
    def make(d: Path) -> Path:
        d.mkdir(parents=True)
        write_sequence_bag(simulate_sequence('street', n_keyframes=40, seed=0), d / 'mcap')
        if storage == 'mcap':
            return d / 'mcap'
        dst = d / ('sqlite' if storage == 'sqlite3' else 'street.bag')
        convert = Path(sys.executable).parent / 'rosbags-convert'
        subprocess.run([str(convert), '--src', str(d / 'mcap'), '--dst', str(dst)]
                       + (['--dst-storage', storage] if storage == 'sqlite3' else []),
                       check=True, capture_output=True)
        return dst
    return make


def models() -> dict[str, Callable[[Path], Path]]:
    """Return the photo collections this run can make: name -> writer into a folder."""
    out = {'COLMAP text': _colmap(False), 'COLMAP binary': _colmap(True), 'BAL': _bal}
    with contextlib.suppress(ImportError):
        import pycolmap  # noqa: F401
        out['COLMAP rigs (binary)'] = _rigs
    if SHARED_PILE.is_dir():
        out['ParallaxBA fake-pile'] = _pile
    return out


RECORDINGS = {'MCAP recording': _recording('mcap'), 'SQLite recording': _recording('sqlite3'),
              'ROS 1 bag': _recording('ros1')}
"""The recordings: name -> writer into a folder (returns the bag's path)."""


def run_one(source: Path, work: Path, verb: list[str], seed: int) -> tuple[str, str]:
    """Damage one file of a copy of ``source`` and run ``verb`` on it; (outcome, last line).

    ``verb``: the command before the input's path (``['solve']``); ``--out`` follows it.
    """
    rng = random.Random(seed)
    copy = work / 'input'
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    if source.is_dir():
        shutil.copytree(source, copy)
        target = copy
        victim = rng.choice(sorted(p for p in copy.iterdir() if p.is_file()))
    else:
        copy.mkdir()
        target = victim = copy / source.name
        shutil.copy(source, victim)
    victim.write_bytes(damage_bytes(victim.read_bytes(), rng))
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main([*verb[:1], str(target), *verb[1:], '--out', str(work / 'out')])
    text = err.getvalue()
    last = (text.strip().splitlines() or [''])[-1]
    if 'Traceback' in text or 'internal error' in text or code not in (0, 1, 3):
        return 'internal error', f'{victim.name} seed {seed}: {last}'
    return ('done' if code in (0, 3) else 'refused'), last


def main_bench() -> int:
    """Run the benchmark; return 1 if any run ended with an internal error."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--runs', type=int, default=50, help='damaged copies per input and verb')
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    solve = [['solve', '--init', init, '--max-iters', '3', '--quiet']
             for init in ('file', 'global')]
    cases = [(name, make, verb) for name, make in models().items() for verb in solve]
    cases += [(name, make, ['replay']) for name, make in RECORDINGS.items()]
    bugs = 0
    print(f'{"input":<24}{"verb":<20}{"done":>6}{"refused":>9}{"internal errors":>17}')
    with tempfile.TemporaryDirectory() as tmp:
        sources: dict[str, Path] = {}
        for name, make, verb in cases:
            if name not in sources:
                sources[name] = make(Path(tmp) / name.replace(' ', '_'))
            counts = {'done': 0, 'refused': 0, 'internal error': 0}
            for seed in range(args.runs):
                outcome, line = run_one(sources[name], Path(tmp) / 'work', verb, seed)
                counts[outcome] += 1
                if outcome == 'internal error':
                    print(f'  internal error: {line}', file=sys.stderr)
            bugs += counts['internal error']
            shown = ' '.join(verb[:3])
            print(f'{name:<24}{shown:<20}{counts["done"]:>6}{counts["refused"]:>9}'
                  f'{counts["internal error"]:>17}', flush=True)
    return 1 if bugs else 0


if __name__ == '__main__':
    sys.exit(main_bench())
