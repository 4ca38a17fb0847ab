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
"""The back-end's accuracy beside what the images alone allow (not a test).

Run::

    python benchmarks/bench_vision_limit.py --scenario street --keyframes 60 --seeds 0-11
    python benchmarks/bench_vision_limit.py --scenario loop aerial --keyframes 60 --cameras 2

Per simulated recording (``pmba simulate --scenario S --keyframes N --seed K --extrinsic
euroc [--cameras 2]``, replayed with the defaults as ``pmba replay`` runs it), the ATE and
RPE ratios to the front-end's of:

* the back-end (``pmba replay``);
* the vision limit: a bundle adjustment of every observation of the recording, no
  front-end motion, started at the ground truth (poses and points) and run to convergence.
  Its error is the images' own: no estimator that trusts the images more than the
  front-end gets below it, and where it is above the front-end (a drone's stereo pair from
  tens of metres up) the front-end's motion has to carry the result.

One camera: Sim(3) alignment, a monocular map has no scale; two: SE(3). Body poses (EuRoC's
cam0 extrinsic) throughout. One row per recording as it finishes.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import tempfile

import numpy as np
from pmba_ros.backend.config import BackendConfig
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import make_problem, Parameterization, Rig
from pmba_ros.core.solve import solve, SolveOptions
from pmba_ros.eval.metrics import ate, rpe
from pmba_ros.eval.trajectory import read_tum, Trajectory
from pmba_ros.replay import replay
from pmba_ros.sim.bag import EUROC_CAM0, groundtruth_path, write_sequence_bag
from pmba_ros.sim.rig import add_camera, EUROC_CAM1
from pmba_ros.sim.sequence import SimSequence, simulate_sequence

CAMERA_INFOS = ('/camera_info', '/camera1/camera_info')


def recording(scenario: str, keyframes: int, seed: int, cameras: int) -> SimSequence:
    """Return the sequence ``pmba simulate ... --extrinsic euroc --cameras C`` writes."""
    seq = simulate_sequence(scenario, n_keyframes=keyframes, seed=seed)
    if cameras == 2:
        seq = add_camera(seq, EUROC_CAM0.inverse() @ EUROC_CAM1, camera_id=1, seed=seed + 1)
    return seq


def vision_limit(seq: SimSequence, cameras: int) -> Trajectory:
    """Return the body trajectory of the images alone, converged from the ground truth."""
    rig = None
    if cameras == 2:
        T_c0c1 = EUROC_CAM0.inverse() @ EUROC_CAM1
        rig = Rig(np.stack([np.eye(3), T_c0c1.rotation]),
                  np.stack([np.zeros(3), T_c0c1.translation]))
    frames = seq.frames
    cam = np.concatenate([np.full(f.feature_ids.shape[0], i) for i, f in enumerate(frames)])
    feat = np.concatenate([f.feature_ids for f in frames])
    camera = np.concatenate([f.camera_ids for f in frames])
    xy = np.concatenate([f.normalized for f in frames if f.normalized is not None])
    keep = camera < cameras
    cam, feat, camera, xy = cam[keep], feat[keep], camera[keep], xy[keep]
    K = seq.camera
    M = len(seq)
    bearings = np.column_stack([xy, np.ones(xy.shape[0])])
    bearings /= np.linalg.norm(bearings, axis=1)[:, None]
    fixed = np.zeros(M, bool)
    fixed[0] = True
    problem = make_problem(seq.R_wc_gt, seq.centers_gt,
                           Intrinsics.uniform(M, K.fx, K.fy, K.cx, K.cy), cam, feat,
                           np.column_stack([K.fx * xy[:, 0] + K.cx, K.fy * xy[:, 1] + K.cy]),
                           bearings_c=bearings, points_w=seq.points_w, fixed=fixed,
                           n_feats=seq.points_w.shape[0], camera=camera if rig else None,
                           rig=rig)
    result = solve(problem, SolveOptions(param=Parameterization.PMBA, max_iterations=100))
    if not result.converged:
        msg = f'the vision-only BA did not converge in {result.iterations} iterations'
        raise RuntimeError(msg)
    R_wb, C_wb = EUROC_CAM0.inverse().apply_to_poses(result.R_wc, result.centers_w)
    return Trajectory(seq.stamps_ns.astype(np.float64) * 1e-9, C_wb, R_wb)


def run(scenario: str, keyframes: int, seed: int, cameras: int, work: Path) -> str:
    """Replay one recording and solve its vision limit; return its table row."""
    seq = recording(scenario, keyframes, seed, cameras)
    bag = work / f'{scenario}{keyframes}s{seed}c{cameras}'
    write_sequence_bag(seq, bag, extrinsic=EUROC_CAM0,
                       rig_extrinsics=[EUROC_CAM1] if cameras == 2 else [])
    align = 'se3' if cameras == 2 else 'sim3'
    config = (BackendConfig(num_cams=2, camera_info_topics=CAMERA_INFOS) if cameras == 2
              else None)
    out = bag.with_name(bag.name + '_out')
    replay([bag], out, config, align=align)
    gt = read_tum(groundtruth_path(bag))
    front_end = read_tum(out / 'keyframes_frontend.tum')
    cells = [scenario, str(keyframes), str(seed), str(cameras)]
    fe_ate, fe_rpe = ate(front_end, gt, align).rmse, rpe(front_end, gt, align=align).rmse
    for est in (read_tum(out / 'keyframes_optimized.tum'), vision_limit(seq, cameras)):
        cells += [f'{ate(est, gt, align).rmse / fe_ate:.3f}',
                  f'{rpe(est, gt, align=align).rmse / fe_rpe:.3f}']
    return '| ' + ' | '.join(cells) + ' |'


def seeds(text: str) -> list[int]:
    """Parse ``0-3`` or ``0,2,5``."""
    if '-' in text:
        first, last = text.split('-')
        return list(range(int(first), int(last) + 1))
    return [int(s) for s in text.split(',')]


def main(argv: list[str] | None = None) -> int:
    """Print one table row per scenario, keyframe count and seed."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--scenario', nargs='+', default=['street'],
                        choices=('street', 'aerial', 'loop'))
    parser.add_argument('--keyframes', nargs='+', type=int, default=[60])
    parser.add_argument('--seeds', type=seeds, default=[0, 1, 2, 3], help='e.g. 0-11 or 0,5')
    parser.add_argument('--cameras', type=int, choices=(1, 2), default=1)
    args = parser.parse_args(argv)
    print('| scenario | keyframes | seed | cameras | back-end ATE | back-end RPE '
          '| vision limit ATE | vision limit RPE |')
    print('|---|---|---|---|---|---|---|---|')
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in args.scenario:
            for n in args.keyframes:
                for seed in args.seeds:
                    print(run(scenario, n, seed, args.cameras, Path(tmp)), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
