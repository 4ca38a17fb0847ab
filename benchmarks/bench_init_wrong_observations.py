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
"""Global initialization with wrong single observations (wrong matches inside good tracks).

Run::

    python benchmarks/bench_init_wrong_observations.py [--fractions 0 0.02 0.05 0.1 0.3]

For simulated streets of 30 and 100 cameras (tracks up to 20 and 50 views, shuffled: an
unordered collection), a fraction of the observations is moved to random pixels
(:func:`pmba_ros.sim.variants.wrong_observations`) and ``global_init`` runs with a Cauchy
loss. One row per case: cameras placed, their largest centre error after a similarity
alignment over the scene's extent, the final RMS and the BA's noise estimate, the
observations dropped off their pairs' epipolar lines and after the BA, and the time.
"""

from __future__ import annotations

import argparse
import time

from _truth import largest_centre_error
from pmba_ros.core.problem import BAProblem
from pmba_ros.core.solve import SolveOptions
from pmba_ros.init.pipeline import global_init, InitOptions
from pmba_ros.sim import variants
from pmba_ros.sim.scenes import shuffle_cameras, street_scene


def _row(name: str, truth: BAProblem, fraction: float) -> str:
    moved = variants.wrong_observations(truth, fraction, seed=1).problem
    t0 = time.perf_counter()
    res = global_init(moved, InitOptions(solve_options=SolveOptions(loss='cauchy')))
    seconds = time.perf_counter() - t0
    report = res.report
    return (f'{name:8s} {fraction:6.2f} {res.camera_index.shape[0]:3d}/{truth.n_cams:<3d} '
            f'{largest_centre_error(truth, res):10.5f} {res.solve.final_rms_px:9.3f} '
            f'{res.solve.noise_px:6.3f} '
            f'{report["summary"]["observations_off_their_pairs"]:7d} '
            f'{report["ba"]["observations_off_after_ba"]:6d} {seconds:6.1f}')


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--fractions', type=float, nargs='+',
                        default=[0.0, 0.02, 0.05, 0.1, 0.3])
    args = parser.parse_args()
    scenes = {f'street{n}': shuffle_cameras(street_scene(seed=3, n_cams=n, n_points=20 * n),
                                            seed=1).gt for n in (30, 100)}
    print('scene    wrong  cams   err/extent  rms px  noise  off-pairs after-ba   time s')
    for name, truth in scenes.items():
        for fraction in args.fractions:
            print(_row(name, truth, fraction), flush=True)


if __name__ == '__main__':
    main()
