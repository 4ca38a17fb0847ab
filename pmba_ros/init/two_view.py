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
"""Epipolar-geometry (EG) pairs: co-visible image pairs and their 5-point relative poses.

Notation (pmba.md §4, OpenCV's convention for a pair (1, 2) = (cam_a, cam_b), cam_a < cam_b):

==========  ============  ========  ===================================================
paper       code          shape     meaning
==========  ============  ========  ===================================================
R_cv        R_rel[p]      (P,3,3)   X_2 = R_cv X_1 + t_cv; with camera->world R_k,
                                    R_cv = R_2^T R_1 (so R_1 = R_2 R_cv)
t_cv        t_rel[p]      (P,3)     unit translation, t_cv ~ R_2^T (P_1 - P_2)
b1, b2      bearings      (C,3)     unit bearings of a correspondence in cams 1 and 2
==========  ============  ========  ===================================================

The pairs and their correspondences come from :mod:`pmba_ros.init.covisibility`; only the
OpenCV calls loop over pairs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
import logging

import numpy as np

try:
    import cv2
except ImportError as err:  # pragma: no cover - depends on the installation
    msg = ("PMBA's global initialization needs OpenCV: pip install 'pmba_ros[opencv]' "
           '(on ROS, rosdep installs python3-opencv)')
    raise ImportError(msg) from err

from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.compiled import chunks, epipolar
from pmba_ros.core.engine import EngineName, resolve
from pmba_ros.init import covisibility, parallax

logger = logging.getLogger(__name__)

#: OpenCV robust estimators by name (``InitOptions.ransac_method``).
RANSAC_METHODS = {'ransac': cv2.RANSAC, 'usac_accurate': cv2.USAC_ACCURATE,
                  'usac_magsac': cv2.USAC_MAGSAC, 'usac_default': cv2.USAC_DEFAULT,
                  'usac_fast': cv2.USAC_FAST}


@dataclass(frozen=True, eq=False)
class EGPairs:
    """Estimated epipolar-geometry pairs (only the successful ones).

    Attributes:
        cam_a: First camera, shape (P,).
        cam_b: Second camera, shape (P,).
        R_rel: Relative rotations R_cv = R_b^T R_a, shape (P, 3, 3).
        t_rel: Unit relative translations t_cv ~ R_b^T (P_a - P_b), shape (P, 3).
        n_inliers: Cheirality inliers, shape (P,) (the edge weight).
        offsets: CSR offsets (P+1,) into ``obs_a``/``obs_b`` (inlier correspondences only).
        obs_a: Inlier observation indices in cam_a, shape (C,).
        obs_b: Inlier observation indices in cam_b, shape (C,).
        parallax_px: Median parallax of the inliers left by the best pure rotation (px), (P,).
        noise_px: The median parallax a pure rotation would leave with the pair's noise
            (px), (P,).
    """

    cam_a: IntArray
    cam_b: IntArray
    R_rel: FloatArray
    t_rel: FloatArray
    n_inliers: IntArray
    offsets: IntArray
    obs_a: IntArray
    obs_b: IntArray
    parallax_px: FloatArray
    noise_px: FloatArray

    @property
    def n_pairs(self) -> int:
        """Return the number of pairs P."""
        return int(self.cam_a.shape[0])

    def pair_index(self) -> IntArray:
        """Return the pair of every correspondence, shape (C,)."""
        return np.repeat(np.arange(self.n_pairs), np.diff(self.offsets))

    def subset(self, keep: BoolArray) -> EGPairs:
        """Return the pairs selected by the mask ``keep`` (P,), with their correspondences."""
        keep = np.asarray(keep, dtype=bool)
        counts = np.diff(self.offsets)
        corr_keep = np.repeat(keep, counts)
        return EGPairs(self.cam_a[keep], self.cam_b[keep], self.R_rel[keep], self.t_rel[keep],
                       self.n_inliers[keep],
                       np.concatenate([[0], np.cumsum(counts[keep])]).astype(np.int64),
                       self.obs_a[corr_keep], self.obs_b[corr_keep], self.parallax_px[keep],
                       self.noise_px[keep])


def cheirality_depths(R_rel: FloatArray, t_rel: FloatArray, b1: FloatArray, b2: FloatArray,
                      ) -> tuple[FloatArray, FloatArray]:
    """Return the depths (lambda1, lambda2) with lambda1 R b1 + t = lambda2 b2 (midpoint-free).

    Args:
        R_rel: Relative rotation of each correspondence, shape (C, 3, 3) or (3, 3).
        t_rel: Relative translation, shape (C, 3) or (3,).
        b1: Unit bearings in camera 1, shape (C, 3).
        b2: Unit bearings in camera 2, shape (C, 3).

    Returns:
        Depth along b1 and along b2, shapes (C,); both positive for a point in front of both
        cameras. They are computed from cross products (no division by zero: 0 when the rays are
        parallel).

    References:
        pmba.md §4.3 (sign of the translation by the cheirality majority).
    """
    Rb1 = np.einsum('...ij,...j->...i', R_rel, b1)
    t = np.broadcast_to(t_rel, Rb1.shape)
    m = so3.cross(Rb1, b2)  # Rb1 x b2
    mm = np.maximum(np.sum(m * m, axis=1), 1e-300)
    lam1 = -np.sum(so3.cross(t, b2) * m, axis=1) / mm
    lam2 = -np.sum(so3.cross(t, Rb1) * m, axis=1) / mm
    return lam1, lam2


def _normalized(b: FloatArray) -> FloatArray:
    return np.ascontiguousarray(b[:, :2] / b[:, 2:3])


def essential_5pt(b1: FloatArray, b2: FloatArray, threshold: float, *, prob: float = 0.999,
                  method: int = cv2.USAC_FAST) -> FloatArray | None:
    """Return one pair's essential matrix (3, 3) from OpenCV's 5-point RANSAC, or None.

    Args:
        b1: Unit bearings in camera 1 (z > 0), shape (C, 3).
        b2: Unit bearings of the same features in camera 2, shape (C, 3).
        threshold: RANSAC threshold on normalized image coordinates (about px / f).
        prob: RANSAC confidence.
        method: OpenCV robust method (cv2.RANSAC or a cv2.USAC_* flag).

    References:
        PMBA Sec. 3 (EG pairs; "Kneip's 5-point" there, Nister's here: pmba.md §8 item 9).
    """
    try:
        E, mask = cv2.findEssentialMat(_normalized(b1), _normalized(b2), np.eye(3),
                                       method=method, prob=prob, threshold=threshold)
    except cv2.error as err:
        logger.debug('findEssentialMat failed: %s', err)
        return None
    if E is None or mask is None or E.shape[0] < 3:
        return None
    return np.asarray(E[:3], dtype=float)


def sampson_errors(E: FloatArray, b1: FloatArray, b2: FloatArray) -> FloatArray:
    """Return the Sampson distances of correspondences to their essential matrices.

    Args:
        E: Essential matrix of every correspondence, shape (C, 3, 3) (x2^T E x1 = 0).
        b1: Bearings in camera 1 (z > 0), shape (C, 3).
        b2: Bearings in camera 2 (z > 0), shape (C, 3).

    Returns:
        Distances on normalized image coordinates (about px / f), shape (C,).
    """
    x1 = b1 / b1[:, 2:3]
    x2 = b2 / b2[:, 2:3]
    Ex1 = np.einsum('kij,kj->ki', E, x1)
    Etx2 = np.einsum('kji,kj->ki', E, x2)
    num = np.sum(x2 * Ex1, axis=1)
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    errors: FloatArray = np.abs(num) / np.sqrt(np.maximum(den, 1e-300))
    return errors


#: Triangulated points farther than this many baselines do not count as cheirality inliers
#: (OpenCV's recoverPose rule: they carry no information on the translation).
_MAX_DEPTH_BASELINES = epipolar.MAX_DEPTH_BASELINES


def _essential_candidates(E: FloatArray) -> tuple[tuple[FloatArray, FloatArray], FloatArray]:
    """Return the two rotations (P, 3, 3) and the translation (P, 3) (up to sign) of each E."""
    U, _, Vt = np.linalg.svd(E)
    U = U * np.where(np.linalg.det(U) < 0.0, -1.0, 1.0)[:, None, None]
    Vt = Vt * np.where(np.linalg.det(Vt) < 0.0, -1.0, 1.0)[:, None, None]
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return (U @ W @ Vt, U @ W.T @ Vt), U[:, :, 2]


def decompose_essential(E: FloatArray, b1: FloatArray, b2: FloatArray, segment: IntArray,
                        inliers: BoolArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Choose each pair's (R, t) among the four of its essential matrix by cheirality.

    The candidate that puts most of the pair's ``inliers`` in front of both cameras (closer
    than 50 baselines, as OpenCV's recoverPose) wins.

    Args:
        E: Essential matrices, shape (P, 3, 3).
        b1: Unit bearings in camera 1 of every correspondence, shape (C, 3).
        b2: Unit bearings in camera 2, shape (C, 3).
        segment: Pair of every correspondence, shape (C,).
        inliers: Epipolar inliers, shape (C,).

    Returns:
        R_cv (P, 3, 3), unit t_cv (P, 3) and the cheirality inliers (C,) (epipolar inliers
        in front of both cameras).
    """
    rotations, t = _essential_candidates(E)
    P = E.shape[0]
    best_score = np.full(P, -1)
    R_best = np.zeros((P, 3, 3))
    t_best = np.zeros((P, 3))
    good_best = np.zeros(b1.shape[0], dtype=bool)
    rows = np.flatnonzero(inliers)
    seg, b1, b2 = segment[rows], b1[rows], b2[rows]
    for R in rotations:
        # The depths are linear in t: -t flips both signs, one solve serves both.
        lam1, lam2 = cheirality_depths(R[seg], t[seg], b1, b2)
        near = ((np.abs(lam1) * b1[:, 2] < _MAX_DEPTH_BASELINES)
                & (np.abs(lam2) * b2[:, 2] < _MAX_DEPTH_BASELINES))
        for sign in (1.0, -1.0):
            good = near & (sign * lam1 > 0.0) & (sign * lam2 > 0.0)
            score = np.bincount(seg[good], minlength=P)
            better = score > best_score
            best_score = np.where(better, score, best_score)
            R_best[better] = R[better]
            t_best[better] = sign * t[better]
            good_best[rows] = np.where(better[seg], good, good_best[rows])
    return R_best, t_best, good_best


def relative_pose_5pt(b1: FloatArray, b2: FloatArray, threshold: float, *,
                      prob: float = 0.999, method: int = cv2.USAC_FAST,
                      ) -> tuple[FloatArray, FloatArray, BoolArray, BoolArray] | None:
    """Estimate one pair's relative pose with OpenCV's 5-point RANSAC and the cheirality check.

    Args:
        b1: Unit bearings in camera 1 (z > 0), shape (C, 3).
        b2: Unit bearings of the same features in camera 2, shape (C, 3).
        threshold: RANSAC threshold on normalized image coordinates (about px / f).
        prob: RANSAC confidence.
        method: OpenCV robust method (cv2.RANSAC or a cv2.USAC_* flag).

    Returns:
        (R_cv (3, 3), t_cv (3,), cheirality inlier mask (C,), epipolar inlier mask (C,)), or
        None if OpenCV finds no model.
    """
    E = essential_5pt(b1, b2, threshold, prob=prob, method=method)
    if E is None:
        return None
    seg = np.zeros(b1.shape[0], dtype=np.int64)
    epi = sampson_errors(np.broadcast_to(E, (b1.shape[0], 3, 3)), b1, b2) <= threshold
    R, t, inl = decompose_essential(E[None], b1, b2, seg, epi)
    return R[0], t[0], inl, epi


def sample_evenly(n: int, max_points: int) -> IntArray:
    """Return up to ``max_points`` indices evenly spread over range(n)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def check_models(E: FloatArray, thresholds: FloatArray, b1: FloatArray, b2: FloatArray,
                 seg: IntArray, engine: EngineName | str,
                 ) -> tuple[BoolArray, IntArray, FloatArray, FloatArray, BoolArray, IntArray]:
    """Test every correspondence against its pair's model, and choose each pair's (R, t).

    Returns the epipolar inliers (C,) and their count per pair (P,), R_cv (P, 3, 3), t_cv
    (P, 3), the cheirality inliers (C,) and their count per pair (P,)
    (:func:`sampson_errors`, :func:`decompose_essential`).
    """
    P = E.shape[0]
    if resolve(engine).name is EngineName.COMPILED:
        (R0, R1), t0 = _essential_candidates(E)
        epi, n_epi, good, votes = epipolar.epipolar_votes(
            E, np.stack([R0, R1], axis=1), t0, thresholds, b1, b2, seg)
        # The first of the best-voted candidates, in decompose_essential's order.
        best = np.argmax(votes, axis=1)
        R = np.where((best < 2)[:, None, None], R0, R1)
        t = np.where((best % 2 == 0)[:, None], t0, -t0)
        inl = ((good >> best[seg].astype(np.uint8)) & 1).astype(bool)
        return epi, n_epi, R, t, inl, votes[np.arange(P), best]
    epi = sampson_errors(E[seg], b1, b2) <= thresholds[seg]
    R, t, inl = decompose_essential(E, b1, b2, seg, epi)
    return (epi, np.bincount(seg[epi], minlength=P), R, t, inl,
            np.bincount(seg[inl], minlength=P))


def estimate_eg_pairs(bearings_c: FloatArray, focal_px: FloatArray,
                      corr: covisibility.PairCorrespondences, *, threshold_px: float = 1.0,
                      min_inliers: int = 20, min_parallax_px: float = 1.0,
                      min_parallax_noise: float = 0.0,
                      prob: float = 0.999, method: int = cv2.USAC_FAST,
                      max_sample: int | None = None,
                      engine: EngineName | str = EngineName.AUTO,
                      tick: Callable[[int, int], None] | None = None,
                      ) -> tuple[EGPairs, dict[str, int]]:
    """Run the 5-point RANSAC on every co-visible pair and keep the usable ones.

    OpenCV estimates each pair's essential matrix, from at most ``max_sample`` of its
    correspondences (evenly spread); everything else is vectorized over all pairs at once:
    the epipolar inliers among all correspondences (Sampson distance), the choice of (R, t) by
    cheirality, and the parallax test. A pair is kept if its model has at least
    ``min_inliers`` cheirality inliers and the median parallax that the best pure rotation
    leaves on its epipolar inliers
    (:func:`~pmba_ros.init.parallax.rotation_only_parallaxes`) is at least
    ``min_parallax_px`` and ``min_parallax_noise`` times what the pair's noise alone would
    leave; otherwise the pair has no usable baseline (pure rotation) and its translation
    direction is undetermined. The noise is measured on the correspondences given to the
    RANSAC (:func:`~pmba_ros.init.parallax.noise_sigma`), and a pure rotation would leave
    :data:`~pmba_ros.init.parallax.ROTATION_NOISE_PER_SIGMA` times it.

    Args:
        bearings_c: Unit bearings of all observations (camera frame), shape (K, 3).
        focal_px: Focal length of the observing camera of every observation, shape (K,) (px).
        corr: Candidate pairs and correspondences.
        threshold_px: RANSAC threshold in pixels (divided by the pair's focal length).
        min_inliers: Minimum number of cheirality inliers.
        min_parallax_px: Minimum median parallax (px) left by the best pure rotation.
        min_parallax_noise: Minimum ratio of that parallax to the median a pure rotation
            would leave with the pair's noise.
        prob: RANSAC confidence.
        method: OpenCV robust method.
        max_sample: Largest number of a pair's correspondences given to the RANSAC (None:
            all of them).
        engine: The compiled loops (``'auto'``: where numba runs) or the numpy code, for the
            tests of the models on all correspondences.
        tick: Called as ``tick(pairs_taken, pairs_to_estimate)`` as the RANSACs go on
            (:func:`~pmba_ros.core.compiled.chunks.each`).

    Returns:
        The kept pairs, and counts of rejected pairs by reason.

    References:
        PMBA Sec. 3, Fig. 5 (EG pairs); pmba.md §4.1.
    """
    rejected = {'ransac_failed': 0, 'too_few_inliers': 0, 'low_parallax': 0}
    n_pairs = corr.n_pairs
    seg_all = np.repeat(np.arange(n_pairs), corr.counts())
    b1_all, b2_all = bearings_c[corr.obs_a], bearings_c[corr.obs_b]
    front = (b1_all[:, 2] > 1e-3) & (b2_all[:, 2] > 1e-3)
    n_front = np.bincount(seg_all[front], minlength=n_pairs)
    f_pair = parallax.pair_focal_px(corr.offsets, corr.obs_a, corr.obs_b, focal_px)
    thresholds = threshold_px / f_pair
    E = np.zeros((n_pairs, 3, 3))
    has_model = np.zeros(n_pairs, dtype=bool)
    noise_px = np.zeros(n_pairs)
    front_idx = np.flatnonzero(front)
    front_offsets = np.concatenate([[0], np.cumsum(n_front)])
    todo = np.flatnonzero(n_front >= max(min_inliers, 5))
    # One OpenCV call per pair; it runs without the GIL. Each pair's model is written to its
    # own row.
    cost = n_front[todo] if max_sample is None else np.minimum(n_front[todo], max_sample)

    def estimate(i: int) -> None:
        p = todo[i]
        rows = front_idx[front_offsets[p]:front_offsets[p + 1]]
        rows = rows if max_sample is None else rows[sample_evenly(rows.shape[0], max_sample)]
        b1, b2 = b1_all[rows], b2_all[rows]
        model = essential_5pt(b1, b2, float(thresholds[p]), prob=prob, method=method)
        if model is not None:
            E[p], has_model[p] = model, True
            distances = sampson_errors(np.broadcast_to(model, (rows.shape[0], 3, 3)), b1, b2)
            sigma = parallax.noise_sigma(distances)
            noise_px[p] = parallax.ROTATION_NOISE_PER_SIGMA * sigma * f_pair[p]

    chunks.each(estimate, cost, chunks.threads_for(int(np.sum(n_front[todo]))), tick)
    rejected['too_few_inliers'] += int(np.sum(n_front < max(min_inliers, 5)))
    rejected['ransac_failed'] += int(np.sum((n_front >= max(min_inliers, 5)) & ~has_model))
    sel = front & has_model[seg_all]
    # Usually every correspondence is in front and every pair has a model: no copies then.
    seg, b1, b2 = ((seg_all, b1_all, b2_all) if sel.all()
                   else (seg_all[sel], b1_all[sel], b2_all[sel]))
    epi, n_epi, R, t, inl, counts = check_models(E, thresholds, b1, b2, seg, engine)
    # Parallax on the epipolar inliers, before cheirality: without baseline the
    # cheirality test of an arbitrary t drops points at random.
    par_px = parallax.rotation_only_parallaxes(b1, b2, seg, n_pairs, epi, engine) * f_pair
    par_px = np.where(n_epi >= 5, par_px, 0.0)
    low = has_model & (par_px < np.maximum(min_parallax_px, min_parallax_noise * noise_px))
    few = has_model & ~low & (counts < min_inliers)
    rejected['low_parallax'] += int(np.sum(low))
    rejected['too_few_inliers'] += int(np.sum(few))
    keep = has_model & ~low & ~few
    inl_keep = inl & keep[seg]
    rows = np.flatnonzero(sel)[inl_keep]  # sorted by pair, as corr
    pairs = EGPairs(corr.cam_a[keep], corr.cam_b[keep], R[keep], t[keep], counts[keep],
                    np.concatenate([[0], np.cumsum(counts[keep])]).astype(np.int64),
                    corr.obs_a[rows], corr.obs_b[rows], par_px[keep], noise_px[keep])
    return pairs, rejected


def homography_poses(pairs: EGPairs, bearings_c: FloatArray, max_sample: int | None,
                     ) -> tuple[FloatArray, FloatArray, IntArray]:
    """Return the poses of every pair's homography: R (P, 4, 3, 3), unit t (P, 4, 3), count.

    OpenCV fits the homography to (a sample of) the pair's inliers by least squares, and
    decomposes it into up to four (R, t, n); the pairs whose fit fails have none. No RANSAC:
    the inliers are the 5-point model's, so where they see a plane they all fit its
    homography, and where they do not, no pose of any homography passes the test of
    :func:`pmba_ros.init.planar_ambiguity.alternatives` (a plane's second pose).
    """
    P = pairs.n_pairs
    R, t = np.zeros((P, 4, 3, 3)), np.zeros((P, 4, 3))
    count = np.zeros(P, dtype=np.int64)
    sizes = np.diff(pairs.offsets)

    def decompose(p: int) -> None:
        rows = np.arange(pairs.offsets[p], pairs.offsets[p + 1])
        if max_sample is not None:
            rows = rows[sample_evenly(rows.shape[0], max_sample)]
        b1, b2 = bearings_c[pairs.obs_a[rows]], bearings_c[pairs.obs_b[rows]]
        try:
            H, _ = cv2.findHomography(b1[:, :2] / b1[:, 2:3], b2[:, :2] / b2[:, 2:3], 0)
            if H is None or not np.all(np.isfinite(H)):
                return
            _, rotations, translations, _ = cv2.decomposeHomographyMat(H, np.eye(3))
        except cv2.error:
            return
        k = 0
        for Rk, tk in zip(rotations, translations, strict=True):
            norm = float(np.linalg.norm(tk))
            if norm > 1e-12 and k < 4:  # a zero t: the pure rotation, no epipolar geometry
                R[p, k], t[p, k], k = Rk, tk.ravel() / norm, k + 1
        count[p] = k

    cost = sizes if max_sample is None else np.minimum(sizes, max_sample)
    chunks.each(decompose, cost, chunks.threads_for(int(np.sum(cost))))
    return R, t, count


def refine_translations(pairs: EGPairs, bearings_c: FloatArray, R_wc: FloatArray,
                        engine: EngineName | str = EngineName.AUTO,
                        ) -> tuple[EGPairs, FloatArray]:
    """Re-estimate every pair's translation direction with the rotations known.

    With R = R_b^T R_a fixed, b2^T [t]x R b1 = t . (R b1 x b2), so t is the eigenvector of the
    smallest eigenvalue of sum_k m_k m_k^T, m_k = (R b1_k) x b2_k; its sign is the one that puts
    the majority of the correspondences in front of both cameras.

    Args:
        pairs: EG pairs with their inlier correspondences.
        bearings_c: Unit bearings of all observations, shape (K, 3).
        R_wc: Averaged camera -> world rotations, shape (M, 3, 3).
        engine: The compiled loops (``'auto'``: where numba runs) or the numpy code.

    Returns:
        The pairs with R_rel = R_b^T R_a and the new t_rel, and the world-frame unit direction
        d_ab = xi(P_a - P_b) = R_b t_cv of each pair, shape (P, 3).

    References:
        pmba.md §4.3 ("relative translation fine-tuning with rotation known").
    """
    R_rel = np.swapaxes(R_wc[pairs.cam_b], 1, 2) @ R_wc[pairs.cam_a]
    if resolve(engine).name is EngineName.COMPILED:
        # Bearings are read in place, through the correspondences' observation indices.
        b = np.ascontiguousarray(bearings_c, dtype=float)
        S = epipolar.epipolar_scatter(R_rel, b, pairs.obs_a, pairs.obs_b, pairs.offsets)
        t = np.linalg.eigh(S)[1][:, :, 0]  # smallest eigenvalue
        votes = epipolar.translation_votes(R_rel, t, b, pairs.obs_a, pairs.obs_b,
                                           pairs.offsets)
        return _with_translations(pairs, R_wc, R_rel, t, votes)
    pidx = pairs.pair_index()
    b1, b2 = bearings_c[pairs.obs_a], bearings_c[pairs.obs_b]
    Rb1 = np.einsum('kij,kj->ki', R_rel[pidx], b1)
    m = np.cross(Rb1, b2)
    outer = m[:, :, None] * m[:, None, :]
    starts = pairs.offsets[:-1]
    nonempty = np.diff(pairs.offsets) > 0
    S = np.zeros((pairs.n_pairs, 3, 3))
    if pidx.size:
        S[nonempty] = np.add.reduceat(outer, starts[nonempty], axis=0)
    _, vecs = np.linalg.eigh(S)
    t = vecs[:, :, 0]  # smallest eigenvalue
    lam1, lam2 = cheirality_depths(R_rel[pidx], t[pidx], b1, b2)
    signs = np.bincount(pidx, weights=np.sign(lam1) + np.sign(lam2), minlength=pairs.n_pairs)
    return _with_translations(pairs, R_wc, R_rel, t, signs.astype(float))


def _with_translations(pairs: EGPairs, R_wc: FloatArray, R_rel: FloatArray, t: FloatArray,
                       votes: FloatArray) -> tuple[EGPairs, FloatArray]:
    """Return the pairs with R_rel and t (flipped where the depth votes are negative), d_ab."""
    t = t * np.where(votes < 0, -1.0, 1.0)[:, None]
    d_world = np.einsum('pij,pj->pi', R_wc[pairs.cam_b], t)
    return replace(pairs, R_rel=R_rel, t_rel=t), d_world
