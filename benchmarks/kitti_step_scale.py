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
"""KITTI-00 frames 0-76: how long each step is by the stereo points, the VO and the GT.

Run::

    python benchmarks/kitti_step_scale.py

For every pair of consecutive frames it aligns the stereo-triangulated points the two
frames share (``VO_stereo_factors00s.txt`` stores each in its observing camera's frame;
Horn's method on the points within 30 m, refit on the 60 % closest) and prints that step's
length over the ground truth's, beside the VO's. No optimization is involved: it shows the
metric scale the images themselves give, which a stereo back-end can only follow.

A second table checks the right image against the left one and the ground truth: each
landmark seen from at least four frames spanning 3 m is triangulated from its left-image
rays at the ground-truth poses, and the disparity that depth predicts is compared with the
measured one (uL - uR), per block of six frames and per depth band. A ratio that holds
across depths is a scale the two sources disagree on, not a disparity offset: no
image-only method can see it.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
import sys

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def horn(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return R, t minimizing |b - (R a + t)| over the rows (Horn / Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, cb - rot @ ca


def stereo_step(a: np.ndarray, b: np.ndarray) -> float:
    """Return the length of the step that moves the points ``a`` onto ``b``."""
    rot, t = horn(a, b)
    err = np.linalg.norm(b - (a @ rot.T + t), axis=1)
    keep = err <= np.percentile(err, 60)
    return float(np.linalg.norm(horn(a[keep], b[keep])[1]))


def gt_disparity_ratios(factors: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Return rows (frame, depth, measured / GT-predicted disparity) of the tracked landmarks."""
    calib = np.loadtxt(SHARED / 'kitti00_stereo_vo' / 'VO_calibration00s.txt')
    f, cx, cy, baseline = calib[0], calib[3], calib[4], calib[5]
    cam, lmk = factors[:, 0].astype(int), factors[:, 1].astype(int)
    rays = np.stack([(factors[:, 2] - cx) / f, (factors[:, 4] - cy) / f,
                     np.ones(cam.shape[0])], axis=1)
    rays_w = np.einsum('nij,nj->ni', gt[cam, :, :3], rays)
    rays_w /= np.linalg.norm(rays_w, axis=1, keepdims=True)
    centers = gt[cam, :, 3]
    rows = []
    order = np.argsort(lmk, kind='stable')
    for idx in np.split(order, np.flatnonzero(np.diff(lmk[order])) + 1):
        span = np.ptp(centers[idx], axis=0)
        if idx.shape[0] < 4 or np.linalg.norm(span) < 3.0:
            continue
        # Least squares over the rays: sum (I - d d^T) (X - c) = 0.
        proj = np.eye(3) - np.einsum('ni,nj->nij', rays_w[idx], rays_w[idx])
        point = np.linalg.solve(proj.sum(axis=0), np.einsum('nij,nj->i', proj, centers[idx]))
        depth = np.einsum('nji,nj->ni', gt[cam[idx], :, :3], point - centers[idx])[:, 2]
        good = depth > 0
        measured = factors[idx[good], 2] - factors[idx[good], 3]
        rows.append(np.stack([cam[idx[good]], depth[good],
                              measured * depth[good] / (f * baseline)], axis=1))
    return np.concatenate(rows)


def print_disparity_table(ratios: np.ndarray, n: int) -> None:
    """Print the median measured / GT-predicted disparity per frame block and depth band."""
    bands = ((5.0, 15.0), (15.0, 30.0), (30.0, 60.0))
    print('\nmeasured / GT-predicted disparity (left tracks triangulated at the GT poses)')
    print(f'{"frames":>10}' + ''.join(f'{f"{lo:.0f}-{hi:.0f} m":>12}' for lo, hi in bands))
    for first in range(0, n, 6):
        block = (ratios[:, 0] >= first) & (ratios[:, 0] < first + 6)
        cells = []
        for lo, hi in bands:
            sel = block & (ratios[:, 1] >= lo) & (ratios[:, 1] < hi)
            cells.append(f'{np.median(ratios[sel, 2]):>12.3f}' if np.count_nonzero(sel) >= 20
                         else f'{"-":>12}')
        print(f'{first:>4} -{min(first + 5, n - 1):>3}' + ''.join(cells))


def main() -> int:
    """Print the per-step length ratios; 1 without the shared data."""
    kitti = SHARED / 'kitti00_stereo_vo'
    if not kitti.is_dir():
        print(f'needs {kitti}', file=sys.stderr)
        return 1
    factors = np.loadtxt(kitti / 'VO_stereo_factors00s.txt')
    vo = np.loadtxt(kitti / 'VO_camera_poses00s.txt')[:, 1:].reshape(-1, 4, 4)
    n = vo.shape[0]
    gt = np.loadtxt(SHARED / 'trajectories' / 'evo' / 'KITTI_00_gt.txt')[:n].reshape(-1, 3, 4)
    step_gt = np.linalg.norm(np.diff(gt[:, :, 3], axis=0), axis=1)
    step_vo = np.linalg.norm(np.diff(vo[:, :3, 3], axis=0), axis=1)
    points: dict[int, dict[int, np.ndarray]] = defaultdict(dict)
    for cam, lmk, xyz in zip(factors[:, 0].astype(int), factors[:, 1].astype(int),
                             factors[:, 5:8], strict=True):
        points[cam][lmk] = xyz
    step_stereo = np.full(n - 1, np.nan)
    for k in range(n - 1):
        shared = [m for m in points[k] if m in points[k + 1]]
        a = np.array([points[k][m] for m in shared])
        b = np.array([points[k + 1][m] for m in shared])
        near = (a[:, 2] < 30.0) & (b[:, 2] < 30.0)
        if np.count_nonzero(near) >= 10:
            step_stereo[k] = stereo_step(a[near], b[near])
    print(f'{"frames":>10}{"GT m":>9}{"VO / GT":>10}{"stereo / GT":>13}')
    for k in range(n - 1):
        print(f'{k:>4} -{k + 1:>3}{step_gt[k]:>9.3f}{step_vo[k] / step_gt[k]:>10.3f}'
              f'{step_stereo[k] / step_gt[k]:>13.3f}')
    for label, rows in (('frames 0-12', slice(0, 12)), ('all', slice(None))):
        print(f'median over {label}: VO / GT {np.median(step_vo[rows] / step_gt[rows]):.3f}, '
              f'stereo / GT {np.nanmedian(step_stereo[rows] / step_gt[rows]):.3f}')
    print_disparity_table(gt_disparity_ratios(factors, gt), n)
    return 0


if __name__ == '__main__':
    sys.exit(main())
