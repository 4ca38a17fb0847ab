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
"""Global initialization of survey flights over flat ground, with and without the pose vote.

Run::

    python benchmarks/bench_init_flat_ground.py [--seeds 10] [--points 1000] [--relief 0 0.5 2]

For nadir survey flights (:func:`pmba_ros.sim.scenes.aerial_scene`, 6 lines of 6 images at
50 m, 0.5 px noise) over ground of the given relief (m, standard deviation),
``global_init`` runs twice on the same tracks: as it is, and with every EG pair kept on the
pose its RANSAC returned (:func:`pmba_ros.init.planar_ambiguity.resolved` bypassed: the
pipeline before pairs had two poses). One row per flight and run: pairs found, pairs with
a second pose and turned, pairs the spanning tree disagrees with, BA invocations, the
largest camera centre error after a similarity alignment over the flight's extent, the
final RMS, and the time. The last lines count the flights each run places within 0.5 % of
the extent.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import time
from typing import Any

from _truth import largest_centre_error
from pmba_ros.core.problem import BAProblem
from pmba_ros.errors import InitError
from pmba_ros.init import planar_ambiguity
from pmba_ros.init.pipeline import global_init
from pmba_ros.sim.scenes import aerial_scene

Resolver = Callable[..., Any]


def _run(truth: BAProblem) -> tuple[str, float]:
    """Return one row's columns after the scene's, and the error over the extent."""
    t0 = time.perf_counter()
    try:
        res = global_init(truth)
    except InitError as err:
        return f'{"init error: " + str(err)[:60]:>60s}', float('inf')
    seconds = time.perf_counter() - t0
    error = largest_centre_error(truth, res)
    pairs, graph = res.report['pairs'], res.report['view_graph']
    return (f'{pairs["pairs_found"]:5d} {pairs["pairs_with_two_poses"]:5d} '
            f'{pairs["pairs_turned"]:6d} {graph["pairs_tree_inconsistent"]:9d} '
            f'{res.ba_invocations:3d} {error:10.5f} {res.solve.final_rms_px:7.3f} '
            f'{seconds:6.1f}'), error


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--points', type=int, default=1000)
    parser.add_argument('--relief', type=float, nargs='+', default=[0.0, 0.5, 2.0])
    args = parser.parse_args()
    vote: Resolver = planar_ambiguity.resolved

    def ransac_pose(pairs: Any, alt: Any, tol_deg: float) -> Any:
        return pairs, 0

    good = {'vote': 0, 'ransac': 0}
    print('relief seed run     pairs  two  turned  tree-off  BA  err/extent  rms px  time s')
    for relief in args.relief:
        for seed in range(args.seeds):
            truth = aerial_scene(seed, 6, 6, n_points=args.points, relief_m=relief).gt
            for run, resolver in (('vote', vote), ('ransac', ransac_pose)):
                planar_ambiguity.resolved = resolver
                columns, error = _run(truth)
                good[run] += int(error < 0.005)
                print(f'{relief:6.1f} {seed:4d} {run:7s} {columns}', flush=True)
    planar_ambiguity.resolved = vote
    n = len(args.relief) * args.seeds
    for run, count in good.items():
        print(f'{run}: {count} of {n} flights within 0.5 % of their extent')


if __name__ == '__main__':
    main()
