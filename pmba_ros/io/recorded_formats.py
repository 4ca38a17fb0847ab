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
"""Fit a replay's input settings to what a recording holds.

A live node has to be told its front-end's topics and message formats; a recording shows
them. Where the configured tracks topic was not recorded but a known front-end's topics were
(:data:`~pmba_ros.backend.frontends.PAIRINGS`), and where the configured keyframe type, track
layout or camera count cannot read a recording and exactly one other setting can, a replay
takes that one and says so in its warnings: the configured settings stay wherever they read
the recording, so nothing that parses is ever read another way.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import replace
import logging
from typing import Any, TYPE_CHECKING

from pmba_ros.backend.frontends import PAIRINGS
from pmba_ros.backend.tracks import KEYFRAME_MSGTYPES, LAYOUTS, parse_tracks, tracks_msgtype
from pmba_ros.errors import BagError, MessageError
from pmba_ros.io.bag_inputs import CAMERA_INFO_TYPES, find_topic, resolve_topic
from pmba_ros.io.bags import iter_messages, OpenBags, TopicInfo

if TYPE_CHECKING:
    from pmba_ros.backend.config import BackendConfig
    from pmba_ros.backend.types import TrackFrame

logger = logging.getLogger(__name__)

__all__ = ['MAX_CAMERAS', 'PEEK_MESSAGES', 'fit_to_recording']

PEEK_MESSAGES = 20
"""Tracks messages (with observations) a layout must read to fit a recording."""

MAX_CAMERAS = 8
"""Largest rig a recording's camera ids may announce; larger ids are no camera channel."""

_UNBOUNDED_CAMERAS = 1 << 20
"""Camera count for reading ids before the rig's size is known (vins_mono needs the real one)."""


def fit_to_recording(bags: OpenBags, config: BackendConfig, warnings: list[str],
                     chosen: Collection[str] = ()) -> BackendConfig:
    """Return ``config`` with the input settings the recording needs.

    Settings named in ``chosen`` (the user's explicit choices) are kept as they are.

    * the input topics are a known front-end's where the tracks topic was not recorded
      (:func:`_front_end_topics`);
    * ``keyframe_type`` follows the keyframe topic's message type;
    * ``feature_layout``: if the configured layout cannot read the first
      :data:`PEEK_MESSAGES` tracks messages with observations and exactly one other layout
      of the topic's message type can, that one;
    * ``num_cams`` grows to the camera ids of those messages (layouts with a camera
      channel), and a rig's ``camera_info_topics`` are taken from the recorded CameraInfo
      topics where they name one topic per camera (see :func:`_rig_camera_infos`).

    Each change is logged and appended to ``warnings``.
    """
    topics = bags.topics
    config = _front_end_topics(topics, config, warnings, chosen)
    changes: dict[str, Any] = {}
    keyframes = find_topic(resolve_topic(config.keyframe_topic), topics)
    if keyframes is not None:
        kind = {t: k for k, t in KEYFRAME_MSGTYPES.items()}.get(topics[keyframes].msgtype)
        if kind is not None and kind != config.keyframe_type and 'keyframe_type' not in chosen:
            changes['keyframe_type'] = kind
            _note(warnings, f'keyframes topic {keyframes!r} holds {topics[keyframes].msgtype}: '
                            f'read as keyframe_type {kind!r}, not {config.keyframe_type!r}')
    tracks = find_topic(resolve_topic(config.features_topic), topics)
    if tracks is None:
        return replace(config, **changes) if changes else config   # select_inputs says so
    sample = _peek(bags, tracks)
    if 'feature_layout' in chosen:
        layout, frames = config.feature_layout, _reads(sample, config.feature_layout,
                                                       config.num_cams)
    else:
        layout, frames = _fitting_layout(sample, topics[tracks].msgtype, config, warnings)
    if layout != config.feature_layout:
        changes['feature_layout'] = layout
    cameras = _camera_count(frames or [], layout, config.num_cams)
    if layout == 'vins_mono' and 'num_cams' not in chosen:
        _camera_count_unknown(bags, config, warnings)
    if cameras > config.num_cams and 'num_cams' not in chosen:
        changes['num_cams'] = cameras
        rig = _rig_camera_infos(bags, config, cameras)
        text = (f'tracks topic {tracks!r} holds camera ids up to {cameras - 1}: num_cams '
                f'{cameras}')
        if rig:
            changes['camera_info_topics'] = rig
            changes['camera_info_topic'] = rig[config.camera_id]
            text += f', camera info topics {", ".join(rig)} in camera-id order'
        else:
            text += ('; no CameraInfo topic per camera recorded (give --camera-info-topic '
                     'once per camera id): only the reference camera is used')
        _note(warnings, text)
    return replace(config, **changes) if changes else config


_INPUTS = {'features': 'features_topic', 'keyframe_pose': 'keyframe_topic',
           'camera_info': 'camera_info_topic', 'extrinsic': 'extrinsic_topic'}
"""The node's input topic names (the pairings' remapping sources) -> their config fields."""


def _front_end_topics(topics: Mapping[str, TopicInfo], config: BackendConfig,
                      warnings: list[str], chosen: Collection[str]) -> BackendConfig:
    """Return ``config`` reading a known front-end's topics if its own tracks are not recorded.

    The first pairing whose tracks topic is recorded, with its keyframe topic where the
    keyframes come from one, gives the input topics and its layout and keyframe type
    (checked against the messages afterwards like any configured ones). Topics in ``chosen``
    stay.
    """
    if 'features_topic' in chosen or find_topic(resolve_topic(config.features_topic), topics):
        return config
    need_poses = config.keyframe_source == 'keyframe_topic'
    for name, pairing in PAIRINGS.items():
        remap = {_INPUTS[src]: dst for src, dst in pairing['remappings']}
        if find_topic(remap['features_topic'], topics) is None or (
                need_poses and find_topic(remap['keyframe_topic'], topics) is None):
            continue
        changes = {field: topic for field, topic in remap.items()
                   if field not in chosen and find_topic(topic, topics) is not None}
        changes |= {field: value for field, value in pairing['parameters'].items()
                    if field in ('feature_layout', 'keyframe_type') and field not in chosen}
        _note(warnings, f'tracks topic {resolve_topic(config.features_topic)!r} is not '
                        f"recorded; reading {name}'s topics: "
                        + ', '.join(remap[f] for f in _INPUTS.values() if f in changes)
                        + ' (set --tracks-topic to choose)')
        return replace(config, **changes)
    return config


def _note(warnings: list[str], text: str) -> None:
    logger.warning('%s', text)
    warnings.append(text)


def _peek(bags: OpenBags, topic: str) -> list[object]:
    """Return the first tracks messages with observations (fewer on a damaged recording)."""
    sample: list[object] = []
    try:
        for message in iter_messages(bags, topics=[topic], points_as_arrays=True):
            msg = message.msg
            if len(getattr(msg, 'points', ())) or getattr(msg, 'width', 0):
                sample.append(msg)
                if len(sample) >= PEEK_MESSAGES:
                    break
    except BagError:   # damage is the replay's to report, where it reads the recording
        pass
    return sample


def _reads(sample: list[object], layout: str, num_cams: int) -> list[TrackFrame] | None:
    """Return the frames ``layout`` reads from every message of ``sample``, else None."""
    cams = num_cams if layout == 'vins_mono' else _UNBOUNDED_CAMERAS
    try:
        # The layout the message is in, even with pixels in its normalized fields: the
        # replay's reading of the first message then says so.
        return [parse_tracks(msg, layout, cams, check_rays=False) for msg in sample]
    except MessageError:
        return None


def _fitting_layout(sample: list[object], msgtype: str, config: BackendConfig,
                    warnings: list[str]) -> tuple[str, list[TrackFrame] | None]:
    """Return the configured layout if it reads ``sample``, else the one other that does.

    With the frames it read (None: it reads none of them, or there was no sample).
    """
    configured = config.feature_layout
    frames = _reads(sample, configured, config.num_cams)
    if not sample or frames is not None:
        return configured, frames
    fits = [(layout, read) for layout in LAYOUTS if layout != configured
            and tracks_msgtype(layout) == msgtype
            and (read := _reads(sample, layout, config.num_cams)) is not None]
    if len(fits) != 1:
        return configured, None   # none or several: the replay's errors name the mismatch
    layout, frames = fits[0]
    _note(warnings, f'tracks are not in layout {configured!r} but in {layout!r}: read as '
                    f'{layout!r} (set --tracks-layout to choose)')
    return layout, frames


def _camera_count(frames: list[TrackFrame], layout: str, num_cams: int) -> int:
    """Return the cameras the sampled tracks use (at least ``num_cams``)."""
    if layout == 'vins_mono':   # its ids encode num_cams; they cannot tell it
        return num_cams
    top = max((int(f.camera_ids.max()) for f in frames if f.camera_ids.size), default=-1)
    return top + 1 if num_cams <= top < MAX_CAMERAS else num_cams


def _camera_info_topics(bags: OpenBags) -> list[str]:
    """Return the recorded CameraInfo topics in name order."""
    return sorted(t for t, i in bags.topics.items() if i.msgtype in CAMERA_INFO_TYPES)


def _camera_count_unknown(bags: OpenBags, config: BackendConfig, warnings: list[str]) -> None:
    """Warn where a vins_mono recording may hold more cameras than ``num_cams``.

    Its ids are ``id * NUM_OF_CAM + cam``: read with too few cameras, a rig's second camera
    becomes features of the first, each seen from one place, and the map is wrong without an
    error. The ids cannot tell the count; more CameraInfo topics than cameras may.
    """
    infos = _camera_info_topics(bags)
    if len(infos) > config.num_cams:
        _note(warnings, f'tracks in layout vins_mono hold their camera in the id (id * '
                        f'NUM_OF_CAM + cam), which does not tell NUM_OF_CAM: read as '
                        f'num_cams {config.num_cams}; the recording has {len(infos)} CameraInfo '
                        f'topics ({", ".join(infos)}): if its tracker ran with NUM_OF_CAM '
                        f'{len(infos)}, give --camera-info-topic once per camera, in '
                        'camera-id order')


def _rig_camera_infos(bags: OpenBags, config: BackendConfig, cameras: int) -> tuple[str, ...]:
    """Return one recorded CameraInfo topic per camera id, or () where that is ambiguous.

    The configured ``camera_info_topic`` is the reference camera's where it was recorded
    and the others follow in name order; without it, the recorded ones in name order (a
    ``cam0`` / ``cam1`` naming). Any other count of CameraInfo topics names no rig.
    """
    if config.camera_info_topics or config.camera_id != 0:
        return ()
    infos = _camera_info_topics(bags)
    reference = find_topic(resolve_topic(config.camera_info_topic), infos)
    if reference is not None:
        infos = [reference, *(t for t in infos if t != reference)]
    return tuple(infos) if len(infos) == cameras else ()
