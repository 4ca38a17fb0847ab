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
"""Tests of pmba_ros.init.view_graph and pmba_ros.init.rotation_averaging."""

from __future__ import annotations

import itertools

import numpy as np
from pmba_ros.core import so3
from pmba_ros.errors import InitError
from pmba_ros.init import rotation_averaging, view_graph
import pytest


def _random_graph(rng: np.random.Generator, n_cams: int, p_edge: float,
                  ) -> tuple[np.ndarray, np.ndarray]:
    pairs = [(a, b) for a, b in itertools.combinations(range(n_cams), 2)
             if rng.random() < p_edge or b == a + 1]
    cam_a, cam_b = np.array(pairs, dtype=np.int64).T
    return cam_a, cam_b


def _relative(R_wc: np.ndarray, cam_a: np.ndarray, cam_b: np.ndarray) -> np.ndarray:
    return np.swapaxes(R_wc[cam_b], 1, 2) @ R_wc[cam_a]  # R_cv = R_b^T R_a


def _kruskal_max_weight(n: int, cam_a: np.ndarray, cam_b: np.ndarray, w: np.ndarray) -> float:
    """Weight of a maximum spanning tree by Kruskal with union-find (independent check)."""
    parent = list(range(n))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    total = 0.0
    for e in np.argsort(-w, kind='stable'):
        ra, rb = find(int(cam_a[e])), find(int(cam_b[e]))
        if ra != rb:
            parent[ra] = rb
            total += float(w[e])
    return total


def test_maximum_spanning_tree_has_maximum_weight(rng: np.random.Generator) -> None:
    """The tree spans the graph and its weight equals Kruskal's maximum spanning tree."""
    cam_a, cam_b = _random_graph(rng, 9, 0.5)
    w = rng.integers(1, 100, cam_a.shape[0]).astype(float)
    tree = view_graph.maximum_spanning_tree(9, cam_a, cam_b, w)
    assert int(tree.sum()) == 8
    assert w[tree].sum() == pytest.approx(_kruskal_max_weight(9, cam_a, cam_b, w))
    assert view_graph.largest_component(9, cam_a[tree], cam_b[tree]).all()


def test_largest_component_keeps_the_biggest_part() -> None:
    """Two components of 4 and 3 cameras plus an isolated one: the 4 are kept."""
    cam_a = np.array([0, 1, 2, 4, 5])
    cam_b = np.array([1, 2, 3, 5, 6])
    comp = view_graph.largest_component(8, cam_a, cam_b)
    assert comp.tolist() == [True] * 4 + [False] * 4


def test_chained_tree_rotations_are_exact_for_exact_pairs(rng: np.random.Generator) -> None:
    """Chaining exact R_cv along the tree gives R_k = R_root^T-aligned true rotations."""
    M = 8
    R_true = so3.exp(rng.normal(size=(M, 3)))
    cam_a, cam_b = _random_graph(rng, M, 0.3)
    R_rel = _relative(R_true, cam_a, cam_b)
    tree = view_graph.maximum_spanning_tree(M, cam_a, cam_b, np.ones(cam_a.shape[0]))
    R, reached = view_graph.chain_tree_rotations(M, 3, cam_a[tree], cam_b[tree], R_rel[tree])
    assert reached.all()
    np.testing.assert_allclose(R, R_true[3].T @ R_true, atol=1e-12)
    dis = view_graph.pair_rotation_disagreement_deg(R, cam_a, cam_b, R_rel)
    assert np.max(dis) < 1e-4


def test_chordal_averaging_is_exact_without_noise(rng: np.random.Generator) -> None:
    """Three sparse solves with one matrix recover rotations exactly (R_root = I)."""
    M = 10
    R_true = so3.exp(rng.normal(size=(M, 3)))
    cam_a, cam_b = _random_graph(rng, M, 0.4)
    R = rotation_averaging.chordal_rotation_averaging(
        M, 2, cam_a, cam_b, _relative(R_true, cam_a, cam_b),
        rng.uniform(1, 50, cam_a.shape[0]))
    np.testing.assert_allclose(R, R_true[2].T @ R_true, atol=1e-10)


def test_chordal_averaging_beats_the_tree_under_noise(rng: np.random.Generator) -> None:
    """Averaging all pairs is more accurate than chaining a spanning tree."""
    M = 15
    R_true = so3.exp(rng.normal(size=(M, 3)))
    cam_a, cam_b = _random_graph(rng, M, 0.6)
    noise = so3.exp(rng.normal(scale=np.deg2rad(0.5), size=(cam_a.shape[0], 3)))
    R_rel = _relative(R_true, cam_a, cam_b) @ noise
    root = 0
    R = rotation_averaging.chordal_rotation_averaging(M, root, cam_a, cam_b, R_rel)
    tree = view_graph.maximum_spanning_tree(M, cam_a, cam_b, np.ones(cam_a.shape[0]))
    R_tree, _ = view_graph.chain_tree_rotations(M, root, cam_a[tree], cam_b[tree], R_rel[tree])
    R_ref = R_true[root].T @ R_true
    err_avg = np.rad2deg(so3.angle(R, R_ref)).mean()
    err_tree = np.rad2deg(so3.angle(R_tree, R_ref)).mean()
    assert err_avg < err_tree
    assert err_avg < 0.5


def test_chordal_averaging_raises_on_disconnected_graph() -> None:
    """A camera without any pair makes the normal matrix singular: InitError."""
    cam_a, cam_b = np.array([0, 1]), np.array([1, 2])
    R_rel = np.broadcast_to(np.eye(3), (2, 3, 3))
    with pytest.raises(InitError, match='connected'):
        rotation_averaging.chordal_rotation_averaging(4, 0, cam_a, cam_b, R_rel)


def test_robust_averaging_shrugs_off_corrupted_pairs(rng: np.random.Generator) -> None:
    """15 % of pairs wrong by 20-60 deg: IRLS stays near the noise level, plain L2 does not."""
    M = 20
    R_true = so3.exp(rng.normal(size=(M, 3)))
    cam_a, cam_b = _random_graph(rng, M, 0.5)
    P = cam_a.shape[0]
    noise = so3.exp(rng.normal(scale=np.deg2rad(0.2), size=(P, 3)))
    R_rel = _relative(R_true, cam_a, cam_b) @ noise
    bad = rng.random(P) < 0.15
    # Keep the chain edges clean so every camera stays connected by good pairs.
    bad &= cam_b != cam_a + 1
    axis = rng.normal(size=(int(bad.sum()), 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    R_rel[bad] = R_rel[bad] @ so3.exp(axis * np.deg2rad(rng.uniform(20, 60, (bad.sum(), 1))))
    R_ref = R_true[0].T @ R_true
    plain = rotation_averaging.chordal_rotation_averaging(M, 0, cam_a, cam_b, R_rel)
    robust, factor, rounds = rotation_averaging.robust_rotation_averaging(
        M, 0, cam_a, cam_b, R_rel, cauchy_deg=1.0)
    err_plain = np.rad2deg(so3.angle(plain, R_ref)).max()
    err_robust = np.rad2deg(so3.angle(robust, R_ref)).max()
    assert err_plain > 2.0
    assert err_robust < 0.5
    assert 1 < rounds < 20
    assert factor[bad].max() < 0.01 < factor[~bad].min()


def test_robust_averaging_equals_plain_averaging_on_consistent_pairs(
        rng: np.random.Generator) -> None:
    """Without noise every factor is 1 and the result is the exact chordal solution."""
    M = 8
    R_true = so3.exp(rng.normal(size=(M, 3)))
    cam_a, cam_b = _random_graph(rng, M, 0.5)
    R, factor, rounds = rotation_averaging.robust_rotation_averaging(
        M, 1, cam_a, cam_b, _relative(R_true, cam_a, cam_b))
    np.testing.assert_allclose(R, R_true[1].T @ R_true, atol=1e-10)
    np.testing.assert_allclose(factor, 1.0, atol=1e-12)
    assert rounds == 1
