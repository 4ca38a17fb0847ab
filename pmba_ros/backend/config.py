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
"""The back-end configuration: what the node's parameters (and ``--params FILE.yaml``) become.

:class:`BackendConfig` is a frozen dataclass with validated fields; :meth:`BackendConfig.
from_params` builds it from a flat parameter dict (the node's declared parameters) or from a
ROS 2 parameter file's ``{node_name: {ros__parameters: {...}}}`` nesting, and
:meth:`BackendConfig.from_yaml` reads such a file. ``config/pmba.yaml`` holds the defaults.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
import math
import os
from typing import Any, TYPE_CHECKING

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.backend.extrinsics import EXTRINSIC_VALUES, extrinsics_from_params
from pmba_ros.backend.tracks import KEYFRAME_KINDS, LAYOUTS

if TYPE_CHECKING:
    from pmba_ros.init.options import InitOptions

MODES = ('sliding', 'global')
"""Estimation modes: sliding window (last K keyframes free) or global (all free)."""

KEYFRAME_SOURCES = ('keyframe_topic', 'tracks')
"""Where keyframes come from: front-end keyframe poses, or every tracks message."""

QOS_RELIABILITIES = ('reliable', 'best_effort')
LOSSES = ('none', 'huber', 'cauchy')

INPUT_QOS = ('', 'reliable', 'best_effort', 'transient_local', 'sensor_data')
"""Per-input QoS presets; '' takes ``qos_reliability`` and ``qos_depth``."""

CHOICES: dict[str, tuple[str, ...]] = {
    'mode': MODES, 'feature_layout': LAYOUTS, 'keyframe_type': KEYFRAME_KINDS,
    'keyframe_source': KEYFRAME_SOURCES, 'qos_reliability': QOS_RELIABILITIES, 'loss': LOSSES,
    'features_qos': INPUT_QOS, 'keyframe_qos': INPUT_QOS, 'camera_info_qos': INPUT_QOS}
"""Parameters that take one of a fixed set of strings."""

INT_MINIMUMS: dict[str, int] = {
    'window_size': 2, 'max_fixed_keyframes': 0, 'fixed_lookback': 0, 'init_batch_size': 3,
    'init_retry_every': 1, 'init_min_features': 1, 'init_max_iterations': 1,
    'fallback_reinit_after': 1, 'min_observations': 5, 'num_cams': 1,
    'camera_id': 0, 'qos_depth': 1, 'queue_size': 1, 'buffer_size': 1, 'max_iterations': 1,
    'max_landmarks': 0, 'max_observations_per_feature': 0, 'init_max_batch': 3, 'seed': 0}
"""Integer parameters and their smallest accepted value."""

INT_MAXIMUMS: dict[str, int] = {'seed': 2 ** 31 - 1}
"""Integer parameters with a largest value (OpenCV's RNG takes a C int seed)."""

POSITIVE_FLOATS = ('motion_prior_direction_rel', 'max_time_s', 'loss_scale_px',
                   'covariance_position_m2', 'covariance_rotation_rad2', 'fallback_focal_px',
                   'association_timeout_s', 'stale_input_s')
NON_NEGATIVE_FLOATS = ('motion_prior_translation_rel', 'motion_prior_shape_rel',
                       'motion_prior_rotation_rad',
                       'fallback_max_scale_jump', 'fallback_max_motion_error',
                       'init_min_parallax_px', 'transform_tolerance_s', 'stamp_tolerance_s',
                       'tf_rate_hz')
"""Float parameters (an integer is accepted and converted) that must be > 0 / >= 0."""

TF_RATE_HZ = (0.01, 1000.0)
"""The rates ``tf_rate_hz`` may take besides 0."""

NODE_NAME = 'pmba_node'

NOT_OPTIMIZED_COVARIANCE_SCALE = 10.0
"""Covariance factor of keyframe poses published before their solve."""
"""Node name; ``config/pmba.yaml`` nests its parameters under it."""

_IGNORED_PARAMS = ('use_sim_time', 'start_type_description_service')


@dataclass(frozen=True, slots=True)
class BackendConfig:
    """Back-end and node configuration (ROS parameter names = field names).

    Attributes:
        mode: 'sliding' (the last ``window_size`` keyframes free, older ones fixed) or
            'global' (every keyframe free at every refine).
        window_size: Free keyframes K in sliding mode (>= 2).
        max_fixed_keyframes: Older fixed keyframes added to a sliding problem (the ones that
            co-observe most window features; >= 2 of them fix the gauge).
        fixed_lookback: Keyframes before the window whose observations are kept for that.
        init_batch_size: Keyframes collected before the global initialization (>= 3).
        init_min_parallax_px: Rotation-compensated parallax (px) that makes a feature
            well conditioned for the initialization (between two keyframes of the batch).
        init_min_features: Well-conditioned features (between one pair of the batch's
            keyframes) required to try the initialization; half as many once the batch is
            full (``init_max_batch`` keyframes: a front-end tracking few features).
        init_retry_every: After a failed attempt, retry after this many new keyframes.
        init_max_batch: Largest batch kept while waiting for parallax (oldest dropped).
        init_max_iterations: Iteration budget of the initialization's BA.
        motion_prior_translation_rel: Sigma of the length of the front-end's keyframe-to-keyframe
            translation against the map <- odom scale of the run so far (monocular sliding
            windows; otherwise the initialization's) on a long run (early in one it grows,
            ``motion.RUN_SCALE_SPAN``), as a fraction of the step (the relative-motion prior of
            each window solve; one sigma weighs as one sigma of the tracks' pixel noise,
            measured by the solves; 0: no translation prior).
        motion_prior_shape_rel: Sigma of that length against the map's own map <- odom scale
            over the ``window_size`` steps around it (the front-end's steps agree with each
            other better than its scale holds), as a fraction of the step; in a rig's
            solves (a metric map) the lengths are held to each other only, the scale left
            to the baseline (0: only the length above).
        motion_prior_direction_rel: Sigma of that translation across the step (its direction),
            as a fraction of the step.
        motion_prior_rotation_rad: Sigma of its relative rotation, rad (0: none).
        fallback_max_scale_jump: A window solve that changes the map <- odom scale by more than
            this fraction is rolled back (counted as ``solve_rollbacks``).
        fallback_max_motion_error: A window solve whose keyframe-to-keyframe translations
            differ from the front-end's by more than this fraction (median, after the map
            scale) is rolled back, unless they already did before it.
        fallback_reinit_after: Rolled-back solves in a row after which the window restarts
            from the front-end's relative motion (counted as ``reinitializations``).
        max_observations_per_feature: Sliding problems keep at most this many observations
            of a feature, evenly spread over its track (0: all; the Schur complement's cost
            grows with the square of it).
        min_observations: Keyframes with fewer observations are not optimized: their pose is
            the front-end's motion from the solved keyframes on either side
            (:mod:`~pmba_ros.backend.gaps`).
        feature_layout: Track layout (see :data:`pmba_ros.backend.tracks.LAYOUTS`).
        num_cams: Front-end camera count (VINS ``NUM_OF_CAM``); not given, the count that
            ``camera_extrinsics`` or ``camera_info_topics`` list, else 1.
        camera_id: Reference camera: the keyframe poses are solved in its frame, and its
            CameraInfo is ``camera_info_topic``. Other cameras' observations are used once
            their CameraInfo (``camera_info_topics``) and extrinsic are known (a rig: the
            baseline makes the map metric).
        camera_extrinsics: Body -> camera transforms, 7 values per camera id (x, y, z, qx,
            qy, qz, qw: the camera frame in the keyframe poses' body frame); empty: from TF
            (keyframe ``child_frame_id`` -> CameraInfo ``frame_id``), else from
            ``extrinsic_topic``, else identity.
        keyframe_type: 'odometry' (nav_msgs/Odometry), 'pose_stamped' or
            'pose_with_covariance' (geometry_msgs/PoseWithCovarianceStamped).
        keyframe_source: 'keyframe_topic' (each keyframe pose is a keyframe) or 'tracks'
            (every tracks message is a keyframe; its front-end pose is sampled from the
            ``keyframe_topic`` poses, a stream at any rate, where they come).
        features_topic: Input tracks topic (relative, remappable).
        keyframe_topic: Input keyframe pose topic.
        camera_info_topic: Input CameraInfo topic (of camera ``camera_id``).
        camera_info_topics: One CameraInfo topic per camera id, in camera-id order (a
            multi-camera rig); empty: ``camera_info_topic`` only.
        extrinsic_topic: Input nav_msgs/Odometry (or PoseStamped) whose pose is camera
            ``camera_id``'s frame in the body frame: VINS-Mono / VINS-Fusion's
            ``/vins_estimator/extrinsic``, OpenVINS' ``loop_extrinsic``.
        path_topic: Output nav_msgs/Path of optimized keyframes.
        keyframes_topic: Output geometry_msgs/PoseArray of optimized keyframes.
        landmarks_topic: Output sensor_msgs/PointCloud2 (xyz float32, transient local).
        odometry_topic: Output nav_msgs/Odometry of the newest keyframe.
        map_frame: Frame of all outputs.
        odom_frame: Front-end frame (child of map_frame in TF); '' = the keyframe header's.
        base_frame: Odometry child frame; '' = the keyframe's child_frame_id (or 'base_link').
        publish_tf: Publish map -> odom on /tf.
        transform_tolerance_s: Future-dating of the map -> odom stamp, s.
        qos_reliability: Subscription reliability ('reliable' or 'best_effort').
        qos_depth: Subscription / publisher history depth.
        queue_size: Bounded queue between the callbacks and the solver thread.
        buffer_size: Track frames / keyframes buffered for association.
        stamp_tolerance_s: Largest stamp difference between a keyframe and its tracks, s.
        association_timeout_s: A keyframe whose tracks did not arrive by then (input stamps)
            is taken without tracks.
        max_iterations: Dogleg iteration budget per refine. One suits a sliding window:
            each keyframe's solve starts where the last one stopped, so a second iteration
            adds little (docs/speed.md).
        max_time_s: Wall-time budget per refine, s (ignored if ``deterministic``).
        loss: Robust loss of every solve, the initialization's BA included ('huber', 'cauchy'
            or 'none').
        loss_scale_px: Robust loss scale, px.
        covariance_position_m2: Odometry position variance floor, m^2 (> 0).
        covariance_rotation_rad2: Odometry rotation variance floor, rad^2 (> 0).
        max_landmarks: Most retired landmarks kept for the map (oldest dropped).
        fallback_focal_px: Focal length used for loss scaling before a CameraInfo arrives
            (tracks with normalized coordinates do not need one).
        deterministic: No time budgets and no wall-clock values in the outputs (replay).
        seed: Seed of the initialization's RANSAC.
        save_directory: Where the node's ~/save service writes (TUM trajectories, PLY map).
        features_qos: QoS of the tracks subscription, one of :data:`INPUT_QOS` ('' takes
            ``qos_reliability`` and ``qos_depth``).
        keyframe_qos: QoS of the keyframe pose subscription (as ``features_qos``).
        camera_info_qos: QoS of the CameraInfo subscription (as ``features_qos``; best effort
            receives from reliable and best-effort publishers alike).
        tf_rate_hz: Rate at which the node re-sends the newest map -> odom, Hz (0: only on
            keyframes; else within :data:`TF_RATE_HZ`).
        stale_input_s: The node's diagnostics warn when no input arrived for this long, s.
    """

    mode: str = 'sliding'
    window_size: int = 20
    max_fixed_keyframes: int = 16
    fixed_lookback: int = 20
    init_batch_size: int = 20
    init_min_parallax_px: float = 3.0
    init_min_features: int = 30
    init_retry_every: int = 5
    init_max_batch: int = 60
    init_max_iterations: int = 100
    max_observations_per_feature: int = 14
    motion_prior_translation_rel: float = 0.045
    motion_prior_shape_rel: float = 0.01
    motion_prior_direction_rel: float = 0.005
    motion_prior_rotation_rad: float = 0.0005
    fallback_max_scale_jump: float = 0.1
    fallback_max_motion_error: float = 0.5
    fallback_reinit_after: int = 3
    min_observations: int = 15
    feature_layout: str = 'vins_fusion'
    num_cams: int = 1
    camera_id: int = 0
    camera_extrinsics: tuple[float, ...] = ()
    keyframe_type: str = 'odometry'
    keyframe_source: str = 'keyframe_topic'
    features_topic: str = 'features'
    keyframe_topic: str = 'keyframe_pose'
    camera_info_topic: str = 'camera_info'
    camera_info_topics: tuple[str, ...] = ()
    extrinsic_topic: str = 'extrinsic'
    path_topic: str = 'pmba/path'
    keyframes_topic: str = 'pmba/keyframes'
    landmarks_topic: str = 'pmba/landmarks'
    odometry_topic: str = 'pmba/odometry'
    map_frame: str = 'map'
    odom_frame: str = ''
    base_frame: str = ''
    publish_tf: bool = True
    transform_tolerance_s: float = 0.1
    qos_reliability: str = 'reliable'
    qos_depth: int = 100
    queue_size: int = 200
    buffer_size: int = 200
    stamp_tolerance_s: float = 0.005
    association_timeout_s: float = 1.0
    max_iterations: int = 1
    max_time_s: float = 0.15
    loss: str = 'cauchy'
    loss_scale_px: float = 2.0
    covariance_position_m2: float = 1e-3
    covariance_rotation_rad2: float = 1e-4
    max_landmarks: int = 200_000
    fallback_focal_px: float = 500.0
    deterministic: bool = False
    seed: int = 0
    save_directory: str = 'pmba_output'
    features_qos: str = ''
    keyframe_qos: str = ''
    camera_info_qos: str = 'best_effort'
    tf_rate_hz: float = 10.0
    stale_input_s: float = 5.0

    def __post_init__(self) -> None:
        """Validate every field.

        Raises:
            ValueError: With the parameter name and the accepted values.
        """
        for name, allowed in CHOICES.items():
            if getattr(self, name) not in allowed:
                msg = f'parameter {name}={getattr(self, name)!r}: expected one of {allowed}'
                raise ValueError(msg)
        for name, low in INT_MINIMUMS.items():
            value = getattr(self, name)
            high = INT_MAXIMUMS.get(name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low or (
                    high is not None and value > high):
                bounds = f'>= {low}' if high is None else f'in [{low}, {high}]'
                msg = f'parameter {name}={value!r}: expected an integer {bounds}'
                raise ValueError(msg)
        if self.init_max_batch < self.init_batch_size:
            msg = (f'parameter init_max_batch={self.init_max_batch} must be >= '
                   f'init_batch_size={self.init_batch_size}')
            raise ValueError(msg)
        if self.max_observations_per_feature == 1 or self.max_observations_per_feature == 2:
            msg = ('parameter max_observations_per_feature: expected 0 (no cap) or >= 3, got '
                   f'{self.max_observations_per_feature}')
            raise ValueError(msg)
        if self.camera_id >= self.num_cams:
            msg = f'parameter camera_id={self.camera_id} must be < num_cams={self.num_cams}'
            raise ValueError(msg)
        positive, non_negative = POSITIVE_FLOATS, NON_NEGATIVE_FLOATS
        for name in positive + non_negative:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or \
                    (not math.isfinite(value) and name != 'max_time_s'):
                msg = f'parameter {name}={value!r}: expected a finite number'
                raise ValueError(msg)
            if value < 0 or (name in positive and value == 0):
                kind = '> 0' if name in positive else '>= 0'
                msg = f'parameter {name}={value!r}: expected {kind}'
                raise ValueError(msg)
            object.__setattr__(self, name, float(value))
        if self.tf_rate_hz and not TF_RATE_HZ[0] <= self.tf_rate_hz <= TF_RATE_HZ[1]:
            # Outside it the node's timer period overflows or the timer spins a core.
            msg = (f'parameter tf_rate_hz={self.tf_rate_hz!r}: expected 0 (off) or '
                   f'{TF_RATE_HZ[0]:g}-{TF_RATE_HZ[1]:g} Hz')
            raise ValueError(msg)
        for name in ('features_topic', 'keyframe_topic', 'camera_info_topic',
                     'extrinsic_topic', 'path_topic',
                     'keyframes_topic', 'landmarks_topic', 'odometry_topic', 'map_frame',
                     'save_directory'):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                msg = f'parameter {name}={value!r}: expected a non-empty string'
                raise ValueError(msg)
        for name in ('odom_frame', 'base_frame'):
            if not isinstance(getattr(self, name), str):
                msg = f'parameter {name}: expected a string'
                raise ValueError(msg)
        topics = self.camera_info_topics
        if not isinstance(topics, list | tuple) or not all(isinstance(t, str) and t
                                                           for t in topics):
            msg = f'parameter camera_info_topics={topics!r}: expected a list of topic names'
            raise ValueError(msg)
        object.__setattr__(self, 'camera_info_topics', tuple(topics))
        try:
            flat = tuple(float(v) for v in self.camera_extrinsics)
        except (TypeError, ValueError) as err:
            msg = f'parameter camera_extrinsics: expected a list of numbers ({err})'
            raise ValueError(msg) from err
        object.__setattr__(self, 'camera_extrinsics', flat)
        n_topics = len(self.camera_info_topics)
        if n_topics and flat and len(flat) != EXTRINSIC_VALUES * n_topics:
            # Checked first: each list's own error would ask for another num_cams.
            msg = (f'parameters camera_extrinsics ({len(flat)} values, {EXTRINSIC_VALUES} per '
                   f'camera) and camera_info_topics ({n_topics} topics) must list the same '
                   'cameras, one entry per camera id')
            raise ValueError(msg)
        if n_topics and n_topics != self.num_cams:
            msg = (f'parameter camera_info_topics: {n_topics} topics for num_cams='
                   f'{self.num_cams}: set num_cams: {n_topics} (one topic per camera id), or '
                   'leave camera_info_topics empty for camera_info_topic alone')
            raise ValueError(msg)
        extrinsics_from_params(flat, self.num_cams)
        for name in ('publish_tf', 'deterministic'):
            if not isinstance(getattr(self, name), bool):
                msg = f'parameter {name}={getattr(self, name)!r}: expected a bool'
                raise ValueError(msg)

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> BackendConfig:
        """Build a config from parameters; missing ones take their defaults.

        Args:
            params: Flat ``{name: value}`` (the node's parameters), or a parameter file's
                ``{node_name: {'ros__parameters': {...}}}`` (``pmba_node`` or ``/**``).

        Returns:
            The validated config.

        Raises:
            ValueError: On unknown parameter names or invalid values.
        """
        flat = _unnest(params)
        known = {f.name for f in fields(cls)}
        unknown = sorted(k for k in flat if k not in known and k not in _IGNORED_PARAMS
                         and not k.startswith('qos_overrides.'))
        if unknown:
            msg = f'unknown parameter(s) {unknown}; known: {sorted(known)}'
            raise ValueError(msg)
        values = {k: v for k, v in flat.items() if k in known}
        if 'num_cams' not in values:   # as the node declares it: the lists' count by default
            values['num_cams'] = implied_num_cams(values) or _DEFAULTS['num_cams']
        return cls(**values)

    @classmethod
    def from_yaml(cls, path: str | os.PathLike[str]) -> BackendConfig:
        """Read a ROS 2 parameter file (or a flat YAML mapping) into a config.

        Raises:
            ValueError: If the file is not a mapping, or on invalid parameters.
            OSError: If the file cannot be read.
        """
        import yaml

        with open(path, encoding='utf-8') as fh:
            data = yaml.safe_load(fh)
        if not isinstance(data, dict):
            msg = f'{os.fspath(path)}: expected a YAML mapping of parameters'
            raise ValueError(msg)
        return cls.from_params(data)

    def odometry_covariance(self, *, optimized: bool = True) -> FloatArray:
        """Return the 6x6 covariance (position, rotation) published with a keyframe pose.

        A pose not optimized (yet) gets :data:`NOT_OPTIMIZED_COVARIANCE_SCALE` times the
        floor: it is the front-end's, mapped through map <- odom.
        """
        cov = np.diag([self.covariance_position_m2] * 3 + [self.covariance_rotation_rad2] * 3)
        return cov if optimized else NOT_OPTIMIZED_COVARIANCE_SCALE * cov

    def init_features_needed(self, batch_size: int) -> int:
        """Return the well-conditioned features a batch of ``batch_size`` keyframes needs.

        A full batch (``init_max_batch``) holds all the tracks waiting would bring: with a
        front-end that tracks few features (low texture) it is tried with half of
        ``init_min_features`` rather than never.
        """
        full = batch_size >= self.init_max_batch
        return (self.init_min_features + 1) // 2 if full else self.init_min_features

    def init_options(self, need: int) -> InitOptions:
        """Return the back-end's global initialization options, ``need`` features per pair.

        The pairs' thresholds follow the count of well-conditioned features the batch was
        tried with (the initialization's own defaults at 30).
        """
        from pmba_ros.core.loss import Loss
        from pmba_ros.core.problem import Parameterization
        from pmba_ros.core.solve import SolveOptions, SolverKind
        from pmba_ros.init.options import InitOptions

        return InitOptions(
            min_pair_matches=max(5, need), min_pair_inliers=max(5, 2 * need // 3),
            solve_options=SolveOptions(
                param=Parameterization.PMBA, solver=SolverKind.DOGLEG, loss=Loss(self.loss),
                loss_scale_px=self.loss_scale_px, max_iterations=self.init_max_iterations,
                function_tolerance=1e-10))

    def to_params(self) -> dict[str, Any]:
        """Return the flat parameter dict (the node declares these; sequences as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


_DEFAULTS: dict[str, Any] = {f.name: f.default for f in fields(BackendConfig)}
"""Each parameter's default (a slotted dataclass has no class attributes to read them from)."""


def implied_num_cams(params: Mapping[str, Any]) -> int | None:
    """Return the camera count that ``camera_extrinsics`` and ``camera_info_topics`` list.

    A stereo rig's 14 extrinsic values, or its two CameraInfo topics, made a parameter
    file without ``num_cams: 2`` fail with ``num_cams=1``: ``num_cams`` defaults to this
    count (the node declares it so, and :meth:`BackendConfig.from_params` takes it), and
    one given explicitly is checked against the lists.

    Args:
        params: Parameter values by name (either list may be missing).

    Returns:
        The count, or None if neither list has entries, an extrinsic count is not a multiple
        of 7, or the lists disagree (the config's validation then names the problem).
    """
    n_values, n_topics = (_length(params.get(name))
                          for name in ('camera_extrinsics', 'camera_info_topics'))
    if n_values % EXTRINSIC_VALUES:
        return None
    counts = {n for n in (n_values // EXTRINSIC_VALUES, n_topics) if n}
    return counts.pop() if len(counts) == 1 else None


def _length(value: Any) -> int:
    """Return the number of entries of a list parameter (rclpy gives arrays; 0 if none)."""
    if value is None or isinstance(value, str | bytes):
        return 0
    try:
        return len(value)
    except TypeError:
        return 0


def _unnest(params: dict[str, Any]) -> dict[str, Any]:
    """Return the flat parameters of a possibly node-nested parameter mapping.

    Raises:
        ValueError: If the mapping is nested by node but has no parameters for this node.
    """
    names = (NODE_NAME, f'/{NODE_NAME}', '/**')
    for key in names:
        node = params.get(key)
        if isinstance(node, dict) and isinstance(node.get('ros__parameters'), dict):
            return dict(node['ros__parameters'])
    if isinstance(params.get('ros__parameters'), dict):
        return dict(params['ros__parameters'])
    # Node sections without one for this node had their names taken for parameter names:
    # "unknown parameter(s) ['other_node']".
    ours = [key for key in names if key in params]
    if ours or any(isinstance(v, dict) and 'ros__parameters' in v for v in params.values()):
        found = (f'its section {ours[0]!r} holds {params[ours[0]]!r}' if ours
                 else f'its top-level keys are {sorted(map(str, params))}')
        msg = (f'the file has no parameters for node {NODE_NAME!r}: {found} (the loader '
               f"reads {{ros__parameters: {{...}}}} under {', '.join(map(repr, names))})")
        raise ValueError(msg)
    return dict(params)
