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
"""The EG pairs stage of the global initialization: which pairs get a 5-point RANSAC.

Small collections try every pair that shares ``min_pair_matches`` tracks. Larger ones try
each camera's best partners only (``max_pair_partners``), ranked on a sample of each pair's
correspondences; the full correspondences are then joined for those pairs alone, so memory
and time follow the pairs tried, not all co-visible pairs (with tracks of a hundred views,
the co-visible pairs of a few hundred cameras share about a hundred million
correspondences).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray
from pmba_ros.core.problem import BAProblem
from pmba_ros.errors import InitError
from pmba_ros.init import covisibility, parallax, planar_ambiguity, two_view
from pmba_ros.init.options import InitOptions

#: Correspondences per pair that rank the partners (the sample of
#: :func:`~pmba_ros.init.parallax.sampled_parallax_px`).
PARTNER_SAMPLE = 100


def best_partners(n_cams: int, corr: covisibility.PairCorrespondences, shared: FloatArray,
                  bearings_c: FloatArray, focal: FloatArray, max_partners: int,
                  min_parallax_px: float) -> BoolArray:
    """Return the candidate pairs worth a RANSAC: each camera's best partners.

    Half of a camera's places go to the partners sharing most tracks (``shared``, per pair
    of ``corr``: the best measured relative rotations; on real photo collections they keep
    the averaging and the BA on course), half to the partners of widest baseline: a quick
    parallax estimate on ``corr`` (a sample of each pair's correspondences is enough) times
    the square root of the shared tracks (the accuracy of the translation direction, which
    anchors the features of the CLS and NLS). Pairs whose estimate is below
    ``min_parallax_px`` (near pure rotation, rejected after the RANSAC anyway) rank last for
    both.
    """
    quick = parallax.sampled_parallax_px(corr, bearings_c, focal, PARTNER_SAMPLE)
    baseline = quick >= min_parallax_px
    rest = shared / (1.0 + float(shared.max()))  # below 1: orders only the rest by tracks
    by_tracks = covisibility.top_partners(corr.cam_a, corr.cam_b,
                                          np.where(baseline, shared, 0.0) + rest, n_cams,
                                          max_partners // 2)
    score = np.where(baseline, quick * np.sqrt(shared), 0.0) + rest
    by_baseline = covisibility.top_partners(corr.cam_a, corr.cam_b, score, n_cams,
                                            max_partners - max_partners // 2)
    return by_tracks | by_baseline


def estimate_pairs(problem: BAProblem, options: InitOptions,
                   tick: Callable[[int, int], None] | None = None,
                   ) -> tuple[two_view.EGPairs, covisibility.PairCorrespondences, dict[str, Any]]:
    """Return the EG pairs (PMBA Sec. 3), the candidates' correspondences, the report entries.

    ``tick(pairs_taken, pairs_to_estimate)`` follows the RANSACs
    (:func:`~pmba_ros.init.two_view.estimate_eg_pairs`).

    Raises:
        InitError: If no pair shares enough tracks, or none has a usable model.
    """
    obs, M = problem.obs, problem.n_cams
    counts = covisibility.covisibility_counts(obs.cam_idx, obs.feat_idx, M)
    candidates = counts >= max(options.min_pair_matches, 1)
    n_covisible = int(np.count_nonzero(candidates))
    if n_covisible == 0:
        msg = (f'global init: no image pair shares at least {options.min_pair_matches} '
               'tracks (min_pair_matches)')
        raise InitError(msg)
    focal = np.sqrt(problem.intrinsics.fx * problem.intrinsics.fy)[obs.cam_idx]
    k = options.max_pair_partners
    if k is not None and n_covisible > k * M:
        sample = covisibility.pair_correspondences(obs.cam_idx, obs.feat_idx, M, 0,
                                                   pairs=candidates,
                                                   max_per_pair=PARTNER_SAMPLE, counts=counts)
        a, b = sample.cam_a, sample.cam_b
        keep = best_partners(M, sample, counts[a, b].astype(float), obs.bearings_c, focal,
                             k, options.min_pair_parallax_px)
        candidates = np.zeros_like(candidates)
        candidates[a[keep], b[keep]] = True
    corr = covisibility.pair_correspondences(obs.cam_idx, obs.feat_idx, M, 0,
                                             pairs=candidates, counts=counts)
    pairs, rejected = two_view.estimate_eg_pairs(
        obs.bearings_c, focal, corr, threshold_px=options.ransac_threshold_px,
        min_inliers=options.min_pair_inliers, min_parallax_px=options.min_pair_parallax_px,
        min_parallax_noise=options.min_pair_parallax_noise,
        prob=options.ransac_confidence, method=two_view.RANSAC_METHODS[options.ransac_method],
        max_sample=options.ransac_max_points, tick=tick)
    entries = {'pairs_covisible': n_covisible, 'pairs_candidate': corr.n_pairs,
               'pairs_found': pairs.n_pairs,
               'pairs_rejected': rejected,
               'inliers': {'median': float(np.median(pairs.n_inliers)) if pairs.n_pairs
                           else 0.0},
               'noise_px': {'median': float(np.median(pairs.noise_px)) if pairs.n_pairs
                            else 0.0}}
    if pairs.n_pairs == 0:
        if rejected['low_parallax'] > 0 and rejected['low_parallax'] >= corr.n_pairs // 2:
            msg = (f'global init: no EG pair has a baseline: {rejected["low_parallax"]} of '
                   f'{corr.n_pairs} pairs have median parallax below '
                   f'{options.min_pair_parallax_px} px or {options.min_pair_parallax_noise} '
                   "times their noise's after removing the rotation (pure rotation? PMBA "
                   'needs anchors with a baseline, pmba.md §3.3)')
        else:
            msg = f'global init: no EG pair could be estimated (rejected: {rejected})'
        raise InitError(msg)
    # DEVIATION(Fig. 5): a pair with a plane's two poses keeps the one its triangles close.
    alt = planar_ambiguity.alternatives(pairs, obs.bearings_c, focal, options.ransac_threshold_px,
                                        options.max_pair_disagreement_deg,
                                        max_sample=options.ransac_max_points)
    pairs, turned = planar_ambiguity.resolved(pairs, alt, options.max_pair_disagreement_deg)
    entries.update(pairs_with_two_poses=int(alt.pair.size), pairs_turned=turned)
    return pairs, corr, entries
