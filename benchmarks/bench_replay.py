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
"""Replay benchmark: accuracy and throughput on the simulated street and the KITTI-00 tracks.

Run::

    python benchmarks/bench_replay.py                 # street 200 keyframes + KITTI-00, sliding
    python benchmarks/bench_replay.py --modes sliding global   # global mode too (slow)
    python benchmarks/bench_replay.py --keyframes 500 --no-kitti --check
    python benchmarks/bench_replay.py --max-iterations 2 1    # iteration budget per solve
    python benchmarks/bench_replay.py --no-kitti --repeat 5   # 5 replays a row, medians
    python benchmarks/bench_replay.py --no-kitti --budget     # where the CPU time goes

For each case it writes the bag, replays it (global and/or sliding mode) and prints the
front-end and optimized ATE (Sim(3)-aligned RMSE), their ratio, and the throughput as a
multiple of real time (bag duration / replay wall time; the street runs at 10 keyframes/s),
with the replay's CPU time (process time) as a load-independent figure. A warm-up replay of
30 keyframes runs first, so that every row measures steady-state throughput. ``--max-iterations``
adds a row per Dogleg budget per keyframe solve (the node's ``max_iterations``; default 1).
``--repeat N`` replays each row N times and prints each run, then the median and range of
wall time, CPU time and speed (on a shared machine the CPU time is the steadier figure).
``--budget`` times the main parts of the street replays (CPU seconds, summed over the row's
replays): window solves, building the window problem, the global initialization (with
any solve right after it), the outputs, parsing the tracks and writing the result bag; a
profiler would inflate the parts made of many small numpy calls.
``--check`` exits non-zero unless the street's optimized ATE is at most 30 % of the
front-end's and the replay runs at least 10x faster than real time. The solver's compiled
loops are used when numba is installed; ``PMBA_NUMBA=0`` measures the numpy engine.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
import sys
import tempfile
import time
from typing import Any

import numpy as np
from pmba_ros._process import tune_process
from pmba_ros.backend import estimator, logic
from pmba_ros.backend.config import BackendConfig
from pmba_ros.io import bag_writer
from pmba_ros.replay import replay, ReplayReport
from pmba_ros.sim.bag import groundtruth_path, write_sequence_bag
from pmba_ros.sim.sequence import simulate_sequence

SHARED = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def _row(name: str, mode: str, report: ReplayReport, cpu_s: float) -> str:
    """Format one result row."""
    acc = report.accuracy or {}
    ratio = acc.get('ate_ratio')
    return (f'{name:<18}{mode:<12}{report.keyframes_in:>6}{report.keyframes_out:>7}'
            f'{acc.get("ate_frontend_m", float("nan")):>11.4f}'
            f'{acc.get("ate_optimized_m", float("nan")):>11.4f}'
            f'{(ratio if ratio is not None else float("nan")):>8.3f}'
            f'{report.bag_duration_s:>8.1f}{report.wall_s:>8.2f}'
            f'{cpu_s:>8.2f}{report.realtime_factor:>8.2f}x')


def _spread(runs: list[tuple[float, float, float]]) -> str:
    """Return the median and range of wall s, CPU s and speed over repeated replays."""
    cols = np.array(runs)
    med = np.median(cols, axis=0)
    lo, hi = cols.min(axis=0), cols.max(axis=0)
    return (f'{"  median (range)":<30}wall {med[0]:.2f} ({lo[0]:.2f}-{hi[0]:.2f}) s, '
            f'cpu {med[1]:.2f} ({lo[1]:.2f}-{hi[1]:.2f}) s, '
            f'speed {med[2]:.2f}x ({lo[2]:.2f}-{hi[2]:.2f}x) over {len(runs)} replays')


#: Parts timed by ``--budget``: (label, owner, attribute), the owner's attribute wrapped.
_BUDGET = (('window solves', estimator, 'solve'),
           ('window problems', estimator.Estimator, '_build_problem'),
           ('feature conversion', estimator, 'xyz_to_parallax'),
           ('initialization', estimator.Estimator, '_initialize'),
           ('outputs', logic.BackendLogic, '_outputs'),
           ('tracks parsing', logic.BackendLogic, 'on_tracks'),
           ('bag writing', bag_writer.BagWriter, 'write'))


@contextmanager
def _budget(enabled: bool) -> Iterator[dict[str, float]]:
    """Time the :data:`_BUDGET` parts (CPU seconds) while the block runs, if enabled."""
    spent = {label: 0.0 for label, *_ in _BUDGET} if enabled else {}
    originals = [(owner, name, getattr(owner, name)) for _, owner, name in _BUDGET]

    def timed(label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[label] += time.process_time() - t0
        return wrapper

    try:
        if enabled:
            for (label, *_), (owner, name, fn) in zip(_BUDGET, originals, strict=True):
                setattr(owner, name, timed(label, fn))
        yield spent
    finally:
        for owner, name, fn in originals:
            setattr(owner, name, fn)


def main() -> int:
    """Run the benchmark and print the table."""
    tune_process()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--keyframes', type=int, default=200)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--modes', nargs='+', default=['sliding'],
                        choices=['sliding', 'global'])
    parser.add_argument('--max-iterations', nargs='+', type=int,
                        default=[BackendConfig().max_iterations])
    parser.add_argument('--no-kitti', action='store_true')
    parser.add_argument('--repeat', type=int, default=1, metavar='N',
                        help='replays per row (median and range printed)')
    parser.add_argument('--budget', action='store_true',
                        help='print the CPU seconds of the main parts of the street replays')
    parser.add_argument('--check', action='store_true')
    args = parser.parse_args()
    header = (f'{"case":<18}{"mode, its":<12}{"kf_in":>6}{"kf_out":>7}{"ATE fe":>11}'
              f'{"ATE opt":>11}{"ratio":>8}{"data s":>8}{"wall s":>8}{"cpu s":>8}{"speed":>9}')
    print(header)
    print('-' * len(header))
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        seq = simulate_sequence('street', n_keyframes=args.keyframes, seed=args.seed)
        street = root / 'street'
        write_sequence_bag(seq, street)
        sim_s = time.perf_counter() - t0
        # Rows compare steady-state throughput: the lazy imports (SciPy, OpenCV, the
        # back-end) and the typestore's first use are paid once here, on a short bag, and
        # printed below. A `pmba replay` process pays them once as well.
        warm = root / 'warm'
        write_sequence_bag(simulate_sequence('street', n_keyframes=30, seed=args.seed), warm)
        t0 = time.perf_counter()
        replay([warm], root / 'warm_out', BackendConfig())
        warm_s = time.perf_counter() - t0
        configs = [(f'{mode} {its}', BackendConfig(mode=mode, max_iterations=its))
                   for mode in args.modes for its in args.max_iterations]
        for label, config in configs:
            runs = []
            with _budget(args.budget) as spent:
                for _ in range(max(1, args.repeat)):
                    cpu0 = time.process_time()
                    report = replay([street], root / 'street_out', config,
                                    gt=groundtruth_path(street))
                    cpu = time.process_time() - cpu0
                    runs.append((report.wall_s, cpu, report.realtime_factor))
                    print(_row(f'street {args.keyframes}', label, report, cpu))
            if len(runs) > 1:
                print(_spread(runs))
            if args.budget:
                total = sum(cpu for _, cpu, _ in runs)
                print('  CPU budget: ' + ', '.join(
                    f'{name} {seconds:.2f} s ({100 * seconds / total:.0f} %)'
                    for name, seconds in spent.items()) + f' of {total:.2f} s')
            acc = report.accuracy or {}
            if (acc.get('ate_ratio') or 1.0) > 0.3 or report.realtime_factor < 10.0:
                ok = False
        kitti = SHARED / 'kitti00_stereo_vo'
        if not args.no_kitti and kitti.exists():
            from pmba_ros.cli.main import main as pmba
            bag = root / 'kitti00'
            pmba(['import-tracks', '--out', str(bag)])
            for label, config in configs:
                cpu0 = time.process_time()
                report = replay([bag], root / 'kitti_out', config, gt=groundtruth_path(bag))
                print(_row('kitti00 (77 kf)', label, report, time.process_time() - cpu0))
    print(f'(simulating and writing the street bag took {sim_s:.2f} s; the first, warm-up '
          f'replay of 30 keyframes took {warm_s:.2f} s, imports included)')
    if args.check and not ok:
        print('check failed: street ATE ratio > 0.3 or slower than 10x real time')
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
