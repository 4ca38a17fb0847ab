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
"""Pairs that see a plane: their two poses, chosen by triangles (init.planar_ambiguity)."""

from __future__ import annotations

import itertools

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.problem import BAProblem
from pmba_ros.eval.align import umeyama_alignment
from pmba_ros.init import pair_selection, pipeline, planar_ambiguity, two_view
from pmba_ros.init.options import InitOptions
from pmba_ros.sim.scenes import aerial_scene, street_scene
import pytest


def _relative(R_wc: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the true R_cv = R_b^T R_a of pairs (a, b)."""
    return np.einsum('nji,njk->nik', R_wc[b], R_wc[a])


def _pair_errors_deg(pairs: two_view.EGPairs, R_wc: np.ndarray) -> np.ndarray:
    return np.degrees(so3.angle(pairs.R_rel, _relative(R_wc, pairs.cam_a, pairs.cam_b)))


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    return so3.exp(rng.normal(size=(n, 3)))


def test_triangles_are_those_of_the_graph() -> None:
    """Every triangle, once, whichever camera of a pair comes first."""
    rng = np.random.default_rng(0)
    edges = [(a, b) for a, b in itertools.combinations(range(12), 2) if rng.random() < 0.4]
    flip = rng.random(len(edges)) < 0.5
    cam_a = np.array([b if f else a for (a, b), f in zip(edges, flip, strict=True)])
    cam_b = np.array([a if f else b for (a, b), f in zip(edges, flip, strict=True)])
    tri = planar_ambiguity.triangles(cam_a, cam_b)
    got = {frozenset(map(int, t)) for t in tri}
    assert len(got) == tri.shape[0]
    index = {frozenset(e): i for i, e in enumerate(edges)}
    want = {frozenset((index[frozenset((a, b))], index[frozenset((b, c))],
                       index[frozenset((a, c))]))
            for a, b, c in itertools.combinations(range(12), 3)
            if {frozenset((a, b)), frozenset((b, c)), frozenset((a, c))} <= index.keys()}
    assert got == want
    assert len(want) > 10
    for ab, bc, ac in tri:   # ab and bc share the middle camera, ac the outer ones
        lo = lambda p: min(cam_a[p], cam_b[p])  # noqa: E731
        hi = lambda p: max(cam_a[p], cam_b[p])  # noqa: E731
        assert hi(ab) == lo(bc) and lo(ac) == lo(ab) and hi(ac) == hi(bc)


def _graph_with_alternatives(seed: int, noise_deg: float, wrong_first: np.ndarray,
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                        np.ndarray]:
    """Return a complete graph of 8 cameras whose pairs have two rotations, and the truth.

    Every pair's rotations: the true one (with noise) and a wrong one 20-40 degrees away;
    ``wrong_first`` pairs have the wrong one first.
    """
    rng = np.random.default_rng(seed)
    R_wc = _random_rotations(rng, 8)
    a, b = np.array(list(itertools.combinations(range(8), 2))).T
    true = _relative(R_wc, a, b)
    noise = so3.exp(np.deg2rad(noise_deg) * rng.normal(size=(a.size, 3)) / np.sqrt(3.0))
    axis = rng.normal(size=(a.size, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    wrong = so3.exp(np.deg2rad(rng.uniform(20.0, 40.0, a.size))[:, None] * axis) @ true
    first = np.where(wrong_first[:, None, None], wrong, noise @ true)
    second = np.where(wrong_first[:, None, None], noise @ true, wrong)
    return a, b, np.stack([first, second], axis=1), true, R_wc


def test_the_rotations_that_close_triangles_win() -> None:
    """Half the pairs start on a wrong rotation: each of them turns, no other does."""
    wrong_first = np.arange(28) % 2 == 0
    a, b, R_two, _, _ = _graph_with_alternatives(1, 0.3, wrong_first)
    votes, n_tri = planar_ambiguity.triangle_votes(a, b, R_two, np.ones(28, dtype=bool), 2.0)
    assert np.all(n_tri == 6)   # 6 other cameras close a triangle with each pair
    right = np.where(wrong_first, 1, 0)
    assert np.all(votes[np.arange(28), right] == 6)
    assert np.all(votes[np.arange(28), 1 - right] <= 1)
    pairs = two_view.EGPairs(a, b, R_two[:, 0], np.zeros((28, 3)), np.full(28, 50),
                             np.arange(29), np.arange(28), np.arange(28), np.ones(28),
                             np.zeros(28))
    alt = planar_ambiguity.Alternatives(np.arange(28), R_two[:, 1], np.ones((28, 3)))
    resolved, turned = planar_ambiguity.resolved(pairs, alt, 2.0)
    assert turned == 14
    assert np.allclose(resolved.R_rel, np.where(wrong_first[:, None, None], R_two[:, 1],
                                                R_two[:, 0]))


def test_noisy_rotations_keep_the_ransac_pose() -> None:
    """Rotations too noisy for the triangles to close: no pair is turned on a chance vote."""
    wrong_first = np.arange(28) % 2 == 0
    a, b, R_two, _, _ = _graph_with_alternatives(2, 6.0, wrong_first)
    pairs = two_view.EGPairs(a, b, R_two[:, 0], np.zeros((28, 3)), np.full(28, 50),
                             np.arange(29), np.arange(28), np.arange(28), np.ones(28),
                             np.zeros(28))
    alt = planar_ambiguity.Alternatives(np.arange(28), R_two[:, 1], np.ones((28, 3)))
    votes, _ = planar_ambiguity.triangle_votes(a, b, R_two, np.ones(28, dtype=bool), 2.0)
    assert votes.sum() > 0   # a few triangles close by chance
    resolved, turned = planar_ambiguity.resolved(pairs, alt, 2.0)
    assert turned == 0
    assert resolved is pairs


@pytest.fixture(scope='module')
def flat_ground() -> BAProblem:
    """Return a 25-image survey flight over flat ground (the two-view ambiguity at its worst)."""
    return aerial_scene(seed=4, rows=5, cols=5, n_points=2000, relief_m=0.0).gt


def test_flat_ground_pairs_keep_the_pose_their_triangles_close(
        flat_ground: BAProblem, monkeypatch: pytest.MonkeyPatch) -> None:
    """The RANSAC takes the wrong pose of half the pairs; the vote turns them back.

    The pairs left wrong are weak ones (a few dozen inliers, whose homography is noisy);
    the rotation averaging prunes them.
    """
    seen: list[two_view.EGPairs] = []
    resolved = planar_ambiguity.resolved

    def keep(pairs: two_view.EGPairs, alt: planar_ambiguity.Alternatives,
             tol_deg: float) -> tuple[two_view.EGPairs, int]:
        seen.append(pairs)
        return resolved(pairs, alt, tol_deg)

    monkeypatch.setattr(planar_ambiguity, 'resolved', keep)
    pairs, _, entries = pair_selection.estimate_pairs(flat_ground, InitOptions())
    before = _pair_errors_deg(seen[0], flat_ground.R_wc)
    after = _pair_errors_deg(pairs, flat_ground.R_wc)
    assert np.mean(before > 2.0) > 0.4
    assert np.mean(after > 2.0) < 0.15
    strong = pairs.n_inliers >= 100
    assert np.count_nonzero(strong) > 50
    assert np.all(after[strong] < 2.0)
    assert entries['pairs_turned'] == np.count_nonzero(np.any(seen[0].R_rel != pairs.R_rel,
                                                              axis=(1, 2)))
    assert entries['pairs_turned'] <= entries['pairs_with_two_poses']


def test_global_init_on_flat_ground_keeps_its_pairs() -> None:
    """The spanning tree no longer disagrees with half the pairs; the cameras are right.

    On the RANSAC's poses, this flight (1000 points) ended 10 % of its extent off.
    """
    flat_ground = aerial_scene(seed=6, rows=6, cols=6, n_points=1000, relief_m=0.0).gt
    result = pipeline.global_init(flat_ground)
    report = result.report
    assert report['view_graph']['pairs_tree_inconsistent'] <= 0.15 * report['pairs']['pairs_found']
    C = result.solve.centers_w
    C_gt = flat_ground.centers_w[result.camera_index]
    fit = umeyama_alignment(C, C_gt, with_scale=True)
    err = np.linalg.norm(fit.scale * C @ fit.rotation.T + fit.translation - C_gt, axis=1)
    extent = np.sqrt(np.mean(np.sum((C_gt - C_gt.mean(axis=0)) ** 2, axis=1)))
    assert result.problem.n_cams == flat_ground.n_cams
    assert np.max(err) < 0.005 * extent
    assert result.solve.converged


def test_a_scene_with_depth_has_no_second_pose() -> None:
    """A street (facades and ground): no pair is turned, and its pairs stay the RANSAC's."""
    problem = street_scene(seed=3, n_cams=20, n_points=500).gt
    pairs, _, entries = pair_selection.estimate_pairs(problem, InitOptions())
    assert entries['pairs_turned'] == 0
    assert entries['pairs_with_two_poses'] <= 0.05 * entries['pairs_found']
    assert np.all(_pair_errors_deg(pairs, problem.R_wc) < 2.0)
