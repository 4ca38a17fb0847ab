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
"""Bookkeeping of the online back-end: keyframes, their observations, features, landmarks.

Everything here is numpy and ROS-free. Keyframes are numbered 0, 1, ... in arrival order;
their arrays grow by doubling. Observations are kept per keyframe only while they can still
enter a problem (sliding mode drops them ``fixed_lookback`` keyframes behind the window);
features live in :class:`FeatureMap` (sorted ids, world points) while a free keyframe observes
them and then retire into :class:`LandmarkStore`, whose size is capped.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.backend.distortion import pinhole_jacobian
from pmba_ros.core import so3
from pmba_ros.core.compiled import gather as compiled_gather
from pmba_ros.core.engine import compiled_ready
from pmba_ros.core.problem import finite_rows, run_order


class KeyframeStatus(IntEnum):
    """Life cycle of a keyframe."""

    COLLECTED = 0  #: waiting for the global initialization (front-end pose until then)
    ACTIVE = 1  #: free in the problem
    FIXED = 2  #: left the window (sliding mode), pose final
    DEAD_RECKONED = 3  #: too few observations: pose from the front-end, never optimized
    DISCARDED = 4  #: dropped from the initialization batch, no pose
    PASSED_THROUGH = 5  #: front-end pose through map <- odom, never optimized


@dataclass(frozen=True, eq=False)
class KeyframeObs:
    """Observations of one keyframe.

    Attributes:
        ids: Feature ids, shape (K,), unique per camera.
        bearings: Unit bearings in the observing camera's frame, shape (K, 3).
        normalized: Normalized undistorted coordinates (x/z, y/z), shape (K, 2).
        camera: Front-end camera id of each observation, shape (K,), or None: all of the
            reference camera (``camera_id``, whose frame the keyframe poses are in).
        pixel_jac: d(pixel) / d(bearing) by each observation's camera model, shape (K, 2, 3)
            (float32), or None: the pinhole (see :class:`~pmba_ros.core.problem.Observations`).
    """

    ids: IntArray
    bearings: FloatArray
    normalized: FloatArray
    camera: IntArray | None = None
    pixel_jac: FloatArray | None = None

    def of_camera(self, camera: int) -> KeyframeObs:
        """Return the observations of one camera (all of them without camera ids)."""
        if self.camera is None:
            return self
        sel = self.camera == camera
        return KeyframeObs(self.ids[sel], self.bearings[sel], self.normalized[sel],
                           self.camera[sel],
                           None if self.pixel_jac is None else self.pixel_jac[sel])


class KeyframeStore:
    """Poses (map and front-end), stamps and statuses of all keyframes (growing arrays)."""

    def __init__(self) -> None:
        """Create an empty store."""
        self.n = 0
        cap = 64
        self.stamps_ns = np.zeros(cap, dtype=np.int64)
        self.R_map = np.tile(np.eye(3), (cap, 1, 1))
        self.C_map = np.zeros((cap, 3))
        self.R_odom = np.tile(np.eye(3), (cap, 1, 1))
        self.C_odom = np.zeros((cap, 3))
        self.has_odom = np.zeros(cap, dtype=bool)
        self.cov_odom = np.zeros((cap, 6, 6))
        self.has_cov = np.zeros(cap, dtype=bool)
        self.status = np.zeros(cap, dtype=np.int8)
        # The front-end's odom frame: a new segment after each jump it made (relocalization,
        # reset). Steps between segments are no motion.
        self.segment = np.zeros(cap, dtype=np.int64)
        self.obs: dict[int, KeyframeObs] = {}

    def _grow(self) -> None:
        cap = 2 * self.stamps_ns.shape[0]
        for name in ('stamps_ns', 'R_map', 'C_map', 'R_odom', 'C_odom', 'has_odom', 'cov_odom',
                     'has_cov', 'status', 'segment'):
            old = getattr(self, name)
            new = np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[:old.shape[0]] = old
            if name.startswith('R_'):
                new[old.shape[0]:] = np.eye(3)
            setattr(self, name, new)

    def add(self, stamp_ns: int, odom: tuple[FloatArray, FloatArray] | None,
            obs: KeyframeObs | None, status: KeyframeStatus,
            covariance: FloatArray | None = None, segment: int = 0) -> int:
        """Append a keyframe and return its index.

        ``covariance`` is its front-end pose's, ``segment`` its odom segment (see
        :meth:`same_odom`).
        """
        if self.n == self.stamps_ns.shape[0]:
            self._grow()
        i = self.n
        self.stamps_ns[i] = stamp_ns
        self.segment[i] = segment
        if odom is not None:
            self.R_odom[i], self.C_odom[i] = odom
            self.has_odom[i] = True
            if covariance is not None:
                self.cov_odom[i], self.has_cov[i] = covariance, True
        self.status[i] = status
        if obs is not None:
            self.obs[i] = obs
        self.n += 1
        return i

    def same_odom(self, a: IntArray, b: IntArray) -> BoolArray:
        """Return which pairs of keyframes (a, b) both have front-end poses in one odom frame.

        Only between those is the front-end's relative pose a motion.
        """
        return self.has_odom[a] & self.has_odom[b] & (self.segment[a] == self.segment[b])

    def indices(self, status: KeyframeStatus) -> IntArray:
        """Return the indices of the keyframes with ``status``, ascending."""
        return np.flatnonzero(self.status[:self.n] == status).astype(np.int64)

    def observed_ids(self, indices: IntArray) -> IntArray:
        """Return the sorted distinct feature ids that keyframes ``indices`` observe."""
        return unique_ids(np.concatenate([self.obs[int(i)].ids for i in indices]))

    def forget_observations_before(self, index: int) -> None:
        """Drop the stored observations of keyframes older than ``index``."""
        for i in [i for i in self.obs if i < index]:
            del self.obs[i]


class FeatureMap:
    """World points of the features in the problem, keyed by sorted feature id.

    Non-finite rows mean "no usable point yet" (new features, points at infinity); the next
    problem re-initializes them from rotations (PMBA Remark 5).
    """

    def __init__(self) -> None:
        """Create an empty map."""
        self.ids = np.zeros(0, dtype=np.int64)
        self.points = np.zeros((0, 3))

    def __len__(self) -> int:
        """Return the number of features."""
        return int(self.ids.shape[0])

    def lookup(self, ids: IntArray) -> FloatArray:
        """Return the points of ``ids`` (NaN where unknown), shape (len(ids), 3)."""
        pos = np.searchsorted(self.ids, ids)
        pos = np.minimum(pos, max(len(self) - 1, 0))
        found = (len(self) > 0) & (self.ids[pos] == ids) if len(self) else \
            np.zeros(ids.shape[0], dtype=bool)
        out = np.full((ids.shape[0], 3), np.nan)
        out[found] = self.points[pos[found]]
        return out

    def upsert(self, ids: IntArray, points: FloatArray) -> None:
        """Set the points of ``ids`` (inserting unknown ids)."""
        ids = np.asarray(ids, dtype=np.int64)
        all_ids = np.concatenate([self.ids, ids])
        all_pts = np.concatenate([self.points, points])
        # Keep the last occurrence of every id (the update): the first of the reversed ids
        # in a stable sort, as np.unique(return_index=True) finds it.
        rev_ids = all_ids[::-1]
        order = np.argsort(rev_ids, kind='stable')
        first = order[_run_starts(rev_ids[order])]
        self.ids = rev_ids[first]
        self.points = all_pts[::-1][first]

    def pop_except(self, keep_ids: IntArray) -> tuple[IntArray, FloatArray]:
        """Remove every feature not in ``keep_ids``; return the removed ids and points."""
        keep = is_in(self.ids, keep_ids)
        removed = (self.ids[~keep], self.points[~keep])
        self.ids, self.points = self.ids[keep], self.points[keep]
        return removed

    def scale_about(self, center: FloatArray, factor: float) -> None:
        """Apply X -> center + factor (X - center) to every point (unknown ones stay NaN)."""
        self.points = center + factor * (self.points - center)


class LandmarkStore:
    """Retired landmarks (finite points only), capped at ``capacity`` (oldest dropped)."""

    def __init__(self, capacity: int) -> None:
        """Create an empty store."""
        self.capacity = capacity
        self._chunks: list[FloatArray] = []
        self._count = 0

    def __len__(self) -> int:
        """Return the number of landmarks."""
        return self._count

    def add(self, points: FloatArray) -> None:
        """Add finite points; drop the oldest beyond the capacity."""
        pts = points[finite_rows(points)]
        if pts.shape[0] == 0 or self.capacity == 0:
            return
        self._chunks.append(pts)
        self._count += pts.shape[0]
        if self._count > self.capacity:
            merged = np.concatenate(self._chunks)[-self.capacity:]
            self._chunks = [merged]
            self._count = merged.shape[0]

    def scale_about(self, center: FloatArray, factor: float) -> None:
        """Apply X -> center + factor (X - center) to every landmark."""
        self._chunks = [center + factor * (c - center) for c in self._chunks]

    def points(self) -> FloatArray:
        """Return all landmarks, shape (L, 3)."""
        if len(self._chunks) > 1:
            self._chunks = [np.concatenate(self._chunks)]
        return self._chunks[0] if self._chunks else np.zeros((0, 3))


@dataclass(frozen=True)
class Similarity:
    """X_a = scale * rotation @ X_b + translation (e.g. map <- odom)."""

    scale: float
    rotation: FloatArray
    translation: FloatArray

    @classmethod
    def identity(cls) -> Similarity:
        """Return the identity."""
        return cls(1.0, np.eye(3), np.zeros(3))

    def apply_poses(self, R: FloatArray, C: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Map poses (R_wc, centres) of frame b into frame a."""
        return self.rotation @ R, self.scale * C @ self.rotation.T + self.translation


def estimate_similarity(R_a: FloatArray, C_a: FloatArray, R_b: FloatArray, C_b: FloatArray,
                        prior_scale: float = 1.0, min_spread: float = 0.0) -> Similarity:
    """Estimate S with pose_a ~ S pose_b from corresponding poses (rotations and centres).

    The rotation is the chordal mean of R_a R_b^T (well conditioned even for collinear
    centres), then scale and translation are the least-squares fit of the centres. With less
    than 1e-6 of centre spread, or an RMS spread of C_b below ``min_spread``, the scale is
    ``prior_scale``.

    Args:
        R_a: Rotations of the poses in frame a, shape (P, 3, 3).
        C_a: Centres of the poses in frame a, shape (P, 3).
        R_b: Rotations of the same poses in frame b, shape (P, 3, 3).
        C_b: Centres of the same poses in frame b, shape (P, 3).
        prior_scale: Scale used when the centres do not determine it.
        min_spread: The RMS distance of C_b from its mean below which they do not.

    Returns:
        The similarity a <- b.
    """
    rotation = so3.project(np.einsum('pij,pkj->ik', R_a, R_b))
    # np.mean's sum and division, without its wrapper.
    mean_a = np.add.reduce(C_a, axis=0) / C_a.shape[0]
    mean_b = np.add.reduce(C_b, axis=0) / C_b.shape[0]
    rb = (C_b - mean_b) @ rotation.T
    denom = float(np.sum(rb * rb))
    spread = max(1e-12, C_b.shape[0] * min_spread * min_spread)
    scale = float(np.sum((C_a - mean_a) * rb)) / denom if denom > spread else prior_scale
    if not np.isfinite(scale) or scale <= 0:
        scale = prior_scale
    return Similarity(scale, rotation, mean_a - scale * rotation @ mean_b)


def compensated_parallax_angles(b1: FloatArray, b2: FloatArray) -> FloatArray:
    """Angles (rad) between matched bearings after the best rotation b1 -> b2.

    Pure rotation leaves the noise level; translation leaves each feature's parallax
    (Procrustes on bearings, so far features, which carry the rotation, dominate the fit).

    Args:
        b1: Unit bearings in the first camera, shape (K, 3).
        b2: The matching bearings in the second camera, shape (K, 3).

    Returns:
        Residual angle of each feature, radians, shape (K,) (zeros for K < 3).
    """
    if b1.shape[0] < 3:
        return np.zeros(b1.shape[0])
    U, _, Vt = np.linalg.svd(b2.T @ b1)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    R = U @ D @ Vt
    cos = np.clip(np.sum(b2 * (b1 @ R.T), axis=1), -1.0, 1.0)
    return np.asarray(np.arccos(cos), dtype=np.float64)


def rotation_compensated_parallax(b1: FloatArray, b2: FloatArray) -> float:
    """Median of :func:`compensated_parallax_angles` (rad; 0 for K < 3)."""
    if b1.shape[0] < 3:
        return 0.0
    return float(np.median(compensated_parallax_angles(b1, b2)))


MIN_SHARED_FOR_PARALLAX = 20
"""Keyframe pairs sharing fewer features do not count their parallax."""


def well_conditioned_features(store: KeyframeStore, batch: IntArray, threshold: float,
                              camera: int, need: int = MIN_SHARED_FOR_PARALLAX) -> int:
    """Return the most features with enough parallax between two keyframes of the batch.

    A feature counts when its rotation-compensated parallax (the angle left after the
    best rotation between the two keyframes' bearings) is at least ``threshold`` (rad), in
    camera ``camera``'s observations. PMBA does not need most features to have parallax (far
    ones constrain the rotations), only enough near ones to fix the structure; the median
    of a street's mostly far features can stay below any threshold for hundreds of
    keyframes. The pairs are the batch's first keyframe with every later one and every
    keyframe with the last, so features born inside the batch count too; pairs sharing
    fewer than ``need`` features (the count sought) or :data:`MIN_SHARED_FOR_PARALLAX` are
    not counted.
    """
    first, newest = int(batch[0]), int(batch[-1])
    pairs = [(first, int(j)) for j in batch[1:]] + [(int(j), newest) for j in batch[1:-1]]
    best = 0
    for a, b in pairs:
        obs_a, obs_b = store.obs[a].of_camera(camera), store.obs[b].of_camera(camera)
        shared, ia, ib = np.intersect1d(obs_a.ids, obs_b.ids, return_indices=True)
        if shared.shape[0] < max(min(need, MIN_SHARED_FOR_PARALLAX), best):
            continue
        angles = compensated_parallax_angles(obs_a.bearings[ia], obs_b.bearings[ib])
        best = max(best, int(np.count_nonzero(angles >= threshold)))
    return best


class GatheredObservations(NamedTuple):
    """Observations of some keyframes, sorted by feature, then keyframe (see below).

    Attributes:
        local: Keyframe of each observation (index into the gathered ``cams``), shape (K,).
        feat_idx: Feature of each observation (index into ``feature_ids``), shape (K,).
        feature_ids: Id of each feature, shape (N,).
        bearings: Unit bearings, shape (K, 3).
        normalized: Normalized coordinates, shape (K, 2).
        camera: Front-end camera id of each observation (K,), or None (``all_cameras``
            False: the reference camera's only).
        pixel_jac: d(pixel) / d(bearing) of each observation (K, 2, 3), NaN rows for the
            pinhole; None if every one is.
    """

    local: IntArray
    feat_idx: IntArray
    feature_ids: IntArray
    bearings: FloatArray
    normalized: FloatArray
    camera: IntArray | None
    pixel_jac: FloatArray | None = None

    def pixel_jacobians(self, fx: float, fy: float) -> FloatArray | None:
        """Return :attr:`pixel_jac` in float64, the pinhole of ``fx, fy`` in its NaN rows."""
        if self.pixel_jac is None:
            return None
        jac = self.pixel_jac.astype(np.float64)
        nominal = np.isnan(jac[:, 0, 0])
        jac[nominal] = pinhole_jacobian(self.bearings[nominal], fx, fy)
        return jac


def gather_observations(store: KeyframeStore, cams: IntArray, feature_filter: IntArray | None,
                        reference: int = 0, all_cameras: bool = True, *,
                        max_per_feature: int = 0, by_track_length: bool = False,
                        ) -> GatheredObservations:
    """Concatenate the observations of keyframes ``cams`` (optionally of some features only).

    The observations come sorted by feature, then keyframe (the order of
    :func:`~pmba_ros.core.problem.make_problem`, which then has nothing to sort): features by
    id, or with ``by_track_length`` by their number of observations, then id (the order the
    solver wants, :func:`~pmba_ros.core.normal_equations.feature_order`); the compiled loop
    (:mod:`pmba_ros.core.compiled.gather`) orders them where it runs, else
    :func:`ordered_tracks`.

    Args:
        store: The keyframes.
        cams: Keyframes to gather, in time order.
        feature_filter: Feature ids to keep, or None for all.
        reference: The reference camera (of observations without camera ids).
        all_cameras: Every camera's observations (False: the reference camera's only).
        max_per_feature: Thin every track to this many observations (:func:`_thin_sorted`);
            0 keeps all.
        by_track_length: Order the features by their number of observations.
    """
    parts = [store.obs[int(c)] for c in cams]
    if not all_cameras:
        parts = [p.of_camera(reference) for p in parts]
    ids = np.concatenate([p.ids for p in parts]) if parts else np.zeros(0, np.int64)
    offsets = np.zeros(len(parts) + 1, dtype=np.int64)
    np.cumsum(np.array([p.ids.shape[0] for p in parts], dtype=np.int64), out=offsets[1:])
    order = (compiled_gather.ordered_tracks if compiled_ready() else ordered_tracks)
    sel, local, feat_idx, feature_ids = order(ids, offsets, feature_filter, max_per_feature,
                                              by_track_length)
    camera = None
    if all_cameras:
        camera = np.full(ids.shape[0], reference, dtype=np.int64)
        if any(p.camera is not None for p in parts):
            camera = np.concatenate([p.camera if p.camera is not None else camera[:p.ids.shape[0]]
                                     for p in parts]).astype(np.int64)
        camera = camera[sel]
    bearings = np.concatenate([p.bearings for p in parts]) if parts else np.zeros((0, 3))
    pixels = np.concatenate([p.normalized for p in parts]) if parts else np.zeros((0, 2))
    jac = None
    if any(p.pixel_jac is not None for p in parts):
        jac = np.concatenate([p.pixel_jac if p.pixel_jac is not None
                              else np.full((p.ids.shape[0], 2, 3), np.nan, np.float32)
                              for p in parts])
        jac = np.take(jac, sel, axis=0)
    # np.take: the rows fancy indexing would copy, for less.
    return GatheredObservations(local, feat_idx, feature_ids, np.take(bearings, sel, axis=0),
                                np.take(pixels, sel, axis=0), camera, jac)


def ordered_tracks(ids: IntArray, offsets: IntArray, feature_filter: IntArray | None, cap: int,
                   by_length: bool) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Return the order of :func:`gather_observations` (numpy; the compiled loop agrees).

    Args:
        ids: Feature id of each observation, the keyframes' observations one after another.
        offsets: Where each keyframe's observations start in ``ids``, and their number
            (P + 1,).
        feature_filter: Feature ids to keep, or None for all.
        cap: Thin every track to this many observations (:func:`_thin_sorted`); 0 keeps all.
        by_length: Order the features by their number of observations, then id (else id).

    Returns:
        The observations kept, in order (indices into ``ids``), their keyframe (index into
        the P keyframes), their feature (index into the next) and each feature's id.
    """
    local = np.repeat(np.arange(offsets.shape[0] - 1, dtype=np.int64), np.diff(offsets))
    sel = (np.flatnonzero(np.isin(ids, feature_filter)) if feature_filter is not None
           else np.arange(ids.shape[0]))
    # ``local`` ascends: a stable sort by id orders by feature, then keyframe.
    sel = sel[np.argsort(ids[sel], kind='stable')]
    start = _run_starts(ids[sel])
    if cap:
        keep = _thin_sorted(start, cap)
        sel, start = sel[keep], start[keep]   # a track's first observation is always kept
    first = np.flatnonzero(start)
    feature_ids = ids[sel[first]]
    counts = np.diff(np.append(first, sel.shape[0]))
    if by_length:
        perm = np.argsort(counts, kind='stable')
        index, counts = run_order(counts, perm)
        sel, feature_ids = sel[index], feature_ids[perm]
    feat_idx = np.repeat(np.arange(feature_ids.shape[0], dtype=np.int64), counts)
    return sel, local[sel], feat_idx, feature_ids


def select_fixed(store: KeyframeStore, candidates: IntArray, window_feats: IntArray,
                 max_fixed: int) -> IntArray:
    """Pick up to ``max_fixed`` candidate keyframes co-observing most window features.

    Ties go to the more recent keyframe; keyframes sharing nothing are never picked.
    """
    if max_fixed == 0 or candidates.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    ids = [store.obs[int(c)].ids for c in candidates]
    owner = np.repeat(np.arange(candidates.shape[0]), [a.shape[0] for a in ids])
    shared = np.isin(np.concatenate(ids), window_feats)
    counts = np.bincount(owner[shared], minlength=candidates.shape[0])
    order = np.lexsort((-candidates, -counts))[:max_fixed]
    chosen = candidates[order][counts[order] > 0]
    return np.sort(chosen).astype(np.int64)


def unique_ids(ids: IntArray) -> IntArray:
    """Return np.unique(ids) of integer ids by a sort (numpy's hash table costs more here)."""
    ordered = np.sort(ids)
    out: IntArray = ordered[_run_starts(ordered)]
    return out


def is_in(values: IntArray, keys: IntArray) -> BoolArray:
    """Return np.isin(values, keys) of integers; by binary search where both ascend.

    Ascending values make the search's branches predictable; numpy's table serves
    unordered ones better.
    """
    if (keys.shape[0] == 0 or not (keys[1:] >= keys[:-1]).all()
            or not (values[1:] >= values[:-1]).all()):
        out: BoolArray = np.isin(values, keys)
        return out
    pos = np.minimum(np.searchsorted(keys, values), keys.shape[0] - 1)
    found: BoolArray = keys[pos] == values
    return found


def _run_starts(ordered: IntArray) -> BoolArray:
    """Return where each run of equal values of a sorted array starts, shape (K,).

    Of ids sorted by feature: where each track of observations starts.
    """
    start = np.ones(ordered.shape[0], dtype=bool)
    np.not_equal(ordered[1:], ordered[:-1], out=start[1:])
    return start


def _thin_sorted(start: BoolArray, cap: int) -> BoolArray:
    """Keep at most ``cap`` (>= 2) observations per track, evenly spread over it.

    The observations are sorted by feature, then time; ``start`` flags the first of each
    track (:func:`_run_starts`). A track's first and last (newest) observation are always
    kept. The Schur complement's cost grows with the square of a feature's observation
    count, and the interior observations of long, low-parallax tracks add little.
    """
    K = start.shape[0]
    first = np.maximum.accumulate(np.where(start, np.arange(K), 0))
    rank = np.arange(K) - first
    track = np.cumsum(start) - 1
    n = np.bincount(track)[track]
    span = np.maximum(n - 1, 1)
    k = np.rint(rank * (cap - 1) / span)
    keep: BoolArray = (n <= cap) | (np.rint(k * span / (cap - 1)) == rank)
    return keep
