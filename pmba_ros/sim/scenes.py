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
"""Deterministic simulated bundle-adjustment scenes (ground truth, noisy tracks, a start).

Every scene is a function of its arguments and ``seed`` alone: all randomness comes from one
``rng = np.random.default_rng(seed)``, drawn in a fixed order (geometry, pixel noise, start
perturbation). Visibility and projection are vectorized over points; only cameras are looped.

World frame of the street and Table-3 scenes: x forward (the direction of motion), y left,
z up. Cameras use the package convention (x right, y down, z forward), so an unrotated
forward-looking camera has ``R_wc = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]``.

==============  ============================================================================
name            meaning
==============  ============================================================================
gt              true poses and points, observations = true projections + N(0, noise_px^2)
start           the same observations; poses (except pose 0) and points perturbed
far_mask        (N,) features generated far away (up to ``max_depth_baselines`` baselines)
collinear_mask  (N,) features generated nearly on the line of motion (tiny parallax)
==============  ============================================================================
"""

from __future__ import annotations

from dataclasses import dataclass
import logging
from typing import TYPE_CHECKING

import numpy as np
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.core.problem import BAProblem, make_problem

if TYPE_CHECKING:
    from collections.abc import Callable

    from pmba_ros._typing import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)

__all__ = ['SimScene', 'aerial_scene', 'shuffle_cameras', 'street_scene', 'synthetic_large',
           'table3_scene']

_WORLD_UP = np.array([0.0, 0.0, 1.0])
_COLLINEAR_DEG = 0.5
"""Largest angle (deg) between a collinear feature's ray and the direction of motion."""
_FAR_MIN_BASELINES = 20.0
_NEAR_MAX_DEPTH_BASELINES = 50.0
_OVERSAMPLE = 3


@dataclass(frozen=True, eq=False)
class SimScene:
    """A simulated scene.

    Attributes:
        gt: True poses and points with the noisy pixel observations.
        start: The same observations (same ``obs`` object) with perturbed poses and points.
        noise_px: Standard deviation of the pixel noise (per axis, px).
        far_mask: Features generated far away, shape (N,) (None if the scene has no labels).
        collinear_mask: Features generated nearly on the line of motion, shape (N,).
    """

    gt: BAProblem
    start: BAProblem
    noise_px: float
    far_mask: BoolArray | None = None
    collinear_mask: BoolArray | None = None


def street_scene(seed: int = 0, n_cams: int = 20, n_points: int = 500, noise_px: float = 0.5,
                 step_m: float = 1.0, far_fraction: float = 0.3,
                 max_depth_baselines: float = 1e4, rot_noise_deg: float = 1.0,
                 pos_noise_m: float = 0.1, point_noise_rel: float = 0.1,
                 image_size: tuple[int, int] = (640, 480), focal_px: float = 500.0,
                 max_track_length: int | None = None, *, collinear_fraction: float = 0.1,
                 jitter_m: float = 0.0, jitter_deg: float = 0.0) -> SimScene:
    """Simulate a camera driving straight down a street (forward, collinear motion).

    Camera i is at ``(i step_m, 0, 0)`` (plus optional jitter) looking along +x. Near features
    lie on two walls (y = +-5 step_m, -1.5 to 6 step_m high) and the ground (z = -1.5 step_m)
    and are detected up to 50 baselines away. Far features lie 20 to ``max_depth_baselines``
    baselines ahead (log-uniform depth) inside the field of view; a ``collinear_fraction`` of
    them lie within 0.5 deg of the line of motion. A feature is observed when it is in front of
    the camera (depth > 1 baseline) and projects inside the image; with ``max_track_length``
    its track is cut to that many consecutive cameras (far features then start at a random
    camera), so long sequences have local tracks. Candidates are oversampled and the first
    ``n_points`` seen by >= 2 cameras are kept (fewer if the geometry cannot supply them, with
    a logged warning).

    Args:
        seed: Seed of the random generator.
        n_cams: Number of poses M (>= 2).
        n_points: Number of features N wanted.
        noise_px: Pixel noise standard deviation per axis (px).
        step_m: Distance between consecutive cameras (the baseline); the scene scales with it.
        far_fraction: Fraction of far features in [0, 1].
        max_depth_baselines: Largest depth of far features, in baselines.
        rot_noise_deg: Start rotation noise, per axis (deg).
        pos_noise_m: Start position noise, per axis (m).
        point_noise_rel: Start point noise per axis, relative to the distance from the
            feature's first observing camera.
        image_size: Image width and height (px).
        focal_px: Focal length (px); the principal point is the image centre, no distortion.
        max_track_length: Longest track (consecutive cameras); None for no limit.
        collinear_fraction: Fraction of the far features that are nearly collinear with the
            motion (at least one if there are far features).
        jitter_m: Standard deviation of the lateral / vertical camera jitter (m).
        jitter_deg: Standard deviation of the camera rotation jitter per axis (deg).

    Returns:
        The scene, with ``far_mask`` and ``collinear_mask`` set.

    Raises:
        ValueError: On invalid arguments.
    """
    _check_common(n_cams, n_points, noise_px, image_size, focal_px)
    if not 0.0 <= far_fraction <= 1.0 or not 0.0 <= collinear_fraction <= 1.0:
        msg = 'street_scene: far_fraction and collinear_fraction must be in [0, 1]'
        raise ValueError(msg)
    if not step_m > 0 or not max_depth_baselines > 1:
        msg = 'street_scene: step_m must be positive and max_depth_baselines > 1'
        raise ValueError(msg)
    if max_track_length is not None and max_track_length < 2:
        msg = f'street_scene: max_track_length must be >= 2, got {max_track_length}'
        raise ValueError(msg)
    rng = np.random.default_rng(seed)
    s = float(step_m)
    width, height = image_size
    intr = Intrinsics.uniform(n_cams, focal_px, focal_px, width / 2.0, height / 2.0)

    # Poses: straight forward motion along world x.
    centers_w = np.zeros((n_cams, 3))
    centers_w[:, 0] = np.arange(n_cams) * s
    if jitter_m > 0:
        centers_w[:, 1:] += rng.normal(0.0, jitter_m, (n_cams, 2))
    forward = np.tile([1.0, 0.0, 0.0], (n_cams, 1))
    R_wc = _look_along(forward)
    if jitter_deg > 0:
        R_wc = R_wc @ so3.exp(rng.normal(0.0, np.deg2rad(jitter_deg), (n_cams, 3)))

    # Candidate features.
    n_far = round(far_fraction * n_points)
    n_near = n_points - n_far
    n_col = max(1, round(collinear_fraction * n_far)) if n_far else 0
    near = _street_near_points(rng, _OVERSAMPLE * n_near, n_cams, s)
    x_last = (n_cams - 1) * s
    n_far_cand = _OVERSAMPLE * n_far
    if max_track_length is None:
        birth = np.full(n_far_cand, n_cams - 1)
    else:
        birth = rng.integers(0, n_cams - 1, n_far_cand)
    lo = min(_FAR_MIN_BASELINES, 0.5 * max_depth_baselines)
    depth = s * np.exp(rng.uniform(np.log(lo), np.log(max_depth_baselines), n_far_cand))
    collinear = np.zeros(n_far_cand, dtype=bool)
    collinear[:_OVERSAMPLE * n_col] = True
    # Far rays: uniform over the central 80 % of the image, or within 0.5 deg of the motion.
    half = np.array([width, height]) / (2.0 * focal_px)
    xy = rng.uniform(-0.8, 0.8, (n_far_cand, 2)) * half
    col_dir = rng.normal(size=(n_far_cand, 2))
    col_dir /= np.linalg.norm(col_dir, axis=1, keepdims=True)
    col_r = np.tan(np.deg2rad(_COLLINEAR_DEG)) * np.sqrt(rng.uniform(0.0, 1.0, n_far_cand))
    xy = np.where(collinear[:, None], col_dir * col_r[:, None], xy)
    rays_c = np.column_stack([xy, np.ones(n_far_cand)])
    rays_c /= np.linalg.norm(rays_c, axis=1, keepdims=True)
    base_R = _look_along(np.array([[1.0, 0.0, 0.0]]))[0]
    anchor = np.column_stack([birth * s, np.zeros((n_far_cand, 2))])
    if max_track_length is None:
        anchor[:, 0] = x_last
    far = anchor + depth[:, None] * (rays_c @ base_R.T)

    points = np.concatenate([near, far])
    kind_far = np.concatenate([np.zeros(len(near), bool), np.ones(n_far_cand, bool)])
    kind_col = np.concatenate([np.zeros(len(near), bool), collinear])
    birth_all = np.concatenate([np.zeros(len(near), np.int64), birth])
    cam_idx, feat_idx, pix = _observe(R_wc, centers_w, points, intr, image_size,
                                      min_depth=s, max_depth=_NEAR_MAX_DEPTH_BASELINES * s,
                                      no_depth_limit=kind_far, birth=birth_all,
                                      max_track_length=max_track_length,
                                      candidates=_street_candidates(
                                          near[:, 0], birth, centers_w[:, 0], s,
                                          max_track_length))
    counts = np.bincount(feat_idx, minlength=len(points))
    ok = counts >= 2
    chosen = np.concatenate([
        _first_true(ok & ~kind_far, n_near),
        _first_true(ok & kind_col, n_col),
        _first_true(ok & kind_far & ~kind_col, n_far - n_col),
    ])
    chosen.sort()
    if chosen.size < n_points:
        logger.warning('street_scene: only %d of %d features are seen by >= 2 cameras',
                       chosen.size, n_points)
    return _finish(rng, R_wc, centers_w, intr, points, cam_idx, feat_idx, pix, chosen,
                   noise_px, rot_noise_deg, pos_noise_m, point_noise_rel,
                   kind_far, kind_col)


def table3_scene(seed: int = 0, noise_px: float = 0.5, rot_noise_deg: float = 1.0,
                 pos_noise_m: float = 0.05, point_noise_rel: float = 0.1) -> SimScene:
    """Simulate the PMBA paper's Table 3 setting: 4 poses, 10 features, 2 of them problematic.

    Four cameras 1 baseline (1 m) apart move straight forward along world x, looking along
    the motion (640x480 px, f = 500 px). Eight well-conditioned features lie 6 to 9 m ahead
    and 0.8 to 1.8 m to the side (parallax of several degrees). Feature 8 is extremely far
    (1e4 baselines ahead, within 15 deg of the optical axis); feature 9 is nearly collinear
    with the motion (0.2 to 0.4 deg off the line of motion, 12 to 20 m ahead). All 10 features
    are seen by all 4 cameras (40 observations).

    Args:
        seed: Seed of the random generator.
        noise_px: Pixel noise standard deviation per axis (px).
        rot_noise_deg: Start rotation noise, per axis (deg).
        pos_noise_m: Start position noise, per axis (m).
        point_noise_rel: Start point noise per axis, relative to the point's distance from
            the first camera.

    Returns:
        The scene; ``far_mask`` marks feature 8 and ``collinear_mask`` feature 9.

    Raises:
        ValueError: If ``noise_px`` is negative.
    """
    _check_common(4, 10, noise_px, (640, 480), 500.0)
    rng = np.random.default_rng(seed)
    n_cams = 4
    centers_w = np.zeros((n_cams, 3))
    centers_w[:, 0] = np.arange(n_cams, dtype=float)
    R_wc = _look_along(np.tile([1.0, 0.0, 0.0], (n_cams, 1)))
    intr = Intrinsics.uniform(n_cams, 500.0, 500.0, 320.0, 240.0)
    good = np.column_stack([
        rng.uniform(6.0, 9.0, 8),
        rng.choice([-1.0, 1.0], 8) * rng.uniform(0.8, 1.8, 8),
        rng.uniform(-1.2, 1.2, 8),
    ])
    az, el = np.deg2rad(rng.uniform(-15.0, 15.0, 2))
    far = 1e4 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    off = np.deg2rad(rng.uniform(0.2, 0.4))
    phi = rng.uniform(0.0, 2.0 * np.pi)
    dist = rng.uniform(12.0, 20.0)
    collinear = dist * np.array([np.cos(off), np.sin(off) * np.cos(phi),
                                 np.sin(off) * np.sin(phi)])
    points = np.vstack([good, far, collinear])
    kind_far = np.zeros(10, dtype=bool)
    kind_far[8] = True
    kind_col = np.zeros(10, dtype=bool)
    kind_col[9] = True
    cam_idx, feat_idx, pix = _observe(R_wc, centers_w, points, intr, (640, 480),
                                      min_depth=0.5, max_depth=np.inf)
    if len(cam_idx) != 40:  # pragma: no cover - the layout above guarantees full visibility
        msg = f'table3_scene: expected 40 observations, got {len(cam_idx)}'
        raise RuntimeError(msg)
    return _finish(rng, R_wc, centers_w, intr, points, cam_idx, feat_idx, pix, np.arange(10),
                   noise_px, rot_noise_deg, pos_noise_m, point_noise_rel, kind_far, kind_col)


def shuffle_cameras(scene: SimScene, seed: int) -> SimScene:
    """Return the same scene with the camera indices permuted (an unordered image set).

    New camera k is old camera ``perm[k]`` with ``perm = default_rng(seed).permutation(M)``;
    poses, intrinsics, fixed flags and observations (pixels and bearings) follow. Features and
    their order are unchanged.

    Args:
        scene: The scene to permute.
        seed: Seed of the permutation.

    Returns:
        The permuted scene.

    Raises:
        ProblemError: If the scene's problems are inconsistent (not expected).
    """
    M = scene.gt.n_cams
    perm = np.random.default_rng(seed).permutation(M)
    inv = np.empty(M, dtype=np.int64)
    inv[perm] = np.arange(M)

    def permute(p: BAProblem) -> BAProblem:
        return make_problem(p.R_wc[perm], p.centers_w[perm], p.intrinsics.take(perm),
                            inv[p.obs.cam_idx], p.obs.feat_idx, p.obs.pixels,
                            bearings_c=p.obs.bearings_c, points_w=p.points_w,
                            fixed=p.fixed[perm], n_feats=p.n_feats, feature_ids=p.feature_ids)

    gt = permute(scene.gt)
    start = gt.with_poses(scene.start.R_wc[perm], scene.start.centers_w[perm])
    start = start.with_points(scene.start.points_w)
    return SimScene(gt, start, scene.noise_px, scene.far_mask, scene.collinear_mask)


def synthetic_large(seed: int = 0, n_cams: int = 100, n_points: int = 20000,
                    noise_px: float = 0.5, radius_m: float = 10.0,
                    max_incidence_deg: float = 30.0, rot_noise_deg: float = 1.0,
                    pos_noise_m: float = 0.1, point_noise_rel: float = 0.1,
                    image_size: tuple[int, int] = (640, 480),
                    focal_px: float = 500.0) -> SimScene:
    """Simulate a benchmark-size scene: a ring of cameras around a textured cylinder.

    Cameras sit on a circle of radius ``radius_m`` (heights within +-0.5 m) and look at the
    axis. Features lie on a vertical cylinder of radius 0.3 ``radius_m`` and height
    +-0.2 ``radius_m``; a camera sees a feature when it is in front, inside the image and
    within ``max_incidence_deg`` of the surface normal (about 12 cameras per feature with the
    defaults, i.e. ~240k observations for 20000 features).

    Args:
        seed: Seed of the random generator.
        n_cams: Number of poses M (>= 2).
        n_points: Number of candidate features (those seen by < 2 cameras are dropped).
        noise_px: Pixel noise standard deviation per axis (px).
        radius_m: Radius of the camera ring (m).
        max_incidence_deg: Largest angle between the surface normal and the ray to a camera.
        rot_noise_deg: Start rotation noise, per axis (deg).
        pos_noise_m: Start position noise, per axis (m).
        point_noise_rel: Start point noise per axis, relative to the distance from the
            feature's first observing camera.
        image_size: Image width and height (px).
        focal_px: Focal length (px).

    Returns:
        The scene (``far_mask`` and ``collinear_mask`` all False).

    Raises:
        ValueError: On invalid arguments.
    """
    _check_common(n_cams, n_points, noise_px, image_size, focal_px)
    if not radius_m > 0 or not 0 < max_incidence_deg < 90:
        msg = 'synthetic_large: radius_m must be positive and max_incidence_deg in (0, 90)'
        raise ValueError(msg)
    rng = np.random.default_rng(seed)
    psi = 2.0 * np.pi * np.arange(n_cams) / n_cams
    centers_w = np.column_stack([radius_m * np.cos(psi), radius_m * np.sin(psi),
                                 rng.uniform(-0.5, 0.5, n_cams)])
    R_wc = _look_along(-centers_w * np.array([1.0, 1.0, 0.0]))
    width, height = image_size
    intr = Intrinsics.uniform(n_cams, focal_px, focal_px, width / 2.0, height / 2.0)
    phi = rng.uniform(0.0, 2.0 * np.pi, n_points)
    r_cyl = 0.3 * radius_m
    points = np.column_stack([r_cyl * np.cos(phi), r_cyl * np.sin(phi),
                              rng.uniform(-0.2, 0.2, n_points) * radius_m])
    normals = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n_points)])
    cam_idx, feat_idx, pix = _observe(R_wc, centers_w, points, intr, image_size,
                                      min_depth=0.1 * radius_m, max_depth=np.inf,
                                      normals=normals,
                                      max_incidence_rad=np.deg2rad(max_incidence_deg))
    none = np.zeros(n_points, dtype=bool)
    return _finish(rng, R_wc, centers_w, intr, points, cam_idx, feat_idx, pix,
                   np.arange(n_points), noise_px, rot_noise_deg, pos_noise_m,
                   point_noise_rel, none, none)


def aerial_scene(seed: int = 0, rows: int = 6, cols: int = 6, n_points: int = 5000,
                 noise_px: float = 0.5, *, height_m: float = 50.0, relief_m: float = 1.0,
                 focal_px: float = 800.0, image_size: tuple[int, int] = (1000, 750),
                 tilt_deg: float = 0.5) -> SimScene:
    """Return a survey flight: nadir images over nearly flat ground, in back-and-forth lines.

    ``rows`` flight lines of ``cols`` images each, at ``height_m`` above ground; images a
    quarter of the height apart along a line, lines 0.35 of it apart. The ground is flat but
    for ``relief_m`` (standard deviation of the points' heights), the hard case of the
    two-view geometry (:mod:`pmba_ros.init.planar_ambiguity`). Cameras look down within
    ``tilt_deg``; image y points along -y of the world. Poses are drawn, then points, then
    noise (:func:`street_scene`'s start perturbation is not applied: ``start`` is ``gt``).
    """
    n_cams = rows * cols
    _check_common(n_cams, n_points, noise_px, image_size, focal_px)
    rng = np.random.default_rng(seed)
    line = np.arange(cols, dtype=float)
    xy = np.concatenate([np.column_stack([line if r % 2 == 0 else line[::-1],
                                          np.full(cols, float(r))]) for r in range(rows)])
    centers = np.column_stack([xy * [0.25 * height_m, 0.35 * height_m],
                               np.full(n_cams, height_m)])
    centers += rng.normal(scale=0.01 * height_m, size=(n_cams, 3))
    down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # x, y, z of cam
    tilt = so3.exp(np.deg2rad(tilt_deg) * rng.normal(size=(n_cams, 3)) / np.sqrt(3.0))
    R_wc = tilt @ down
    lo, hi = centers[:, :2].min(0) - 0.6 * height_m, centers[:, :2].max(0) + 0.6 * height_m
    points = np.column_stack([rng.uniform(lo, hi, (_OVERSAMPLE * n_points, 2)),
                              relief_m * rng.normal(size=_OVERSAMPLE * n_points)])
    intr = Intrinsics.uniform(n_cams, focal_px, focal_px, image_size[0] / 2.0,
                              image_size[1] / 2.0)
    cam_idx, feat_idx, pix = _observe(R_wc, centers, points, intr, image_size,
                                      min_depth=0.1 * height_m, max_depth=10.0 * height_m)
    seen = np.bincount(feat_idx, minlength=points.shape[0]) >= 2
    none = np.zeros(points.shape[0], dtype=bool)
    scene = _finish(rng, R_wc, centers, intr, points, cam_idx, feat_idx, pix,
                    _first_true(seen, n_points), noise_px, 0.0, 0.0, 0.0, none, none)
    return SimScene(scene.gt, scene.gt, scene.noise_px)


def _check_common(n_cams: int, n_points: int, noise_px: float, image_size: tuple[int, int],
                  focal_px: float) -> None:
    """Validate the arguments shared by the scene builders."""
    if n_cams < 2 or n_points < 1:
        msg = f'scene: need n_cams >= 2 and n_points >= 1, got {n_cams}, {n_points}'
        raise ValueError(msg)
    if not noise_px >= 0:
        msg = f'scene: noise_px must be >= 0, got {noise_px}'
        raise ValueError(msg)
    if min(image_size) <= 0 or not focal_px > 0:
        msg = f'scene: image_size and focal_px must be positive, got {image_size}, {focal_px}'
        raise ValueError(msg)


def _look_along(forward_w: FloatArray) -> FloatArray:
    """Return R_wc (M, 3, 3) of cameras looking along ``forward_w`` (M, 3), image y down.

    The camera y axis is world-down (-z) made orthogonal to the viewing direction, so
    ``forward_w`` must not be vertical.
    """
    z_c = forward_w / np.linalg.norm(forward_w, axis=1, keepdims=True)
    down = -_WORLD_UP - np.sum(-_WORLD_UP * z_c, axis=1, keepdims=True) * z_c
    y_c = down / np.linalg.norm(down, axis=1, keepdims=True)
    x_c = np.cross(y_c, z_c)
    return np.stack([x_c, y_c, z_c], axis=2)


def _street_candidates(near_x: FloatArray, far_birth: IntArray, cam_x: FloatArray, s: float,
                       max_track_length: int | None) -> Callable[[int], IntArray]:
    """Return candidates(i): near points within reach of camera i, and the far points.

    Far points follow the near ones in the point array. The points themselves stay in
    generation order (so that keeping the first qualifying candidates is unbiased); only the
    index lists are sorted, by x (near) and by birth camera (far).
    """
    n_near = near_x.shape[0]
    near_order = np.argsort(near_x, kind='stable')
    near_sorted = near_x[near_order]
    slack = 10.0 * s  # covers jitter: a visible near point has depth in (s, 50 s)
    lo = np.searchsorted(near_sorted, cam_x - slack)
    hi = np.searchsorted(near_sorted, cam_x + _NEAR_MAX_DEPTH_BASELINES * s + slack)
    far_order = np.argsort(far_birth, kind='stable')
    birth_sorted = far_birth[far_order]
    all_far = n_near + far_order

    def candidates(i: int) -> IntArray:
        if max_track_length is None:
            far = all_far
        else:
            f_lo = np.searchsorted(birth_sorted, i - max_track_length + 1)
            f_hi = np.searchsorted(birth_sorted, i, side='right')
            far = all_far[f_lo:f_hi]
        return np.concatenate([near_order[lo[i]:hi[i]], far])

    return candidates


def _street_near_points(rng: np.random.Generator, n: int, n_cams: int, s: float) -> FloatArray:
    """Sample ``n`` points on the street walls (y = +-5 s) and ground (z = -1.5 s)."""
    half_width, ground, wall_top = 5.0 * s, -1.5 * s, 6.0 * s
    x = rng.uniform(0.0, (n_cams - 1) * s + _NEAR_MAX_DEPTH_BASELINES * s, n)
    surface = rng.choice(3, size=n, p=[0.4, 0.4, 0.2])  # left wall, right wall, ground
    y = np.where(surface == 0, half_width, -half_width)
    z = rng.uniform(ground, wall_top, n)
    on_ground = surface == 2
    y = np.where(on_ground, rng.uniform(-half_width, half_width, n), y)
    z = np.where(on_ground, ground, z)
    return np.column_stack([x, y, z])


def _observe(R_wc: FloatArray, centers_w: FloatArray, points_w: FloatArray, intr: Intrinsics,
             image_size: tuple[int, int], *, min_depth: float, max_depth: float,
             no_depth_limit: BoolArray | None = None, birth: IntArray | None = None,
             max_track_length: int | None = None, normals: FloatArray | None = None,
             max_incidence_rad: float = np.pi / 2,
             candidates: Callable[[int], IntArray] | None = None,
             ) -> tuple[IntArray, IntArray, FloatArray]:
    """Return cam_idx, feat_idx and true pixels of every visible (camera, point) pair.

    A point is visible from camera i if ``min_depth < depth`` (and ``depth < max_depth``
    unless ``no_depth_limit``), it projects inside the image, it faces the camera (when
    ``normals`` are given), and, with ``max_track_length`` L, ``i >= birth`` and i is among
    the first L cameras after the point was first seen. ``candidates(i)`` may restrict the
    points tested for camera i (a speed-up; it must include every point camera i can see).
    """
    N = points_w.shape[0]
    width, height = image_size
    first_seen = np.full(N, -1, dtype=np.int64)
    cos_max = np.cos(max_incidence_rad)
    cams: list[IntArray] = []
    feats: list[IntArray] = []
    pixels: list[FloatArray] = []
    everything = np.arange(N)
    for i in range(R_wc.shape[0]):
        sub = everything if candidates is None else candidates(i)
        d_w = points_w[sub] - centers_w[i]
        h = d_w @ R_wc[i]  # camera-frame coordinates R_wc^T (X - C)
        vis = h[:, 2] > min_depth
        too_far = h[:, 2] >= max_depth
        if no_depth_limit is not None:
            too_far &= ~no_depth_limit[sub]
        vis &= ~too_far
        if normals is not None:
            dist = np.linalg.norm(d_w, axis=1)
            vis &= -np.sum(normals[sub] * d_w, axis=1) > cos_max * dist
        sel = np.flatnonzero(vis)
        idx = sub[sel]
        pix = project(h[sel], intr, np.full(idx.size, i))
        inside = ((pix[:, 0] >= 0) & (pix[:, 0] < width) & (pix[:, 1] >= 0)
                  & (pix[:, 1] < height))
        idx, pix = idx[inside], pix[inside]
        if max_track_length is not None:
            born = np.ones(idx.size, dtype=bool) if birth is None else i >= birth[idx]
            idx, pix = idx[born], pix[born]
            new = first_seen[idx] < 0
            first_seen[idx[new]] = i
            in_window = i - first_seen[idx] < max_track_length
            idx, pix = idx[in_window], pix[in_window]
        cams.append(np.full(idx.size, i, dtype=np.int64))
        feats.append(idx.astype(np.int64))
        pixels.append(pix)
    return np.concatenate(cams), np.concatenate(feats), np.concatenate(pixels)


def _first_true(mask: BoolArray, n: int) -> IntArray:
    """Return the indices of the first ``n`` True entries of ``mask``."""
    return np.flatnonzero(mask)[:max(n, 0)].astype(np.int64)


def _finish(rng: np.random.Generator, R_wc: FloatArray, centers_w: FloatArray,
            intr: Intrinsics, points_w: FloatArray, cam_idx: IntArray, feat_idx: IntArray,
            true_px: FloatArray, chosen: IntArray, noise_px: float, rot_noise_deg: float,
            pos_noise_m: float, point_noise_rel: float, kind_far: BoolArray,
            kind_col: BoolArray) -> SimScene:
    """Keep the ``chosen`` features, add pixel noise, build gt and start problems."""
    new_id = np.full(points_w.shape[0], -1, dtype=np.int64)
    new_id[chosen] = np.arange(chosen.size)
    keep = new_id[feat_idx] >= 0
    cam_idx, feat_idx, true_px = cam_idx[keep], new_id[feat_idx[keep]], true_px[keep]
    order = np.lexsort((cam_idx, feat_idx))  # noise is drawn in (feature, camera) order
    cam_idx, feat_idx, true_px = cam_idx[order], feat_idx[order], true_px[order]
    pixels = true_px + rng.normal(0.0, noise_px, true_px.shape) if noise_px > 0 else true_px
    gt = make_problem(R_wc, centers_w, intr, cam_idx, feat_idx, pixels,
                      points_w=points_w[chosen], n_feats=chosen.size,
                      feature_ids=np.arange(chosen.size, dtype=np.int64))
    far_mask = kind_far[chosen][gt.feature_ids]
    col_mask = kind_col[chosen][gt.feature_ids]
    far_mask.flags.writeable = False
    col_mask.flags.writeable = False

    M = gt.n_cams
    dR = so3.exp(rng.normal(0.0, np.deg2rad(rot_noise_deg), (M, 3)))
    dC = rng.normal(0.0, pos_noise_m, (M, 3))
    dR[0] = np.eye(3)  # pose 0 keeps its true value
    dC[0] = 0.0
    points_gt = points_w[chosen][gt.feature_ids]
    first_cam = gt.obs.cam_idx[gt.feature_offsets()[:-1]]
    dist = np.linalg.norm(points_gt - gt.centers_w[first_cam], axis=1)
    dX = rng.normal(0.0, 1.0, (gt.n_feats, 3)) * (point_noise_rel * dist)[:, None]
    start = gt.with_poses(gt.R_wc @ dR, gt.centers_w + dC).with_points(points_gt + dX)
    logger.info('scene: %d cameras, %d features, %d observations, noise %.3g px', M,
                gt.n_feats, gt.n_obs, noise_px)
    return SimScene(gt, start, float(noise_px), far_mask, col_mask)
