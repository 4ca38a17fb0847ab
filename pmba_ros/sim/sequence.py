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
"""Simulated keyframe sequences for the online back-end: tracks, front-end poses, ground truth.

A sequence is what a visual front-end would hand the back-end: one :class:`TrackFrame` per
keyframe (camera 0, raw pixels with noise and the normalized coordinates undistorted from
them), a drifting front-end ("odom") pose per keyframe, the camera model, and the ground truth
to evaluate against. Everything is a function of the arguments and ``seed``
(one ``np.random.default_rng(seed)``).

World frame: x forward, y left, z up; cameras use the optical convention (x right, y down,
z forward), poses are camera -> world (``R_wc``) with camera centres.

Scenarios:

==========  =================================================================================
street      forward motion along +x at ``speed_mps`` with a gentle weave (0.3 m lateral,
            0.1 m vertical), facades at y = +-6 m, ground 1.6 m below; rays that hit nothing
            within 40 m become far features (50 m to 1 km).
aerial      a camera looking down from 40 m over uneven ground, flying along +x.
loop        a circle of radius 40 m, camera looking along the direction of travel, walls at
            radii 30 m and 50 m.
rotation    pure rotation about a fixed centre (no baseline: structure is not observable).
==========  =================================================================================

Features are spawned in front of the camera (random pixels, depth from the scenario's
geometry) at every keyframe, live up to ``max_track_length`` keyframes and stop at their first
keyframe out of view, so tracks are local and sequences of any length have bounded tracks.

Front-end drift (``drift``): the front-end integrates the true relative motions with a
heading bias of ``0.01 * drift`` rad per metre travelled (about ``drift`` of the distance as
lateral error after 200 m), a slowly oscillating scale error of amplitude ``drift``, and white
noise of ``0.2 * drift`` of each step (translation) and ``0.01 * drift`` rad (rotation).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import logging

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.backend.types import CameraModel, TrackFrame
from pmba_ros.core import so3
from pmba_ros.eval.trajectory import Trajectory

logger = logging.getLogger(__name__)

__all__ = ['MIN_KEYFRAMES', 'SCENARIOS', 'START_NS', 'SimSequence', 'observation_counts',
           'simulate_sequence', 'track_lengths']

START_NS = 1_000_000_000
"""Stamp of a simulated sequence's first keyframe, ns."""

MIN_KEYFRAMES = 2
"""Fewest keyframes of a sequence (one gives no motion, no track of two observations)."""

SCENARIOS = ('street', 'aerial', 'loop', 'rotation')
"""Scenario names accepted by :func:`simulate_sequence`."""

_WORLD_UP = np.array([0.0, 0.0, 1.0])
_MIN_DEPTH_M = 0.5
_FAR_RANGE_M = (50.0, 1000.0)
_PLUMB_BOB_D = (-0.05, 0.01, 0.0, 0.0, 0.0)

STOP_RAMP = 30
"""Keyframes over which the platform slows to a stop and speeds up again."""


@dataclass(frozen=True, eq=False)
class SimSequence:
    """A simulated keyframe sequence (F keyframes, N features).

    Attributes:
        scenario: Scenario name (one of :data:`SCENARIOS`).
        stamps_ns: Keyframe stamps, shape (F,), ns.
        R_wc_gt: True camera -> world rotations, shape (F, 3, 3).
        centers_gt: True camera centres, shape (F, 3), m.
        R_wc_odom: Front-end camera -> odom rotations (drifted), shape (F, 3, 3).
        centers_odom: Front-end camera centres in the odom frame (drifted), shape (F, 3).
        frames: One TrackFrame per keyframe (camera 0, pixels and normalized coordinates).
        camera: The camera model (pixels are distorted with it).
        points_w: True feature positions, shape (N, 3); row j is feature id j.
        noise_px: Pixel noise standard deviation per axis, px.
        drift: Front-end drift parameter.
        frame_id: Header frame id of the track frames and the odom poses.
    """

    scenario: str
    stamps_ns: IntArray
    R_wc_gt: FloatArray
    centers_gt: FloatArray
    R_wc_odom: FloatArray
    centers_odom: FloatArray
    frames: list[TrackFrame]
    camera: CameraModel
    points_w: FloatArray
    noise_px: float
    drift: float
    frame_id: str = 'odom'

    def __len__(self) -> int:
        """Return the number of keyframes F."""
        return int(self.stamps_ns.shape[0])

    def gt_trajectory(self) -> Trajectory:
        """Return the true camera trajectory (stamps in seconds)."""
        return Trajectory(self.stamps_ns.astype(np.float64) * 1e-9, self.centers_gt, self.R_wc_gt)

    def odom_trajectory(self) -> Trajectory:
        """Return the front-end camera trajectory in the odom frame (stamps in seconds)."""
        return Trajectory(self.stamps_ns.astype(np.float64) * 1e-9, self.centers_odom,
                          self.R_wc_odom)

    def with_odom_jump(self, at: int, yaw_rad: float, shift: FloatArray) -> SimSequence:
        """Return it with the front-end's frame turned and moved from keyframe ``at`` on.

        A relocalization or a restart of the front-end: its poses from ``at`` on are turned by
        ``yaw_rad`` about the odom frame's vertical and moved by ``shift``, m.
        """
        turn = so3.exp(np.array([0.0, 0.0, yaw_rad]))
        centers, rotations = self.centers_odom.copy(), self.R_wc_odom.copy()
        centers[at:] = centers[at:] @ turn.T + shift
        rotations[at:] = turn @ rotations[at:]
        return replace(self, centers_odom=centers, R_wc_odom=rotations)

    def with_few_tracks(self, first: int, count: int, keep: int = 0) -> SimSequence:
        """Return it with ``keep`` tracks in keyframes first..first+count-1 (0: none; a tunnel).

        The kept tracks are of the same features from frame to frame, as a front-end keeps
        its last few through a dark stretch.
        """
        frames = list(self.frames)
        for i in range(first, first + count):
            frames[i] = _fewest(frames[i], keep)
        return replace(self, frames=frames)


def _fewest(frame: TrackFrame, keep: int) -> TrackFrame:
    """Return ``frame`` with ``keep`` of its tracks, the same features from frame to frame."""
    if not keep:
        return TrackFrame.empty(frame.stamp_ns, frame.frame_id)
    # Multiplicative hashing orders the ids the same way in every frame, spread over the image.
    order = np.argsort((frame.feature_ids.astype(np.uint64) * np.uint64(2654435761))
                       % np.uint64(2**32), kind='stable')
    idx = np.sort(order[:keep])
    return replace(frame, feature_ids=frame.feature_ids[idx], camera_ids=frame.camera_ids[idx],
                   pixels=None if frame.pixels is None else frame.pixels[idx],
                   normalized=None if frame.normalized is None else frame.normalized[idx])


def simulate_sequence(scenario: str = 'street', n_keyframes: int = 200, seed: int = 0,
                      noise_px: float = 0.5, drift: float = 0.02, rate_hz: float = 10.0, *,
                      speed_mps: float | None = None, features_per_keyframe: int = 15,
                      max_track_length: int = 40, distortion: str = 'plumb_bob',
                      image_size: tuple[int, int] = (640, 480), focal_px: float = 400.0,
                      start_ns: int = START_NS,
                      stop: tuple[int, int] | None = None,
                      turn_deg: float = 0.0) -> SimSequence:
    """Simulate a keyframe sequence of a scenario.

    Args:
        scenario: One of :data:`SCENARIOS`.
        n_keyframes: Number of keyframes F (>= 2).
        seed: Seed of the random generator.
        noise_px: Pixel noise standard deviation per axis, px (>= 0).
        drift: Front-end drift parameter (>= 0), see the module docstring.
        rate_hz: Keyframe rate, Hz (> 0).
        speed_mps: Travel speed, m/s (default: street 10, aerial 5, loop 8, rotation 0).
        features_per_keyframe: Features spawned at each keyframe (10x at the first).
        max_track_length: Longest track in keyframes (>= 2).
        distortion: Camera distortion model: 'none', 'plumb_bob' or 'equidistant'.
        image_size: Image width and height, px.
        focal_px: Focal length, px (principal point at the image centre).
        start_ns: Stamp of the first keyframe, ns.
        stop: (first, count): the platform is at rest for ``count`` keyframes from keyframe
            ``first``, slowing down over the :data:`STOP_RAMP` keyframes before and speeding
            up over those after (a car at a traffic light, a drone hovering).
        turn_deg: With ``stop``, the platform turns on the spot while at rest: about the
            world's vertical by up to this angle and back (a robot looking around).

    Returns:
        The sequence.

    Raises:
        ValueError: On an unknown scenario or distortion model, or out-of-range arguments.
    """
    if scenario not in SCENARIOS:
        msg = f'unknown scenario {scenario!r} (expected one of {", ".join(SCENARIOS)})'
        raise ValueError(msg)
    if n_keyframes < MIN_KEYFRAMES or max_track_length < 2 or features_per_keyframe < 1:
        msg = 'simulate_sequence: need n_keyframes >= 2, max_track_length >= 2, features >= 1'
        raise ValueError(msg)
    if not (rate_hz > 0 and noise_px >= 0 and drift >= 0 and focal_px > 0):
        msg = 'simulate_sequence: rate_hz, focal_px must be > 0 and noise_px, drift >= 0'
        raise ValueError(msg)
    rng = np.random.default_rng(seed)
    camera = _camera(distortion, image_size, focal_px)
    default_speed = {'street': 10.0, 'aerial': 5.0, 'loop': 8.0, 'rotation': 0.0}[scenario]
    speed = default_speed if speed_mps is None else float(speed_mps)
    t_s = np.arange(n_keyframes) / rate_hz
    R_wc, centers = _trajectory(scenario, _motion_time(n_keyframes, rate_hz, stop), speed)
    if turn_deg and stop is None:
        msg = 'simulate_sequence: turn_deg needs a stop to turn in'
        raise ValueError(msg)
    if stop is not None and turn_deg:
        k = np.arange(n_keyframes) - stop[0]
        at_rest = (k >= 0) & (k < stop[1])
        yaw = np.where(at_rest, np.deg2rad(turn_deg) * np.sin(np.pi * k / stop[1]), 0.0)
        R_wc = np.einsum('kij,kjl->kil', so3.exp(np.outer(yaw, _WORLD_UP)), R_wc)
    stamps = start_ns + np.round(t_s * 1e9).astype(np.int64)

    points, frames = _tracks(rng, scenario, R_wc, centers, camera, stamps, noise_px,
                             features_per_keyframe, max_track_length)
    R_odom, c_odom = _drifted(rng, R_wc, centers, drift)
    return SimSequence(scenario, stamps, R_wc, centers, R_odom, c_odom, frames, camera,
                       points, float(noise_px), float(drift))


def _motion_time(n: int, rate_hz: float, stop: tuple[int, int] | None) -> FloatArray:
    """Return the time along the scenario's path at each keyframe: t, or slowed by ``stop``."""
    if stop is None:
        return np.arange(n) / rate_hz
    first, count = stop
    if first < 0 or count < 1:
        msg = f'simulate_sequence: stop {stop} needs first >= 0 and count >= 1'
        raise ValueError(msg)
    i = np.arange(n)
    rate = np.ones(n)   # of path time per keyframe interval after keyframe i
    down = (i >= first - STOP_RAMP) & (i < first)
    rate[down] = (first - i[down]) / STOP_RAMP
    last = first + count - 1   # the last keyframe at rest
    rate[(i >= first) & (i < last)] = 0.0
    up = (i >= last) & (i < last + STOP_RAMP)
    rate[up] = (i[up] - last + 1) / STOP_RAMP
    return np.concatenate([[0.0], np.cumsum(rate[:-1])]) / rate_hz


def _camera(distortion: str, image_size: tuple[int, int], focal_px: float) -> CameraModel:
    """Return the simulated camera."""
    width, height = image_size
    d = {'none': (), 'plumb_bob': _PLUMB_BOB_D, 'equidistant': (-0.01, 0.002, 0.0, 0.0)}
    if distortion not in d:
        msg = f'unknown distortion {distortion!r} (none, plumb_bob, equidistant)'
        raise ValueError(msg)
    return CameraModel(fx=focal_px, fy=focal_px, cx=width / 2.0, cy=height / 2.0,
                       distortion_model=distortion, d=np.array(d[distortion]), width=width,
                       height=height)


def _look_along(forward_w: FloatArray, up_w: FloatArray | None = None) -> FloatArray:
    """Return R_wc (F, 3, 3) of cameras looking along ``forward_w`` (F, 3), image y down."""
    z_c = forward_w / np.linalg.norm(forward_w, axis=1, keepdims=True)
    down = -_WORLD_UP if up_w is None else -up_w
    down = down - np.sum(down * z_c, axis=1, keepdims=True) * z_c
    y_c = down / np.linalg.norm(down, axis=1, keepdims=True)
    x_c = np.cross(y_c, z_c)
    return np.stack([x_c, y_c, z_c], axis=2)


def _trajectory(scenario: str, t_s: FloatArray, speed: float) -> tuple[FloatArray, FloatArray]:
    """Return true R_wc (F, 3, 3) and centres (F, 3) of a scenario at times t_s."""
    F = t_s.shape[0]
    if scenario == 'street':
        x = speed * t_s
        centers = np.column_stack([x, 0.3 * np.sin(2 * np.pi * x / 60.0),
                                   0.1 * np.sin(2 * np.pi * x / 37.0)])
        fwd = np.column_stack([np.ones(F), 0.3 * 2 * np.pi / 60.0 * np.cos(2 * np.pi * x / 60.0),
                               np.zeros(F)])
        return _look_along(fwd), centers
    if scenario == 'aerial':
        x = speed * t_s
        centers = np.column_stack([x, 3.0 * np.sin(2 * np.pi * x / 80.0), np.full(F, 40.0)])
        heading = np.column_stack([np.ones(F), 3.0 * 2 * np.pi / 80 * np.cos(2 * np.pi * x / 80),
                                   np.zeros(F)])
        heading /= np.linalg.norm(heading, axis=1, keepdims=True)
        # Looking down (z_c = -z_w), image "up" along the heading: y_c = -heading.
        z_c = np.tile(-_WORLD_UP, (F, 1))
        y_c = -heading
        return np.stack([np.cross(y_c, z_c), y_c, z_c], axis=2), centers
    if scenario == 'loop':
        radius = 40.0
        phi = speed * t_s / radius
        centers = np.column_stack([radius * np.sin(phi), radius * (1 - np.cos(phi)),
                                   np.zeros(F)])
        fwd = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(F)])
        return _look_along(fwd), centers
    # rotation: yaw sweep +-30 deg and a small pitch oscillation about a fixed centre.
    yaw = np.deg2rad(30.0) * np.sin(2 * np.pi * t_s / 8.0)
    pitch = np.deg2rad(5.0) * np.sin(2 * np.pi * t_s / 5.0)
    fwd = np.column_stack([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch),
                           np.sin(pitch)])
    return _look_along(fwd), np.zeros((F, 3))


def _ray_depths(rng: np.random.Generator, scenario: str, origin: FloatArray,
                rays_w: FloatArray) -> FloatArray:
    """Return the distance along each unit world ray (S, 3) from ``origin`` to its feature."""
    S = rays_w.shape[0]
    far = np.exp(rng.uniform(np.log(_FAR_RANGE_M[0]), np.log(_FAR_RANGE_M[1]), S))
    with np.errstate(divide='ignore', invalid='ignore'):
        if scenario == 'street':
            cands = [(6.0 - origin[1]) / rays_w[:, 1], (-6.0 - origin[1]) / rays_w[:, 1],
                     (-1.6 - origin[2]) / rays_w[:, 2]]
            hit = np.min(np.where(np.stack(cands) > 0, np.stack(cands), np.inf), axis=0)
            hit = np.where(origin[2] + hit * rays_w[:, 2] > 12.0, np.inf, hit)  # facade top
            return np.where(hit <= 40.0, hit, far)
        if scenario == 'aerial':
            ground = rng.uniform(-3.0, 3.0, S)
            hit = (ground - origin[2]) / rays_w[:, 2]
            return np.where(hit > 0, hit, far)
        if scenario == 'loop':
            centre = np.array([0.0, 40.0, 0.0])
            o = origin - centre
            hits = []
            for radius in (30.0, 50.0):
                a = np.sum(rays_w[:, :2] ** 2, axis=1)
                b = 2 * rays_w[:, :2] @ o[:2]
                c = o[:2] @ o[:2] - radius ** 2
                disc = np.sqrt(b * b - 4 * a * c)
                for root in ((-b - disc) / (2 * a), (-b + disc) / (2 * a)):
                    hits.append(np.where(root > 0, root, np.inf))
            hit = np.min(np.stack(hits), axis=0)
            z = origin[2] + hit * rays_w[:, 2]
            hit = np.where((z > -2.0) & (z < 10.0), hit, np.inf)
            return np.where(np.isfinite(hit), hit, far)
    return np.asarray(rng.uniform(5.0, 100.0, S), dtype=np.float64)


def _tracks(rng: np.random.Generator, scenario: str, R_wc: FloatArray, centers: FloatArray,
            camera: CameraModel, stamps: IntArray, noise_px: float, per_kf: int,
            max_len: int) -> tuple[FloatArray, list[TrackFrame]]:
    """Spawn features keyframe by keyframe and observe them; returns points and frames."""
    width, height = camera.width, camera.height
    F = R_wc.shape[0]
    total = per_kf * (10 + F - 1)
    points = np.zeros((total, 3))
    birth = np.zeros(total, dtype=np.int64)
    life = np.zeros(total, dtype=np.int64)
    alive = np.zeros(total, dtype=bool)
    n_total = 0
    frames: list[TrackFrame] = []
    # A feature's age counts the keyframes that moved: at rest a tracker keeps its features
    # and has no new ones to add.
    moved = np.ones(F, dtype=bool)
    moved[1:] = (np.any(centers[1:] != centers[:-1], axis=1)
                 | np.any(R_wc[1:] != R_wc[:-1], axis=(1, 2)))
    moves = np.cumsum(moved) - 1
    for i in range(F):
        n_new = per_kf * (10 if i == 0 else int(moved[i]))
        px = np.column_stack([rng.uniform(0.05, 0.95, n_new) * width,
                              rng.uniform(0.05, 0.95, n_new) * height])
        xy = camera.normalize(px)
        rays_c = np.column_stack([xy, np.ones(n_new)])
        rays_c /= np.linalg.norm(rays_c, axis=1, keepdims=True)
        rays_w = rays_c @ R_wc[i].T
        depth = _ray_depths(rng, scenario, centers[i], rays_w)
        new = slice(n_total, n_total + n_new)
        points[new] = centers[i] + depth[:, None] * rays_w
        birth[new] = moves[i]
        life[new] = rng.integers(max(2, max_len // 4), max_len + 1, n_new)
        alive[new] = True
        n_total += n_new
        idx = np.flatnonzero(alive[:n_total])
        h = (points[idx] - centers[i]) @ R_wc[i]
        vis = h[:, 2] > _MIN_DEPTH_M
        xy_true = h[:, :2] / np.where(vis, h[:, 2], 1.0)[:, None]
        pix_true = camera.denormalize(xy_true)
        vis &= ((pix_true[:, 0] >= 0) & (pix_true[:, 0] < width) & (pix_true[:, 1] >= 0)
                & (pix_true[:, 1] < height) & np.all(np.isfinite(pix_true), axis=1))
        alive[idx[~vis]] = False
        alive[idx[moves[i] - birth[idx] >= life[idx] - 1]] = False  # their last keyframe
        ids = idx[vis]
        pix = pix_true[vis] + rng.normal(0.0, noise_px, (ids.size, 2)) if noise_px else \
            pix_true[vis]
        normalized = camera.normalize(pix)
        frames.append(TrackFrame(int(stamps[i]), 'odom', ids.astype(np.int64),
                                 np.zeros(ids.size, dtype=np.int64), pix, normalized))
    return points, frames


def _drifted(rng: np.random.Generator, R_wc: FloatArray, centers: FloatArray,
             drift: float) -> tuple[FloatArray, FloatArray]:
    """Integrate the true relative motions with drift (see the module docstring)."""
    F = R_wc.shape[0]
    R_rel = np.einsum('fji,fjk->fik', R_wc[:-1], R_wc[1:])  # R_{i-1}^T R_i
    t_rel = np.einsum('fji,fj->fi', R_wc[:-1], centers[1:] - centers[:-1])
    step = np.linalg.norm(t_rel, axis=1)
    phase = rng.uniform(0.0, 2 * np.pi)
    travelled = np.cumsum(step)
    scale = 1.0 + drift * np.sin(2 * np.pi * travelled / 150.0 + phase)
    bias_axis = np.array([0.0, 1.0, 0.2])  # mostly yaw for a forward camera (y_c is down)
    bias_axis /= np.linalg.norm(bias_axis)
    omega = (0.01 * drift * step)[:, None] * bias_axis \
        + rng.normal(0.0, 0.01 * drift, (F - 1, 3))
    R_rel_o = R_rel @ so3.exp(omega)
    noise_t = rng.normal(0.0, 1.0, (F - 1, 3)) * (0.2 * drift * step)[:, None]
    t_rel_o = scale[:, None] * t_rel + noise_t
    R_o = np.empty_like(R_wc)
    c_o = np.empty_like(centers)
    R_o[0] = R_wc[0]
    c_o[0] = centers[0]
    for i in range(1, F):
        c_o[i] = c_o[i - 1] + R_o[i - 1] @ t_rel_o[i - 1]
        R_o[i] = so3.project(R_o[i - 1] @ R_rel_o[i - 1])
    return R_o, c_o


def observation_counts(seq: SimSequence) -> IntArray:
    """Return the number of observations of each keyframe, shape (F,)."""
    return np.array([len(f) for f in seq.frames], dtype=np.int64)


def track_lengths(seq: SimSequence) -> IntArray:
    """Return the number of keyframes observing each feature, shape (N,)."""
    ids = np.concatenate([f.feature_ids for f in seq.frames])
    return np.bincount(ids, minlength=seq.points_w.shape[0]).astype(np.int64)
