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
"""Anchor selection and conversions between feature parameterizations (pmba.md §1.2, §3).

Notation as in :mod:`pmba_ros.core.problem`. World rays of observations are
``r_k = R_i v_k`` (rotations only); the parallax of a pair of observations is the angle
between their world rays.
"""

from __future__ import annotations

from dataclasses import fields
import logging

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import residuals, rig, sphere
from pmba_ros.core.compiled import anchor_search as compiled_anchor_search
from pmba_ros.core.engine import default_engine, Engine, EngineName
from pmba_ros.core.problem import (
    BAProblem,
    Features,
    finite_rows,
    IdpFeatures,
    ParallaxFeatures,
    Parameterization,
    subset_features,
    XyzFeatures,
)
from pmba_ros.errors import ProblemError

logger = logging.getLogger(__name__)

#: ParallaxBA swaps main and associate anchors when the point is this much farther from the
#: main anchor than from the associate (pmba.md §3.1).
_SWAP_DEPTH_RATIO = 30.0


def world_rays(problem: BAProblem, R_wc: FloatArray) -> FloatArray:
    """Return the world-frame rays r_k = R_i v_k of all observations, shape (K, 3).

    With a rig, v_k is the bearing in the rig frame (:func:`rig.rig_frame_bearings`).
    """
    out: FloatArray = np.einsum('kij,kj->ki', R_wc[problem.obs.cam_idx],
                                rig.rig_frame_bearings(problem))
    return out


def select_anchors(problem: BAProblem, R_wc: FloatArray, *,
                   allowed_pairs: BoolArray | None = None,
                   centers_w: FloatArray | None = None,
                   points_w: FloatArray | None = None,
                   engine: Engine | None = None,
                   min_baseline: float = 0.0,
                   ) -> tuple[IntArray, IntArray, BoolArray]:
    """Pick main and associate anchors of every feature: its widest well-conditioned pair.

    ParallaxBA's rule (pmba.md §3.1) approximates the pair of observations with the largest
    angle between their world rays; this takes the pair whose angle has the largest sine
    (smallest |cos|), with the later camera as main anchor: the same pair below 90 degrees,
    and not a pair near 180 degrees, where the point lies between its anchors and the BA is
    as ill-conditioned as at zero parallax (DEVIATION, see
    :mod:`pmba_ros.core.anchor_search`). With known positions, pairs without baseline are
    excluded; with known points, the anchors are swapped when the point is over 30 times
    farther from the main anchor.

    Args:
        problem: The problem (observations sorted by feature).
        R_wc: Camera -> world rotations, shape (M, 3, 3).
        allowed_pairs: Optional (M, M) symmetric mask of camera pairs that may anchor a
            feature (PMBA: epipolar-geometry pairs only).
        centers_w: Optional camera centres (M, 3): pairs closer than 1e-9 of the scene size
            or ``min_baseline`` are not anchors (zero baseline, pmba.md §3.3).
        points_w: Optional points (N, 3) for the depth-ratio swap.
        engine: The engine that searches the pairs (default: :func:`default_engine`).
        min_baseline: With ``centers_w``, the shortest anchor baseline, in its units.

    Returns:
        main_idx (N,), assoc_idx (N,) and ok (N,): False where no admissible pair exists.
    """
    obs = problem.obs
    close = np.zeros(0, dtype=np.int64)
    if centers_w is not None:
        close = _coincident_pairs(centers_w, min_baseline)
    counts = np.bincount(obs.feat_idx, minlength=problem.n_feats)
    main_idx, assoc_idx, ok = (engine or default_engine()).widest_pairs(
        world_rays(problem, R_wc), obs.cam_idx, np.concatenate([[0], np.cumsum(counts)]),
        _admissible(problem, R_wc.shape[0], allowed_pairs), close, R_wc.shape[0])
    return _swap_far_main(main_idx, assoc_idx, ok, centers_w, points_w)


def _admissible(problem: BAProblem, n_cams: int,
                allowed_pairs: BoolArray | None) -> BoolArray | None:
    """Return the (M, M) mask of camera pairs that may anchor a feature (None: all)."""
    if problem.rig is not None:  # two cameras of one pose have no baseline between anchors
        other = ~np.eye(n_cams, dtype=bool)
        return other if allowed_pairs is None else allowed_pairs & other
    return allowed_pairs


def _swap_far_main(main_idx: IntArray, assoc_idx: IntArray, ok: BoolArray,
                   centers_w: FloatArray | None, points_w: FloatArray | None,
                   ) -> tuple[IntArray, IntArray, BoolArray]:
    """Swap the anchors of points over 30 times farther from the main anchor."""
    if points_w is not None and centers_w is not None:
        d_main = sphere.norms(points_w - centers_w[main_idx])
        d_assoc = sphere.norms(points_w - centers_w[assoc_idx])
        swap = d_main > _SWAP_DEPTH_RATIO * d_assoc
        main_idx, assoc_idx = (np.where(swap, assoc_idx, main_idx),
                               np.where(swap, main_idx, assoc_idx))
    return main_idx, assoc_idx, ok


def _coincident_pairs(centers_w: FloatArray, min_baseline: float = 0.0) -> IntArray:
    """Keys a * M + b (both orders) of camera pairs closer than 1e-9 of the scene size.

    Such pairs have no baseline (pmba.md §3.3); nor, for a caller that sets
    ``min_baseline``, do pairs closer than that. A sweep along x finds the candidates in
    O(M log M); they are usually few.
    """
    M = centers_w.shape[0]
    scale = float(np.ptp(centers_w, axis=0).max()) if M > 1 else 0.0
    tol = max(max(scale, 1.0) * 1e-9, min_baseline)
    order = np.argsort(centers_w[:, 0], kind='stable')
    x = centers_w[order, 0]
    span = np.searchsorted(x, x + tol, side='right') - np.arange(M) - 1   # later within tol
    if not span.any():
        return np.zeros(0, dtype=np.int64)
    first = np.repeat(np.arange(M), span)
    second = first + 1 + (np.arange(first.shape[0]) - np.repeat(np.cumsum(span) - span, span))
    a, b = order[first], order[second]
    diff = centers_w[a] - centers_w[b]
    near = np.einsum('ij,ij->i', diff, diff) <= tol * tol
    a, b = a[near], b[near]
    return np.concatenate([a * M + b, b * M + a]).astype(np.int64)


_NOT_OBSERVED = 'anchor_observations: an anchor camera does not observe its feature'


def anchor_observations(problem: BAProblem, cams: IntArray) -> IntArray:
    """Return the index of the observation of feature j by camera cams[j], shape of ``cams``.

    ``cams`` is (N,), or (N, S) for S cameras of each feature.

    Raises:
        ProblemError: If some feature is not observed by its given camera.
    """
    M = problem.n_cams
    keys = problem.obs.feat_idx * M + problem.obs.cam_idx  # sorted: obs are by feature, camera
    first = np.arange(problem.n_feats) * M
    want = (first if cams.ndim == 1 else first[:, None]) + cams
    k = np.searchsorted(keys, want)
    k = np.minimum(k, keys.shape[0] - 1)
    if keys.shape[0] == 0 or np.any(keys[k] != want):
        raise ProblemError(_NOT_OBSERVED)
    out: IntArray = k.astype(np.int64)
    return out


def check_features(problem: BAProblem, feats: Features, param: Parameterization) -> None:
    """Raise ProblemError if features do not match the parameterization or problem size."""
    expected = {Parameterization.PMBA: ParallaxFeatures, Parameterization.XYZ: XyzFeatures,
                Parameterization.IDP: IdpFeatures}[param]
    if not isinstance(feats, expected):
        msg = f'features of type {type(feats).__name__} do not fit param {param.value!r}'
        raise ProblemError(msg)
    arrays = {f.name: np.asarray(getattr(feats, f.name)) for f in fields(feats)}
    for name, arr in arrays.items():
        if arr.shape[0] != problem.n_feats:
            msg = f'features.{name}: {arr.shape[0]} rows for {problem.n_feats} features'
            raise ProblemError(msg)
        # Integer arrays are finite: only the floating ones are looked at.
        if arr.dtype.kind not in 'iub' and not np.isfinite(arr).all():
            msg = f'features.{name}: non-finite values'
            raise ProblemError(msg)
    if isinstance(feats, ParallaxFeatures):
        main, assoc = arrays['main_idx'], arrays['assoc_idx']
        for name, idx in (('main_idx', main), ('assoc_idx', assoc)):
            if idx.shape[0] and (idx.min() < 0 or idx.max() >= problem.n_cams):
                msg = f'features.{name}: unknown camera index'
                raise ProblemError(msg)
        same = main == assoc
        if same.any():
            msg = f'features: {int(same.sum())} features have main anchor == associate anchor'
            raise ProblemError(msg)
        anchor_observations(problem, np.stack([main, assoc], axis=1))


def features_from_rotations(problem: BAProblem, R_wc: FloatArray, main_idx: IntArray,
                            assoc_idx: IntArray) -> ParallaxFeatures:
    """Return initial PMBA features from rotations only, no triangulation (PMBA Remark 5).

    theta = arccos((R_m v_m) . (R_a v_a)) and n = v_m, so every main-anchor residual starts
    at zero (pmba.md §3.2). With a rig, v are rig-frame bearings of the anchors' first
    cameras.
    """
    km, ka = anchor_observations(problem, np.stack([main_idx, assoc_idx], axis=1)).T
    v = rig.rig_frame_bearings(problem)
    ray_m = np.einsum('nij,nj->ni', R_wc[main_idx], v[km])
    ray_a = np.einsum('nij,nj->ni', R_wc[assoc_idx], v[ka])
    theta = np.arccos(np.clip(sphere.dots(ray_m, ray_a), -1.0, 1.0))
    return ParallaxFeatures(theta, v[km].copy(), main_idx.copy(), assoc_idx.copy())


def xyz_to_parallax(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
                    points_w: FloatArray, *, allowed_pairs: BoolArray | None = None,
                    engine: Engine | None = None, min_baseline: float = 0.0,
                    ) -> tuple[ParallaxFeatures, BoolArray]:
    """Convert Euclidean points to PMBA features with anchors chosen by :func:`select_anchors`.

    n = xi(R_m^T (F - P_m)) and theta = angle(F - P_m, F - P_a). Points that are not finite or
    lie behind the main anchor fall back to :func:`features_from_rotations` values. The
    compiled engine does all of it in one pass over the observations, numpy through
    :func:`select_anchors` and :func:`features_from_rotations`; the results are the same.

    Returns:
        The features and ok (N,): False for features without an admissible anchor pair.
    """
    eng = engine or default_engine()
    if points_w.shape != (problem.n_feats, 3):
        msg = f'xyz_to_parallax: points of shape {points_w.shape} for {problem.n_feats} features'
        raise ValueError(msg)
    if eng.name is EngineName.COMPILED:   # _point_features in one compiled pass
        main_idx, assoc_idx, ok, cos_t, n, _, unseen, n_reinit = (
            compiled_anchor_search.point_features(
                R_wc, centers_w, points_w, rig.rig_frame_bearings(problem), problem.obs.cam_idx,
                problem.obs.feat_idx, _admissible(problem, R_wc.shape[0], allowed_pairs),
                _SWAP_DEPTH_RATIO, min_baseline))
        if unseen >= 0:
            raise ProblemError(_NOT_OBSERVED)
        theta = np.arccos(cos_t)
    else:
        main_idx, assoc_idx, ok, theta, n, valid = _point_features(
            problem, R_wc, centers_w, points_w, allowed_pairs, eng, min_baseline)
        n_reinit = int(np.sum(~valid & ok))
    if n_reinit:
        logger.info('xyz_to_parallax: %d points re-initialized from rotations', n_reinit)
    return ParallaxFeatures(theta, n, main_idx, assoc_idx), ok


def _point_features(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
                    points_w: FloatArray, allowed_pairs: BoolArray | None, engine: Engine,
                    min_baseline: float,
                    ) -> tuple[IntArray, IntArray, BoolArray, FloatArray, FloatArray, BoolArray]:
    """Return the anchors, ok, theta, n and valid (from the point) of xyz_to_parallax.

    The numpy reference of :func:`pmba_ros.core.compiled.anchor_search.point_features`.
    """
    main_idx, assoc_idx, ok = select_anchors(problem, R_wc, allowed_pairs=allowed_pairs,
                                             centers_w=centers_w, points_w=points_w,
                                             engine=engine, min_baseline=min_baseline)
    from_rot = features_from_rotations(problem, R_wc, main_idx, assoc_idx)
    d_m = points_w - centers_w[main_idx]
    d_a = points_w - centers_w[assoc_idx]
    n = sphere.normalize(np.einsum('nji,nj->ni', R_wc[main_idx], d_m))
    cos_t = sphere.dots(sphere.normalize(d_m), sphere.normalize(d_a))
    theta = np.arccos(np.clip(cos_t, -1.0, 1.0))
    # A point is usable if it is in front of the main anchor and on its measured side.
    valid = (finite_rows(points_w) & (n[:, 2] > 0)
             & (sphere.dots(n, from_rot.n) > 0))
    n = np.where(valid[:, None], n, from_rot.n)
    theta = np.where(valid, theta, from_rot.theta)
    return main_idx, assoc_idx, ok, theta, n, valid


def parallax_homogeneous(R_wc: FloatArray, centers_w: FloatArray,
                         feats: ParallaxFeatures) -> tuple[FloatArray, FloatArray]:
    """Homogeneous points (X~, w) with N_i = X~ - w P_i, arccos-free (pmba.md §1.3).

    Returns:
        X~ = g u + sin(theta) P_m, shape (N, 3), and w = sin(theta), shape (N,).
    """
    u, _, _, _, sin_t, _, g = residuals.anchor_terms(R_wc, centers_w, feats)
    return g[:, None] * u + sin_t[:, None] * centers_w[feats.main_idx], sin_t


def parallax_to_xyz(R_wc: FloatArray, centers_w: FloatArray,
                    feats: ParallaxFeatures, behind: bool = False) -> FloatArray:
    """Euclidean points F = P_m + D sin(alpha - theta)/sin(theta) R_m n (PMBA eq. 2).

    Points at infinity (theta ~ 0) come out as inf in their direction's coordinates, and so
    do points whose depth along their ray is negative (the parallax angle crossed zero):
    the homogeneous point, and so every ray to it, is the same, but its Euclidean copy lies
    behind the cameras that see it (COLMAP cannot project a fisheye's ray there). With
    ``behind``, those come out at that copy: a pinhole projection, which does not tell a
    ray from its opposite (BAL, Bundler), sees it where PMBA's rays do.
    """
    u, _, _, _, sin_t, _, g = residuals.anchor_terms(R_wc, centers_w, feats)
    X = g[:, None] * u + sin_t[:, None] * centers_w[feats.main_idx]
    beyond = (g * sin_t < 0) & (not behind)
    X[beyond] = g[beyond, None] * u[beyond]
    w = np.where(beyond, 0.0, sin_t)
    with np.errstate(divide='ignore', invalid='ignore'):
        return X / w[:, None]  # eq. (2)


def far_points(R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
               distance: float) -> FloatArray:
    """Return finite stand-ins for points at infinity: ``distance`` along their rays.

    From each main anchor, along the direction its rays have (PMBA eq. 2 as theta -> 0),
    for formats that store Euclidean points only.
    """
    u, _, _, _, _, _, g = residuals.anchor_terms(R_wc, centers_w, feats)
    out: FloatArray = centers_w[feats.main_idx] + distance * np.sign(g)[:, None] * u
    return out


def xyz_to_idp(problem: BAProblem, R_wc: FloatArray, centers_w: FloatArray,
               points_w: FloatArray) -> IdpFeatures:
    """Inverse-depth features anchored at each feature's first observing camera."""
    offsets = problem.feature_offsets()
    k0 = offsets[:-1]
    h = problem.obs.cam_idx[k0]
    p_c = np.einsum('nji,nj->ni', R_wc[h], points_w - centers_w[h])
    bearing = problem.obs.bearings_c[k0]
    valid = finite_rows(points_w) & (p_c[:, 2] > 1e-12)
    # Points behind the anchor start at infinity along the measured bearing.
    ray = np.where(valid[:, None], p_c, bearing)
    ab = ray[:, :2] / ray[:, 2:3]
    rho = np.where(valid, 1.0 / np.where(valid, p_c[:, 2], 1.0), 0.0)
    return IdpFeatures(h.astype(np.int64), ab, rho)


def idp_to_xyz(R_wc: FloatArray, centers_w: FloatArray, feats: IdpFeatures) -> FloatArray:
    """Euclidean points X = P_h + R_h [a, b, 1]^T / rho."""
    m = np.concatenate([feats.ab, np.ones((feats.ab.shape[0], 1))], axis=1)
    with np.errstate(divide='ignore', invalid='ignore'):
        out: FloatArray = centers_w[feats.anchor_idx] + np.einsum(
            'nij,nj->ni', R_wc[feats.anchor_idx], m) / feats.rho[:, None]
        return out


def to_xyz(R_wc: FloatArray, centers_w: FloatArray,
           feats: ParallaxFeatures | XyzFeatures | IdpFeatures) -> FloatArray:
    """Euclidean points (N, 3) of any feature parameterization."""
    if isinstance(feats, ParallaxFeatures):
        return parallax_to_xyz(R_wc, centers_w, feats)
    if isinstance(feats, IdpFeatures):
        return idp_to_xyz(R_wc, centers_w, feats)
    return np.array(feats.points_w, dtype=float)


def initial_features(problem: BAProblem, param: Parameterization,
                     engine: Engine | None = None) -> tuple[BAProblem, Features]:
    """Return features of a parameterization from the problem's points (dropping unusable ones).

    ``engine`` searches PMBA's anchor pairs (default: the ``'auto'`` engine).

    Raises:
        ProblemError: If the problem has no initial points.
    """
    if problem.points_w is None:
        msg = 'problem has no initial points: pass features, or run the global initialization'
        raise ProblemError(msg)
    if param is Parameterization.XYZ:
        return problem, XyzFeatures(np.array(problem.points_w))
    if param is Parameterization.IDP:
        return problem, xyz_to_idp(problem, problem.R_wc, problem.centers_w, problem.points_w)
    feats, ok = xyz_to_parallax(problem, problem.R_wc, problem.centers_w, problem.points_w,
                                engine=engine)
    if not np.all(ok):
        problem = subset_features(problem, ok, 'features_without_anchor_baseline')
        feats, _ = xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                   np.asarray(problem.points_w), engine=engine)
    return problem, feats
