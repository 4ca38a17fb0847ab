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
"""KITTI-00 frames 0-76: a stereo bundle adjustment independent of pmba_ros, against the VO.

Run::

    python benchmarks/kitti_stereo_peer.py [--optimized OUT/keyframes_optimized.tum]

A plain XYZ stereo BA (``scipy.optimize.least_squares``, trust-region reflective, robust
loss, the Jacobian by finite differences over its sparsity) over ``VO_stereo_factors00s.txt``
(left and right pixel of every observation), started from the stereo VO's poses and the
file's own points, the first pose held: GTSAM's StereoVOExample_large problem. Its ATE
against KITTI's ground truth, beside the VO's (and a pmba_ros replay's, if given), shows
how far any estimator that follows these stereo measurements can get below the VO.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

import numpy as np
from pmba_ros.eval.metrics import ate, rpe
from pmba_ros.eval.trajectory import read_tum, Trajectory
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

SHARED = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def stereo_residuals(x: np.ndarray, n_poses: int, cam: np.ndarray, lmk: np.ndarray,
                     meas: np.ndarray, calib: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Return predicted minus measured (uL, uR, v) of every observation, flattened."""
    f, cx, cy, baseline = calib[0], calib[3], calib[4], calib[5]
    poses = np.concatenate([first[None], x[:6 * (n_poses - 1)].reshape(-1, 6)])
    points = x[6 * (n_poses - 1):].reshape(-1, 3)
    rot = Rotation.from_rotvec(poses[cam, :3])
    p = rot.inv().apply(points[lmk] - poses[cam, 3:])   # in the camera: R_wc^T (X - c)
    z = p[:, 2]
    pred = np.stack([f * p[:, 0] / z + cx, f * (p[:, 0] - baseline) / z + cx,
                     f * p[:, 1] / z + cy], axis=1)
    out: np.ndarray = (pred - meas).reshape(-1)
    return out


def sparsity(n_poses: int, n_points: int, cam: np.ndarray, lmk: np.ndarray) -> lil_matrix:
    """Return which parameters each residual depends on (3 rows per observation)."""
    m = 3 * cam.shape[0]
    A = lil_matrix((m, 6 * (n_poses - 1) + 3 * n_points), dtype=int)
    rows = np.arange(cam.shape[0])
    free = cam > 0
    for r in range(3):
        for k in range(6):
            A[3 * rows[free] + r, 6 * (cam[free] - 1) + k] = 1
        for k in range(3):
            A[3 * rows + r, 6 * (n_poses - 1) + 3 * lmk + k] = 1
    return A


def trajectory(rotvec: np.ndarray, centers: np.ndarray) -> Trajectory:
    """Return camera poses as a trajectory stamped 0.1 s apart (the frames' index)."""
    n = centers.shape[0]
    return Trajectory(0.1 * np.arange(n), centers, Rotation.from_rotvec(rotvec).as_matrix())


def main() -> int:
    """Solve the peer BA and print ATE / RPE against the ground truth; 1 without the data."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--optimized', type=Path,
                        help='a pmba_ros replay keyframes_optimized.tum of the same frames')
    parser.add_argument('--loss', default='huber', help='least_squares loss (default: huber)')
    parser.add_argument('--f-scale', type=float, default=1.0, help='its scale, px')
    parser.add_argument('--max-nfev', type=int, default=400, help='evaluations at most')
    args = parser.parse_args()
    kitti = SHARED / 'kitti00_stereo_vo'
    if not kitti.is_dir():
        print(f'needs {kitti}', file=sys.stderr)
        return 1
    calib = np.loadtxt(kitti / 'VO_calibration00s.txt')
    factors = np.loadtxt(kitti / 'VO_stereo_factors00s.txt')
    vo = np.loadtxt(kitti / 'VO_camera_poses00s.txt')[:, 1:].reshape(-1, 4, 4)
    n = vo.shape[0]
    gt = np.loadtxt(SHARED / 'trajectories' / 'evo' / 'KITTI_00_gt.txt')[:n].reshape(-1, 3, 4)
    cam = factors[:, 0].astype(int)
    ids, lmk = np.unique(factors[:, 1].astype(int), return_inverse=True)
    meas = factors[:, [2, 3, 4]]
    rotvec = Rotation.from_matrix(vo[:, :3, :3]).as_rotvec()
    centers = vo[:, :3, 3]
    # Each point from its first observation's stereo XYZ, in the world by the VO pose.
    first_obs = np.unique(lmk, return_index=True)[1]
    xyz = factors[first_obs, 5:8]
    points = np.einsum('nij,nj->ni', vo[cam[first_obs], :3, :3], xyz) + centers[cam[first_obs]]
    first = np.concatenate([rotvec[0], centers[0]])
    x0 = np.concatenate([np.column_stack([rotvec[1:], centers[1:]]).reshape(-1),
                         points.reshape(-1)])
    fun_args = (n, cam, lmk, meas, calib, first)
    t0 = time.perf_counter()
    res = least_squares(stereo_residuals, x0, jac_sparsity=sparsity(n, ids.shape[0], cam, lmk),
                        loss=args.loss, f_scale=args.f_scale, x_scale='jac', method='trf',
                        tr_solver='lsmr', args=fun_args, max_nfev=args.max_nfev, verbose=0)
    r0 = stereo_residuals(x0, *fun_args)
    print(f'{cam.shape[0]} stereo observations of {ids.shape[0]} landmarks in {n} frames; '
          f'{res.nfev} evaluations, {time.perf_counter() - t0:.0f} s, status {res.status}; '
          f'rms {np.sqrt(np.mean(r0 ** 2)):.3f} -> {np.sqrt(np.mean(res.fun ** 2)):.3f} px')
    poses = np.concatenate([first[None], res.x[:6 * (n - 1)].reshape(-1, 6)])
    truth = Trajectory(0.1 * np.arange(n), gt[:, :, 3], gt[:, :, :3])
    rows = [('stereo VO', trajectory(rotvec, centers)),
            ('peer BA', trajectory(poses[:, :3], poses[:, 3:]))]
    if args.optimized is not None:
        rows.append(('pmba_ros', read_tum(args.optimized)))
    print(f'{"":>10}{"ATE SE(3) m":>13}{"ATE Sim(3) m":>14}{"RPE m":>9}')
    for name, est in rows:
        est = Trajectory(truth.stamps_s[:len(est)], est.positions_xyz, est.R_wc)
        se3, sim3 = ate(est, truth, 'se3').rmse, ate(est, truth, 'sim3').rmse
        print(f'{name:>10}{se3:>13.4f}{sim3:>14.4f}{rpe(est, truth, align="se3").rmse:>9.4f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
