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
"""Harder variants of an existing problem, for stress-testing the global initialization.

Each function takes a :class:`~pmba_ros.core.problem.BAProblem` (a file read from disk or a
simulated scene) and returns a new problem that keeps its poses and points, so PMBA started
from the file's values remains the reference. Randomness comes from ``seed`` alone.

==================  ========================================================================
variant             what changes
==================  ========================================================================
shuffled            camera order permuted (an unordered photo collection)
subset              a random fraction of the cameras kept (fewer, weaker pairs)
stride              every k-th camera kept (wider baselines, fewer common tracks)
mixed_focal         each camera's image scaled by a log-uniform factor: focal lengths and
                    principal points change, the bearings (the geometry) do not
outliers            wrong tracks added: random pixels in the cameras of real tracks
wrong_observations  a fraction of the observations moved to random pixels: single wrong
                    matches inside tracks that are otherwise right
==================  ========================================================================

Features left with fewer than two observations are dropped by
:func:`~pmba_ros.core.problem.make_problem` (counted in ``dropped``); ``feature_ids`` keep the
input's feature ids and :func:`camera_index` the input's camera ids.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.camera import Intrinsics, pixels_to_bearings
from pmba_ros.core.problem import BAProblem, make_problem
from pmba_ros.errors import ProblemError

__all__ = ['VARIANTS', 'Variant', 'make_variants', 'mixed_focal', 'outlier_tracks',
           'shuffled', 'stride', 'subset', 'wrong_observations']


@dataclass(frozen=True, eq=False)
class Variant:
    """A derived problem and where its cameras came from.

    Attributes:
        name: Variant label, e.g. ``stride3`` or ``outliers5``.
        problem: The derived problem (poses and points of the input kept).
        camera_index: Input camera of each camera of ``problem``, shape (M',).
        outlier_ids: Feature ids of the tracks added as outliers (empty for most variants).
        wrong_observations: The observations moved (empty for most variants), shape (K,).
    """

    name: str
    problem: BAProblem
    camera_index: IntArray
    outlier_ids: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    wrong_observations: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))


def _take_cameras(problem: BAProblem, order: IntArray) -> BAProblem:
    """Return the problem on cameras ``order`` (new k = old ``order[k]``), same features."""
    M = problem.n_cams
    new = np.full(M, -1, dtype=np.int64)
    new[order] = np.arange(order.shape[0])
    obs = problem.obs
    keep = new[obs.cam_idx] >= 0
    return make_problem(problem.R_wc[order], problem.centers_w[order],
                        problem.intrinsics.take(order), new[obs.cam_idx[keep]],
                        obs.feat_idx[keep], obs.pixels[keep], bearings_c=obs.bearings_c[keep],
                        points_w=problem.points_w, fixed=problem.fixed[order],
                        n_feats=problem.n_feats, feature_ids=problem.feature_ids)


def shuffled(problem: BAProblem, seed: int) -> Variant:
    """Return the problem with its cameras in a random order."""
    order = np.random.default_rng(seed).permutation(problem.n_cams)
    return Variant('shuffled', _take_cameras(problem, order), order)


def subset(problem: BAProblem, fraction: float, seed: int) -> Variant:
    """Return the problem on a random ``fraction`` of its cameras (at least 3), in order.

    Raises:
        ProblemError: If ``fraction`` is not in (0, 1].
    """
    if not 0.0 < fraction <= 1.0:
        msg = f'subset: fraction must be in (0, 1], got {fraction}'
        raise ProblemError(msg)
    M = problem.n_cams
    n = min(M, max(3, round(fraction * M)))
    order = np.sort(np.random.default_rng(seed).choice(M, size=n, replace=False))
    return Variant(f'subset{round(100 * fraction)}', _take_cameras(problem, order), order)


def stride(problem: BAProblem, step: int, offset: int = 0) -> Variant:
    """Return every ``step``-th camera from ``offset`` (wider baselines between neighbours).

    Raises:
        ProblemError: If fewer than 3 cameras would remain.
    """
    order = np.arange(offset, problem.n_cams, step)
    if step < 1 or order.shape[0] < 3:
        msg = f'stride: step {step} leaves {order.shape[0]} of {problem.n_cams} cameras (need 3)'
        raise ProblemError(msg)
    return Variant(f'stride{step}', _take_cameras(problem, order), order)


def mixed_focal(problem: BAProblem, spread: float, seed: int) -> Variant:
    """Scale each camera's image by a factor in [1/spread, spread] (log-uniform).

    Focal lengths, principal points and pixels scale together, so the bearings and the optimum
    in rays are unchanged while the pixel-space weights and thresholds of every stage see
    focal lengths that differ by up to ``spread**2`` between cameras (like Photo Tourism).

    Raises:
        ProblemError: If ``spread`` < 1.
    """
    if spread < 1.0:
        msg = f'mixed_focal: spread must be >= 1, got {spread}'
        raise ProblemError(msg)
    M = problem.n_cams
    s = np.exp(np.random.default_rng(seed).uniform(-np.log(spread), np.log(spread), M))
    intr = problem.intrinsics
    scaled = Intrinsics(intr.fx * s, intr.fy * s, intr.cx * s, intr.cy * s, intr.k1, intr.k2)
    obs = problem.obs
    pixels = obs.pixels * s[obs.cam_idx, None]
    out = make_problem(problem.R_wc, problem.centers_w, scaled, obs.cam_idx, obs.feat_idx,
                       pixels, bearings_c=obs.bearings_c, points_w=problem.points_w,
                       fixed=problem.fixed, n_feats=problem.n_feats,
                       feature_ids=problem.feature_ids)
    return Variant(f'focal{spread:g}', out, np.arange(M))


def outlier_tracks(problem: BAProblem, fraction: float, seed: int) -> Variant:
    """Add ``fraction * N`` wrong tracks: random pixels seen by the cameras of real tracks.

    Each added track copies the observing cameras of a random real track (so track lengths
    and co-visibility look real) and draws each pixel uniformly inside the bounding box of
    its camera's observations: wrong matches, not out-of-image coordinates. Its starting
    point is the point of another random track (as wrong as a matcher's would be). The added
    tracks get the feature ids after the input's largest and are listed in
    ``Variant.outlier_ids``.

    Raises:
        ProblemError: If ``fraction`` is not in [0, 1), or the problem has no points.
    """
    if not 0.0 <= fraction < 1.0:
        msg = f'outlier_tracks: fraction must be in [0, 1), got {fraction}'
        raise ProblemError(msg)
    if problem.points_w is None:
        msg = 'outlier_tracks: the problem needs starting points (triangulate them first)'
        raise ProblemError(msg)
    rng = np.random.default_rng(seed)
    N = problem.n_feats
    n_bad = round(fraction * N)
    source = rng.choice(N, size=n_bad, replace=False)
    obs = problem.obs
    offsets = problem.feature_offsets()
    counts = offsets[source + 1] - offsets[source]
    pick = np.repeat(offsets[source] - np.cumsum(counts) + counts, counts) + np.arange(
        int(counts.sum()))
    cams = obs.cam_idx[pick]
    M = problem.n_cams
    pixels = _random_pixels(problem, cams, rng)
    new_ids = int(problem.feature_ids.max(initial=-1)) + 1 + np.arange(n_bad)
    points = np.concatenate([problem.points_w, problem.points_w[rng.integers(0, N, n_bad)]])
    out = make_problem(problem.R_wc, problem.centers_w, problem.intrinsics,
                       np.concatenate([obs.cam_idx, cams]),
                       np.concatenate([obs.feat_idx, N + np.repeat(np.arange(n_bad), counts)]),
                       np.concatenate([obs.pixels, pixels]),
                       bearings_c=np.concatenate([
                           obs.bearings_c, pixels_to_bearings(pixels, problem.intrinsics, cams)]),
                       points_w=points, fixed=problem.fixed, n_feats=N + n_bad,
                       feature_ids=np.concatenate([problem.feature_ids, new_ids]))
    return Variant(f'outliers{round(100 * fraction)}', out, np.arange(M), new_ids)


def wrong_observations(problem: BAProblem, fraction: float, seed: int) -> Variant:
    """Move ``fraction`` of the observations to random pixels (as :func:`outlier_tracks` draws).

    Raises:
        ProblemError: If ``fraction`` is not in [0, 1).
    """
    if not 0.0 <= fraction < 1.0:
        msg = f'wrong_observations: fraction must be in [0, 1), got {fraction}'
        raise ProblemError(msg)
    rng = np.random.default_rng(seed)
    obs = problem.obs
    wrong = rng.random(len(obs)) < fraction
    pixels = obs.pixels.copy()
    pixels[wrong] = _random_pixels(problem, obs.cam_idx[wrong], rng)
    bearings = pixels_to_bearings(pixels, problem.intrinsics, obs.cam_idx)
    moved = replace(problem, obs=replace(obs, pixels=pixels, bearings_c=bearings))
    return Variant(f'wrong_observations{round(100 * fraction)}', moved,
                   np.arange(problem.n_cams), wrong_observations=wrong)


def _random_pixels(problem: BAProblem, cams: IntArray, rng: np.random.Generator) -> FloatArray:
    """Return a pixel for each of ``cams``, uniform in the box of its camera's observations."""
    M = problem.n_cams
    lo, hi = np.full((M, 2), np.inf), np.full((M, 2), -np.inf)
    np.minimum.at(lo, problem.obs.cam_idx, problem.obs.pixels)
    np.maximum.at(hi, problem.obs.cam_idx, problem.obs.pixels)
    pixels: FloatArray = lo[cams] + rng.uniform(size=(cams.shape[0], 2)) * (hi[cams] - lo[cams])
    return pixels


VariantMaker = Callable[[BAProblem, int], Variant]

VARIANTS: dict[str, VariantMaker] = {
    'shuffled': shuffled,
    'subset60': lambda p, seed: subset(p, 0.6, seed),
    'stride2': lambda p, seed: stride(p, 2),
    'stride3': lambda p, seed: stride(p, 3),
    'focal3': lambda p, seed: mixed_focal(p, 3.0, seed),
    'outliers5': lambda p, seed: outlier_tracks(p, 0.05, seed),
}
"""The sweep's variants by name (``seed`` is ignored by the deterministic ones)."""


def make_variants(problem: BAProblem, names: list[str] | None = None, seed: int = 0,
                  ) -> list[Variant]:
    """Return the original problem (``original``) and the named variants of it.

    Variants that cannot be made (e.g. a stride leaving fewer than 3 cameras) are skipped.

    Raises:
        ProblemError: If a name is unknown.
    """
    names = list(VARIANTS) if names is None else names
    unknown = sorted(set(names) - set(VARIANTS))
    if unknown:
        msg = f'unknown variants {unknown}; choose from {sorted(VARIANTS)}'
        raise ProblemError(msg)
    out = [Variant('original', problem, np.arange(problem.n_cams))]
    for name in names:
        try:
            out.append(VARIANTS[name](problem, seed))
        except ProblemError:
            continue
        out[-1] = replace(out[-1], name=name)
    return out
