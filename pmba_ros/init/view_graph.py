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
"""View graph of EG pairs: largest connected component, maximum spanning tree, tree rotations.

Nodes are images, edges are EG pairs weighted by their cheirality inliers (pmba.md §4.2).
The tree gives the reference frame (its root), prior rotations chained from the root, and a
test that discards EG pairs whose relative rotation disagrees with the tree.
"""

from __future__ import annotations

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import so3
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree


def largest_component(n_cams: int, cam_a: IntArray, cam_b: IntArray) -> BoolArray:
    """Return the cameras of the largest connected component of the pair graph, shape (M,).

    Ties are broken by the lowest camera index. Cameras without any pair form singleton
    components (never the largest unless there is no pair at all).
    """
    if cam_a.size == 0:
        return np.zeros(n_cams, dtype=bool)
    graph = coo_matrix((np.ones(cam_a.shape[0]), (cam_a, cam_b)), shape=(n_cams, n_cams))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    return np.asarray(labels == int(np.argmax(sizes)), dtype=bool)


def maximum_spanning_tree(n_cams: int, cam_a: IntArray, cam_b: IntArray,
                          weights: FloatArray) -> BoolArray:
    """Return the mask (P,) of the pairs in a maximum spanning tree (forest) of the graph.

    scipy only has a minimum spanning tree, so the positive weights are negated.
    """
    w = np.asarray(weights, dtype=float)
    if np.any(w <= 0):
        msg = 'maximum_spanning_tree: weights must be positive'
        raise ValueError(msg)
    # Edge ids are stored as values so that the tree edges can be mapped back to pairs.
    graph = coo_matrix((-w, (cam_a, cam_b)), shape=(n_cams, n_cams)).tocsr()
    tree = minimum_spanning_tree(graph).tocoo()
    key_tree = np.minimum(tree.row, tree.col) * n_cams + np.maximum(tree.row, tree.col)
    key_pair = np.minimum(cam_a, cam_b) * n_cams + np.maximum(cam_a, cam_b)
    return np.isin(key_pair, key_tree)


def choose_root(n_cams: int, cam_a: IntArray, cam_b: IntArray, weights: FloatArray,
                cameras: BoolArray) -> int:
    """Return the camera of ``cameras`` with the largest weighted degree (the reference frame)."""
    deg = np.bincount(cam_a, weights=weights, minlength=n_cams)
    deg += np.bincount(cam_b, weights=weights, minlength=n_cams)
    deg = np.where(cameras, deg, -np.inf)
    return int(np.argmax(deg))


def chain_tree_rotations(n_cams: int, root: int, cam_a: IntArray, cam_b: IntArray,
                         R_rel: FloatArray) -> tuple[FloatArray, BoolArray]:
    """Chain the relative rotations of tree edges from the root (breadth-first).

    Args:
        n_cams: Number of cameras M.
        root: Reference camera (R_root = I).
        cam_a: First camera of each tree edge, shape (T,).
        cam_b: Second camera, shape (T,).
        R_rel: R_cv = R_b^T R_a of each edge, shape (T, 3, 3).

    Returns:
        Camera -> world rotations (M, 3, 3) (identity where unreached) and the reached mask (M,).

    References:
        pmba.md §4.2 (chaining along the tree; R_a = R_b R_cv).
    """
    T = cam_a.shape[0]
    ids = np.arange(1, T + 1, dtype=float)
    graph = coo_matrix((np.concatenate([ids, ids]),
                        (np.concatenate([cam_a, cam_b]), np.concatenate([cam_b, cam_a]))),
                       shape=(n_cams, n_cams)).tocsr()
    order, pred = breadth_first_order(graph, root, directed=False, return_predecessors=True)
    R_wc = np.broadcast_to(np.eye(3), (n_cams, 3, 3)).copy()
    reached = np.zeros(n_cams, dtype=bool)
    reached[order] = True
    for node in order[1:]:  # loop over cameras (tree traversal), not observations
        parent = int(pred[node])
        edge = int(graph[parent, node]) - 1
        if cam_a[edge] == node:  # R_a = R_b R_cv
            R_wc[node] = R_wc[parent] @ R_rel[edge]
        else:  # R_b = R_a R_cv^T
            R_wc[node] = R_wc[parent] @ R_rel[edge].T
    return R_wc, reached


def pair_rotation_disagreement_deg(R_wc: FloatArray, cam_a: IntArray, cam_b: IntArray,
                                   R_rel: FloatArray) -> FloatArray:
    """Return the angle (deg) between each pair's R_cv and R_b^T R_a of the rotations, (P,)."""
    R_pred = np.swapaxes(R_wc[cam_b], 1, 2) @ R_wc[cam_a]
    return np.rad2deg(so3.angle(R_pred, R_rel))
