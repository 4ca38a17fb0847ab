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
"""Parallax: how far a pair's points move beyond what the best pure rotation explains.

A pair's translation direction is only known where its points show parallax once the
rotation is taken out; noise alone leaves some, in proportion to its sigma
(:data:`ROTATION_NOISE_PER_SIGMA`), and the EG pairs are gated on both
(:func:`~pmba_ros.init.two_view.estimate_eg_pairs`).
"""

from __future__ import annotations

import math

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.compiled import epipolar
from pmba_ros.core.engine import EngineName, resolve
from pmba_ros.init import covisibility

#: The median angle a pure rotation leaves, per unit of the pixel noise sigma (per axis and
#: image): both images' noise, sigma sqrt(2) per axis, has the Rayleigh median sqrt(2 ln 2)
#: times that.
ROTATION_NOISE_PER_SIGMA = math.sqrt(2.0) * math.sqrt(2.0 * math.log(2.0))


def noise_sigma(sampson: FloatArray) -> float:
    """Return the noise sigma of correspondences from their Sampson distances to a model.

    A Sampson distance is one direction of the joint four-dimensional noise, so its median
    is 0.6745 sigma. Wrong matches lie far from the model: the median is taken again over
    the distances within 3 sigma of the last estimate (twice), which a tenth of wrong
    matches would otherwise raise by a tenth or more.
    """
    sigma = float(np.median(sampson)) / 0.6745
    for _ in range(2):
        near = sampson[sampson <= 3.0 * sigma]
        if near.shape[0] < 5:
            break
        sigma = float(np.median(near)) / 0.6745
    return sigma


def _segment_medians(values: FloatArray, segment: IntArray, n_segments: int) -> FloatArray:
    """Return the median of ``values`` within each segment id (0 for an empty segment)."""
    # One sort of segment + a value squashed into [0, 1): cheaper than a two-key lexsort.
    lo_v, hi_v = (float(values.min()), float(values.max())) if values.size else (0.0, 0.0)
    squashed = (values - lo_v) / ((hi_v - lo_v) * (1.0 + 1e-9) + 1e-300)
    v = values[np.argsort(segment + squashed)]
    counts = np.bincount(segment, minlength=n_segments)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    lo = starts + np.maximum(counts - 1, 0) // 2
    hi = starts + counts // 2
    med = np.zeros(n_segments)
    has = counts > 0
    med[has] = 0.5 * (v[lo[has]] + v[hi[has]])
    return med


def _procrustes(cov: FloatArray) -> FloatArray:
    """Return the rotations R (P, 3, 3) that maximise tr(R^T cov) (orthogonal Procrustes)."""
    U, _, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= np.where(d == 0.0, 1.0, d)[:, None]
    R: FloatArray = U @ Vt
    return R


def rotation_only_parallaxes(b1: FloatArray, b2: FloatArray, segment: IntArray,
                             n_segments: int, mask: BoolArray | None = None,
                             engine: EngineName | str = EngineName.AUTO) -> FloatArray:
    """Return, per segment, the median angle (rad) left between b2 and R b1 by the best R.

    R is the orthogonal Procrustes fit (b2 ~ R b1) of each segment (pair) of correspondences.
    For a pair without baseline (pure rotation) the result is at noise level, whatever the
    essential matrix says.

    Args:
        b1: Unit bearings in camera 1, shape (C, 3).
        b2: Unit bearings in camera 2, shape (C, 3).
        segment: Segment (pair) of every correspondence, shape (C,), values < n_segments,
            sorted.
        n_segments: Number of segments P.
        mask: Optional correspondences to use, shape (C,) (None: all).
        engine: The compiled loops (``'auto'``: where numba runs) or the numpy code.

    Returns:
        Median angles, shape (P,) (0 for a segment without correspondences).
    """
    if resolve(engine).name is EngineName.COMPILED:
        use = np.ones(segment.shape[0], dtype=bool) if mask is None else mask
        R = _procrustes(epipolar.rotation_covariances(b1, b2, segment, use, n_segments))
        return epipolar.median_angles(R, b1, b2, segment, use, n_segments)
    if mask is not None:
        b1, b2, segment = b1[mask], b2[mask], segment[mask]
    outer = (b2[:, :, None] * b1[:, None, :]).reshape(-1, 9)
    cov = np.stack([np.bincount(segment, weights=outer[:, c], minlength=n_segments)
                    for c in range(9)], axis=1).reshape(n_segments, 3, 3)
    R = _procrustes(cov.astype(float))
    cosang = np.clip(np.sum(b2 * np.einsum('kij,kj->ki', R[segment], b1), axis=1), -1.0, 1.0)
    return _segment_medians(np.arccos(cosang), segment, n_segments)


def pair_focal_px(offsets: IntArray, obs_a: IntArray, obs_b: IntArray,
                  focal_px: FloatArray) -> FloatArray:
    """Return each pair's focal length (px), sqrt(f_a f_b) at its first correspondence (P,).

    Every pair has a correspondence (``offsets`` strictly increasing).
    """
    first = offsets[:-1]
    f_pair: FloatArray = np.sqrt(focal_px[obs_a[first]] * focal_px[obs_b[first]])
    return f_pair


def sampled_parallax_px(corr: covisibility.PairCorrespondences, bearings_c: FloatArray,
                        focal_px: FloatArray, max_points: int = 100) -> FloatArray:
    """Return a quick median rotation-compensated parallax (px) of every candidate pair.

    :func:`rotation_only_parallaxes` on at most ``max_points`` of each pair's
    correspondences (evenly spread, outliers included): a cheap estimate before any RANSAC,
    to prefer pairs with a baseline.

    Args:
        corr: Candidate pairs.
        bearings_c: Unit bearings of all observations, shape (K, 3).
        focal_px: Focal length of the observing camera of every observation, shape (K,).
        max_points: Correspondences used per pair.

    Returns:
        Parallax estimates, shape (P,) (px, with the pair's mean focal length).
    """
    n = corr.counts()
    m = np.minimum(n, max_points)
    seg = np.repeat(np.arange(corr.n_pairs), m)
    i = np.arange(seg.shape[0]) - np.repeat(np.cumsum(m) - m, m)
    rows = corr.offsets[seg] + (i * n[seg]) // np.maximum(m[seg], 1)
    ia, ib = corr.obs_a[rows], corr.obs_b[rows]
    return (rotation_only_parallaxes(bearings_c[ia], bearings_c[ib], seg, corr.n_pairs)
            * pair_focal_px(corr.offsets, corr.obs_a, corr.obs_b, focal_px))
