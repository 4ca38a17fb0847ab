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
"""The replay report: which back-end counters become warnings."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from pmba_ros.backend.extrinsics import Rigid
from pmba_ros.replay_report import collect_stats, IDENTITY_EXTRINSIC, ReplayReport
import pytest


def _logic(counters: dict[str, int], source: str = 'tf',
           not_optimized: int = 0) -> SimpleNamespace:
    """Return what collect_stats reads of a BackendLogic, with these counters."""
    stats = SimpleNamespace(solve_ms=[], iterations=[], cost_after=[], cost_before=[],
                            update_ms=[], counters=counters, keyframes=10,
                            not_optimized=not_optimized, map_scale=[], noise=None)
    cameras = SimpleNamespace(extrinsic=Rigid.identity(), extrinsic_source=source, rig={})
    estimator = SimpleNamespace(state='tracking', last_message='')
    return SimpleNamespace(stats=stats, cameras=cameras, estimator=estimator,
                           config=SimpleNamespace(min_observations=15))


@pytest.mark.parametrize(('counter', 'text'), [
    ('other_camera_observations', 'other than the reference one not used'),
    ('tracks_without_camera_info', 'no CameraInfo had arrived'),
    ('keyframes_without_pose', 'the pose stream gave no pose'),
    ('odom_frame_jumps', 'a new odom segment starts'),
    ('keyframe_buffer_overflow', 'keyframe poses dropped'),
    ('tracks_buffer_overflow', 'tracks messages dropped'),
    ('feature_id_restarts', 'feature ids started again'),
    ('camera_info_changes', 'the newest were used'),
    ('non_finite_observations', 'undistort to no finite point'),
    ('keyframes_dropped', 'not in the outputs'),
    ('keyframes_dropped_before_init', 'not in the outputs'),
    ('internal_errors', 'please report it'),
    ('output_errors', 'please report it'),
])
def test_input_accepted_but_not_used_is_a_warning(counter: str, text: str) -> None:
    """Counters of input lost or misused after it was accepted each give a warning line."""
    report = ReplayReport(bags=[Path('bag')], out_dir=Path('out'))
    collect_stats(_logic({counter: 7}), report)  # type: ignore[arg-type]
    assert len(report.warnings) == 1
    assert report.warnings[0].startswith('7 ') and text in report.warnings[0]


def test_identity_extrinsic_is_a_warning() -> None:
    """Keyframe poses taken as camera poses for want of an extrinsic are said so."""
    report = ReplayReport(bags=[Path('bag')], out_dir=Path('out'))
    collect_stats(_logic({'extrinsic_unknown': 1}, 'identity'), report)  # type: ignore[arg-type]
    assert report.warnings == [IDENTITY_EXTRINSIC]
    assert report.extrinsic is not None and report.extrinsic['source'] == 'identity'
    quiet = ReplayReport(bags=[Path('bag')], out_dir=Path('out'))
    collect_stats(_logic({}), quiet)  # type: ignore[arg-type]
    assert quiet.warnings == []


def test_observations_not_finite_are_a_warning() -> None:
    """Tracks rows dropped as not finite are warned of, apart from those other lines name."""
    report = ReplayReport(bags=[Path('bag')], out_dir=Path('out'))
    collect_stats(_logic({'dropped_observations': 383}), report)  # type: ignore[arg-type]
    assert report.warnings == [('383 observations dropped from tracks messages: a feature '
                                'id, camera id or coordinate not finite (NaN or inf)')]
    duplicates = ReplayReport(bags=[Path('bag')], out_dir=Path('out'))
    drops = {'dropped_observations': 7, 'duplicate_observations': 5,
             'ambiguous_duplicate_observations': 2}
    collect_stats(_logic(drops), duplicates)  # type: ignore[arg-type]
    assert len(duplicates.warnings) == 2
    assert not any('not finite' in text for text in duplicates.warnings)


def test_keyframes_not_optimized_are_a_warning() -> None:
    """Keyframes left at the front-end's pose (empty tracks messages) are said so, and why."""
    report = ReplayReport(bags=[Path('bag')], out_dir=Path('out'))
    logic = _logic({'keyframes_passed_through': 4, 'keyframes_dead_reckoned': 1}, not_optimized=5)
    collect_stats(logic, report)  # type: ignore[arg-type]
    assert report.warnings == [("5 of 10 keyframes not optimized: they are the front-end's "
                                'poses through map <- odom (5 keyframes had fewer than '
                                'min_observations (15) usable observations)')]
