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
"""Registering left-out cameras by PnP on the placed cameras' triangulated tracks."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.problem import BAProblem, make_problem
from pmba_ros.init.options import InitOptions
from pmba_ros.init.register import register_cameras
from pmba_ros.sim.scenes import street_scene
import pytest


def _scene() -> BAProblem:
    return street_scene(7, n_cams=8, n_points=200, noise_px=0.0).gt


def test_a_left_out_camera_gets_its_pose_back() -> None:
    """Noise-free tracks: both left-out cameras get their poses back (to 1e-6)."""
    gt = _scene()
    placed = np.ones(gt.n_cams, dtype=bool)
    placed[[5, 6]] = False
    R = gt.R_wc.copy()
    C = gt.centers_w.copy()
    R[~placed], C[~placed] = np.eye(3), 0.0
    reg = register_cameras(gt, placed, R, C, min_points=12, max_px=2.0)
    assert sorted(reg.registered.tolist()) == [5, 6] and np.all(reg.cameras)
    np.testing.assert_allclose(reg.centers_w, gt.centers_w, atol=1e-6)
    np.testing.assert_allclose(reg.R_wc, gt.R_wc, atol=1e-6)


def test_wrong_or_too_few_points_place_nothing() -> None:
    """Random bearings for the camera, or fewer points than asked for: it stays out."""
    gt = _scene()
    obs = gt.obs
    rng = np.random.default_rng(0)
    bearings = obs.bearings_c.copy()
    mine = obs.cam_idx == 3
    noise = so3.exp(rng.normal(scale=0.3, size=(int(mine.sum()), 3)))
    bearings[mine] = np.einsum('nij,nj->ni', noise, bearings[mine])
    scrambled = make_problem(gt.R_wc, gt.centers_w, gt.intrinsics, obs.cam_idx,
                             obs.feat_idx, obs.pixels, bearings_c=bearings, n_feats=gt.n_feats)
    placed = np.arange(gt.n_cams) != 3
    reg = register_cameras(scrambled, placed, gt.R_wc, gt.centers_w, min_points=12, max_px=2.0)
    assert reg.registered.tolist() == [] and not reg.cameras[3]
    many = int(np.count_nonzero(mine)) + 1
    reg = register_cameras(gt, placed, gt.R_wc, gt.centers_w, min_points=many, max_px=2.0)
    assert reg.registered.tolist() == []


def test_option_range() -> None:
    """0 switches registration off; fewer than 6 points cannot fix a pose with a check."""
    assert InitOptions(register_min_points=0).register_min_points == 0
    with pytest.raises(ValueError, match='register_min_points'):
        InitOptions(register_min_points=5)
