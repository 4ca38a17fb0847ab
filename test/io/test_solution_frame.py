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
"""A solution written back onto its model's frame (``pmba solve MODEL --out``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pmba_ros.cli.main import main
from pmba_ros.core import so3
from pmba_ros.io import colmap
from pmba_ros.io.solution_frame import model_similarity
from pmba_ros.sim.scenes import street_scene


def _turn(rng: np.random.Generator) -> np.ndarray:
    return so3.exp(rng.normal(size=3))


def test_the_similarity_of_cameras_on_a_line_is_recovered() -> None:
    """Centres on a line fix no turn about it: the orientations do."""
    rng = np.random.default_rng(4)
    R_wc = so3.exp(rng.normal(scale=0.1, size=(6, 3)))
    centers = np.outer(np.arange(6.0), [1.0, 0.0, 0.0])
    R, t, s = _turn(rng), rng.normal(size=3), 2.5
    sim = model_similarity(R_wc, centers, R @ R_wc, s * centers @ R.T + t)
    np.testing.assert_allclose(sim.rotation, R, atol=1e-12)
    np.testing.assert_allclose(sim.translation, t, atol=1e-12)
    assert abs(sim.scale - s) < 1e-12
    rigid = model_similarity(R_wc, centers, R @ R_wc, centers @ R.T + t, with_scale=False)
    assert rigid.scale == 1.0
    np.testing.assert_allclose(rigid.apply(centers), centers @ R.T + t, atol=1e-12)


def test_coincident_centres_take_the_scale_from_the_points() -> None:
    """A panorama's centres coincide: the points give the scale and the translation."""
    rng = np.random.default_rng(5)
    R_wc = so3.exp(rng.normal(size=(5, 3)))
    centers = np.tile([1.0, 2.0, 3.0], (5, 1))
    points = rng.normal(size=(20, 3)) * 10
    R, t, s = _turn(rng), rng.normal(size=3), 0.5
    sim = model_similarity(R_wc, centers, R @ R_wc, s * centers @ R.T + t,
                           points=(points, s * points @ R.T + t))
    assert abs(sim.scale - s) < 1e-12
    np.testing.assert_allclose(sim.translation, t, atol=1e-12)


def test_a_street_model_is_refined_in_place(tmp_path: Path) -> None:
    """`solve MODEL --out` keeps a street model's frame: no turn about the line of travel."""
    scene = street_scene(seed=3, n_cams=8, n_points=200, rot_noise_deg=0.3, pos_noise_m=0.01,
                         point_noise_rel=0.01)
    src, out = tmp_path / 'in', tmp_path / 'out'
    colmap.write_colmap(src, colmap.from_problem(scene.start))
    assert main(['solve', str(src), '--quiet', '--out', str(out)]) == 0
    before, _ = colmap.to_problem(colmap.read_colmap(src))
    after, _ = colmap.to_problem(colmap.read_colmap(out))
    turned = np.degrees(so3.angle(after.R_wc, before.R_wc))
    assert np.max(turned) < 1.0, turned   # the start's noise, not a turn of the frame
    moved = np.linalg.norm(after.centers_w - before.centers_w, axis=1)
    assert np.max(moved) < 0.2, moved
