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
"""Benchmark of the global initialization: wall time of each stage (not a test).

Usage::

    python benchmarks/bench_init.py                 # every case below
    python benchmarks/bench_init.py --only street50 --only photos50   # a 50-keyframe street
                                                    # batch, a 50-camera ring (~30k obs;
                                                    # photos50_60k: ~60k obs)
    python benchmarks/bench_init.py --only ladybug --repeat 3 --json out.json

BLAS thread pools are set as ``pmba`` sets them (:func:`pmba_ros._process.tune_process`):
one thread, more only for large dense factorizations.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import json
import logging
import os
from pathlib import Path
import time
from typing import Any, TYPE_CHECKING

from pmba_ros._process import tune_process

if TYPE_CHECKING:
    from pmba_ros.core.problem import BAProblem

logger = logging.getLogger('bench_init')

DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def _ladybug() -> BAProblem | None:
    from pmba_ros.io.bal import read_bal

    path = DATA / 'bal' / 'problem-49-7776-pre.txt'
    return read_bal(path) if path.exists() else None


def _street200() -> BAProblem | None:
    from pmba_ros.sim.scenes import street_scene

    return street_scene(0, n_cams=200, n_points=20000, noise_px=0.5, max_track_length=15,
                        jitter_m=0.05, jitter_deg=1.0).gt


def _street50() -> BAProblem | None:
    from pmba_ros.sim.scenes import street_scene

    return street_scene(0, n_cams=50, n_points=3000, noise_px=0.5, max_track_length=15,
                        jitter_m=0.05, jitter_deg=1.0).gt


def _photos50(n_points: int = 2500) -> BAProblem | None:
    from pmba_ros.sim.scenes import synthetic_large

    # A closer ring and wider incidence than the defaults: a pair then sees a curved patch
    # with depth spread (the default's near-planar patches leave ~1 px of parallax).
    return synthetic_large(0, n_cams=50, n_points=n_points, noise_px=0.5,
                           max_incidence_deg=60, radius_m=5.0).gt


CASES: dict[str, Callable[[], BAProblem | None]] = {
    'ladybug': _ladybug, 'street200': _street200, 'street50': _street50,
    'photos50': _photos50, 'photos50_60k': lambda: _photos50(5000)}


def run_case(name: str, repeat: int) -> dict[str, Any] | None:
    """Run global_init ``repeat`` times on one case; return the best total and its stages."""
    from pmba_ros.init.pipeline import global_init

    problem = CASES[name]()
    if problem is None:
        logger.warning('%s: data not available, skipped', name)
        return None
    best: dict[str, Any] | None = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = global_init(problem)
        wall = time.perf_counter() - t0
        report = res.to_report()
        if best is None or wall < best['wall_s']:
            best = {'case': name, 'wall_s': wall, 'time_s': report['time_s'],
                    'n_cams': problem.n_cams, 'n_feats': problem.n_feats,
                    'n_obs': problem.n_obs, 'summary': report['summary'],
                    'ba': report['ba']}
    return best


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print one table per case."""
    tune_process()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', choices=sorted(CASES), action='append')
    parser.add_argument('--repeat', type=int, default=1)
    parser.add_argument('--json', type=Path)
    args = parser.parse_args(argv)
    from pmba_ros.init.pipeline import STAGES
    logging.basicConfig(level=logging.WARNING)
    print(f'cpu_count={os.cpu_count()}, load={os.getloadavg()[0]:.2f}')
    results = []
    for name in args.only or sorted(CASES):
        out = run_case(name, args.repeat)
        if out is None:
            continue
        results.append(out)
        head = (f"{name}: {out['n_cams']} cams, {out['n_feats']} feats, {out['n_obs']} obs; "
                f"total {out['wall_s']:.2f} s, final rms {out['summary']['final_rms_px']:.4f}"
                f" px, BA iterations {out['ba']['iterations']}")
        lines = [head]
        lines += [f'  {stage:<11s} {out["time_s"][stage]:8.3f} s' for stage in STAGES]
        print('\n'.join(lines))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
