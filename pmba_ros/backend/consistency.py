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
"""Never worse than the front-end: a solve's motion checked against the front-end's (issue #12).

An initialization whose steps disagree with the front-end's is not taken
(:func:`in_odom_frame`); a window solve that raised its cost, jumped the map's scale or moved
its keyframes far off the front-end's motion is rolled back (:func:`inconsistency`).
"""

from __future__ import annotations

import math

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.motion import row_norms
from pmba_ros.backend.window import (
    estimate_similarity,
    KeyframeStatus,
    KeyframeStore,
    Similarity,
)
from pmba_ros.errors import InitError


def motion_error(kf: KeyframeStore, idx: IntArray, map_scale: float) -> float:
    """Median relative error of the map's keyframe-to-keyframe translations vs odom's.

    Over the keyframes ``idx`` (each with its predecessor), the map's relative translation
    in the earlier keyframe's frame, divided by the map <- odom scale ``map_scale``, is
    compared with the front-end's; the error is relative to the front-end's step length.
    """
    b = idx[(idx > 0)]
    a = b - 1
    ok = kf.same_odom(a, b) & (kf.status[a] != KeyframeStatus.COLLECTED)
    a, b = a[ok], b[ok]
    if a.shape[0] == 0:
        return 0.0
    t_map = np.einsum('nji,nj->ni', kf.R_map[a], kf.C_map[b] - kf.C_map[a])
    t_odom = np.einsum('nji,nj->ni', kf.R_odom[a], kf.C_odom[b] - kf.C_odom[a])
    return step_error(t_map, t_odom, map_scale)


def step_error(t_map: FloatArray, t_odom: FloatArray, map_scale: float) -> float:
    """Median of :func:`relative_step_errors` (0 without a moving step)."""
    return _median(relative_step_errors(t_map, t_odom, map_scale))


def relative_step_errors(t_map: FloatArray, t_odom: FloatArray, map_scale: float) -> FloatArray:
    """Return |t_map / map_scale - t_odom| / |t_odom| of the moving steps.

    ``t_map``, ``t_odom``: the same steps (N, 3), each in its earlier keyframe's frame.
    """
    step = row_norms(t_odom)
    moving = step > 1e-6
    out: FloatArray = row_norms(t_map / map_scale - t_odom)[moving] / step[moving]
    return out


def _median(values: FloatArray) -> float:
    """Return np.median's value (NaN if any is; 0 for none), without its wrapper's cost."""
    if values.shape[0] == 0:
        return 0.0
    rel = np.sort(values)
    mid = rel.shape[0] // 2
    if np.isnan(rel[-1]):
        return math.nan
    return float(rel[mid]) if rel.shape[0] % 2 else float(0.5 * (rel[mid - 1] + rel[mid]))


def in_odom_frame(kf: KeyframeStore, used: IntArray, R_wc: FloatArray, centers_w: FloatArray,
                  max_error: float) -> tuple[FloatArray, FloatArray, Similarity, float]:
    """Return initialized poses in the odom frame, odom <- init, and their worst step error.

    The poses of keyframes ``used``: the map is expressed in the newest odom frame among them
    (map -> odom starts at identity), by a similarity fit of the keyframes with front-end
    poses. The worst step error is the largest relative error of their steps against the
    front-end's.

    Raises:
        InitError: If their steps disagree with the front-end's by more than ``max_error``
            (median, relative, :func:`step_error`): the initialization fitted something else
            than the scene (wrong tracks).
    """
    with_odom = kf.has_odom[used]
    if np.any(with_odom):   # the newest odom frame, if the front-end's jumped meanwhile
        with_odom &= kf.segment[used] == kf.segment[used[with_odom][-1]]
    sim = Similarity.identity()
    if np.count_nonzero(with_odom) >= 2:
        sim = estimate_similarity(kf.R_odom[used][with_odom], kf.C_odom[used][with_odom],
                                  R_wc[with_odom], centers_w[with_odom])
    R, C = sim.apply_poses(R_wc, centers_w)
    idx, R_i, C_i = used[with_odom], R[with_odom], C[with_odom]
    R_o, C_o = kf.R_odom[idx], kf.C_odom[idx]
    rel = relative_step_errors(np.einsum('nji,nj->ni', R_i[:-1], C_i[1:] - C_i[:-1]),
                               np.einsum('nji,nj->ni', R_o[:-1], C_o[1:] - C_o[:-1]), 1.0)
    error = _median(rel)
    if error > max_error:
        msg = f"its steps disagree with the front-end's by {100 * error:.0f} %"
        raise InitError(msg)
    return R, C, sim, float(rel.max()) if rel.shape[0] else 0.0


def inconsistency(kf: KeyframeStore, config: BackendConfig, costs: tuple[float, float],
                  scales: tuple[float, float], moved: IntArray, error_before: float) -> str:
    """Return why an applied window solve is not trusted ('' if it is).

    Checks: the cost did not increase (``costs``: before, after), the poses are finite, the
    map <- odom scale (``scales``: before, after) did not jump by more than
    ``fallback_max_scale_jump``, and the window's motion does not disagree with the
    front-end's by more than ``fallback_max_motion_error`` (relative, median,
    :func:`motion_error`) unless it already did before the solve (``error_before``).
    """
    (cost_before, cost_after), (scale_before, scale) = costs, scales
    if not (math.isfinite(cost_after) and cost_after <= cost_before * (1.0 + 1e-9)):
        return f'cost increased ({cost_before:.6g} -> {cost_after:.6g})'
    if not (np.all(np.isfinite(kf.C_map[moved])) and np.all(np.isfinite(kf.R_map[moved]))):
        return 'non-finite poses'
    if abs(math.log(scale / scale_before)) > math.log1p(config.fallback_max_scale_jump):
        return f'map <- odom scale jumped {scale_before:.4g} -> {scale:.4g}'
    error = motion_error(kf, moved, scale)
    if error > config.fallback_max_motion_error and error > error_before:
        return (f'motion differs from the front-end by {100 * error:.0f} % '
                f'(before the solve {100 * error_before:.0f} %)')
    return ''
