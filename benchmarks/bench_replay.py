"""Replay benchmark: accuracy and throughput on the simulated street and the KITTI-00 tracks.

Run::

    python benchmarks/bench_replay.py                 # street 200 keyframes + KITTI-00, sliding
    python benchmarks/bench_replay.py --modes sliding global   # global mode too (slow)
    python benchmarks/bench_replay.py --keyframes 500 --no-kitti --check

For each case it writes the bag, replays it (global and/or sliding mode) and prints the
front-end and optimized ATE (Sim(3)-aligned RMSE), their ratio, and the throughput as a
multiple of real time (bag duration / replay wall time; the street runs at 10 keyframes/s),
with the replay's CPU time (process time) as a load-independent figure.
``--check`` exits non-zero unless the street's optimized ATE is at most 30 % of the
front-end's and the replay runs at least 10x faster than real time.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile
import time

from pmba_ros._heap import keep_freed_memory
from pmba_ros.backend.config import BackendConfig
from pmba_ros.replay import ReplayReport, replay
from pmba_ros.sim.bag import groundtruth_path, write_sequence_bag
from pmba_ros.sim.sequence import simulate_sequence

SHARED = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def _row(name: str, mode: str, report: ReplayReport, cpu_s: float) -> str:
    """Format one result row."""
    acc = report.accuracy or {}
    ratio = acc.get('ate_ratio')
    return (f'{name:<18}{mode:<9}{report.keyframes_in:>6}{report.keyframes_out:>7}'
            f'{acc.get("ate_frontend_m", float("nan")):>11.4f}'
            f'{acc.get("ate_optimized_m", float("nan")):>11.4f}'
            f'{(ratio if ratio is not None else float("nan")):>8.3f}'
            f'{report.bag_duration_s:>8.1f}{report.wall_s:>8.2f}'
            f'{cpu_s:>8.2f}{report.realtime_factor:>8.2f}x')


def main() -> int:
    """Run the benchmark and print the table."""
    keep_freed_memory()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--keyframes', type=int, default=200)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--modes', nargs='+', default=['sliding'],
                        choices=['sliding', 'global'])
    parser.add_argument('--no-kitti', action='store_true')
    parser.add_argument('--check', action='store_true')
    args = parser.parse_args()
    header = (f'{"case":<18}{"mode":<9}{"kf_in":>6}{"kf_out":>7}{"ATE fe":>11}{"ATE opt":>11}'
              f'{"ratio":>8}{"data s":>8}{"wall s":>8}{"cpu s":>8}{"speed":>9}')
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
        for mode in args.modes:
            cpu0 = time.process_time()
            report = replay([street], root / f'street_{mode}', BackendConfig(mode=mode),
                            gt=groundtruth_path(street))
            print(_row(f'street {args.keyframes}', mode, report, time.process_time() - cpu0))
            acc = report.accuracy or {}
            if (acc.get('ate_ratio') or 1.0) > 0.3 or report.realtime_factor < 10.0:
                ok = False
        kitti = SHARED / 'kitti00_stereo_vo'
        if not args.no_kitti and kitti.exists():
            from pmba_ros.cli.main import main as pmba
            bag = root / 'kitti00'
            pmba(['import-tracks', '--out', str(bag)])
            for mode in args.modes:
                cpu0 = time.process_time()
                report = replay([bag], root / f'kitti_{mode}', BackendConfig(mode=mode),
                                gt=groundtruth_path(bag))
                print(_row('kitti00 (77 kf)', mode, report, time.process_time() - cpu0))
    print(f'(simulating and writing the street bag took {sim_s:.2f} s)')
    if args.check and not ok:
        print('check failed: street ATE ratio > 0.3 or slower than 10x real time')
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
