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
"""The global initialization's pairs stage: the joins of tracks into pairs, numpy and compiled.

Run::

    python benchmarks/bench_init_pairs.py [FILE ...] [--repeat 2]

For each collection (BAL, COLMAP or any format ``pmba solve`` reads; default: a simulated
street of 300 images with 20,000 points, 2.3 M observations, whose far points are seen by
every image), in one process: the
co-visibility counts, the sampled join that ranks the candidate pairs and the full join of
the pairs tried, with the numpy code and with the compiled loops (the same arrays), then the
whole stage (``pair_selection.estimate_pairs``: the joins, the 5-point RANSACs and the
planar pairs' votes). Each time is the best of ``--repeat`` runs; the first compiled run
loads or compiles the loops, and is counted too when ``--repeat 1``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import time
from typing import Any

import numpy as np
from pmba_ros.cli.solve import load_problem
from pmba_ros.core.engine import compiled_available
from pmba_ros.core.problem import BAProblem
from pmba_ros.init import covisibility, pair_selection
from pmba_ros.init.options import InitOptions
from pmba_ros.sim.scenes import street_scene


def _best(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def _joins(problem: BAProblem, engine: str, repeat: int) -> tuple[list[float], int]:
    """Return the times of the counts, the sampled join and the full join, and the sample."""
    o, M = problem.obs, problem.n_cams
    t_counts, counts = _best(lambda: covisibility.covisibility_counts(
        o.cam_idx, o.feat_idx, M, engine), repeat)
    candidates = counts >= InitOptions().min_pair_matches
    t_sample, sample = _best(lambda: covisibility.pair_correspondences(
        o.cam_idx, o.feat_idx, M, 0, pairs=candidates, counts=counts,
        max_per_pair=pair_selection.PARTNER_SAMPLE, engine=engine), repeat)
    tried = np.zeros_like(candidates)
    # Every camera's ten most co-visible partners, as the stage's cap tries about as many.
    keep = covisibility.top_partners(sample.cam_a, sample.cam_b,
                                     counts[sample.cam_a, sample.cam_b].astype(float), M, 10)
    tried[sample.cam_a[keep], sample.cam_b[keep]] = True
    t_full, _ = _best(lambda: covisibility.pair_correspondences(
        o.cam_idx, o.feat_idx, M, 0, pairs=tried, counts=counts, engine=engine), repeat)
    return [t_counts, t_sample, t_full], int(sample.obs_a.shape[0])


def main() -> None:
    """Print one block per collection."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('files', nargs='*')
    parser.add_argument('--repeat', type=int, default=2)
    args = parser.parse_args()
    problems = ({f: load_problem(f, 'auto') for f in args.files} if args.files else
                {'street of 300 images': street_scene(0, n_cams=300, n_points=20000).gt})
    engines = ['numpy', 'compiled'] if compiled_available() else ['numpy']
    for name, problem in problems.items():
        longest = int(np.bincount(problem.obs.feat_idx).max())
        print(f'{name}: {problem.n_cams} cameras, {problem.n_obs} observations, tracks up '
              f'to {longest} views')
        rows = {}
        for engine in engines:
            rows[engine], sampled = _joins(problem, engine, args.repeat)
            print(f'  {engine:8s} counts {rows[engine][0]:7.2f} s  sampled join '
                  f'{rows[engine][1]:7.2f} s ({sampled} kept)  full join {rows[engine][2]:7.2f} s')
        if len(rows) == 2:
            ratio = [n / c for n, c in zip(rows['numpy'], rows['compiled'], strict=True)]
            print(f'  numpy / compiled: counts {ratio[0]:.1f}x, sampled join {ratio[1]:.1f}x, '
                  f'full join {ratio[2]:.1f}x')
        stage, (pairs, _, _) = _best(lambda p=problem: pair_selection.estimate_pairs(
            p, InitOptions()), args.repeat)
        print(f'  pairs stage {stage:7.2f} s, {pairs.n_pairs} pairs', flush=True)


if __name__ == '__main__':
    main()
