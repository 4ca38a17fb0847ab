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
"""Tests of pmba_ros.sim.sequence: shapes, determinism, geometry and drift of the scenarios."""

from __future__ import annotations

import numpy as np
from pmba_ros.core import so3
from pmba_ros.sim.sequence import (
    observation_counts,
    SCENARIOS,
    SimSequence,
    simulate_sequence,
    track_lengths,
)
import pytest


@pytest.fixture(scope='module', params=SCENARIOS)
def seq(request: pytest.FixtureRequest) -> SimSequence:
    """Simulate 40 keyframes of each scenario once for the module."""
    return simulate_sequence(request.param, n_keyframes=40, seed=3)


def test_shapes_and_stamps(seq: SimSequence) -> None:
    """One pose and frame per keyframe at 10 Hz; the rotations are orthonormal."""
    F = len(seq)
    assert F == 40 == len(seq.frames)
    assert seq.R_wc_gt.shape == seq.R_wc_odom.shape == (F, 3, 3)
    assert seq.centers_gt.shape == seq.centers_odom.shape == (F, 3)
    assert np.all(np.diff(seq.stamps_ns) == 100_000_000)  # 10 Hz
    assert [f.stamp_ns for f in seq.frames] == seq.stamps_ns.tolist()
    np.testing.assert_allclose(np.einsum('fji,fjk->fik', seq.R_wc_gt, seq.R_wc_gt),
                               np.tile(np.eye(3), (F, 1, 1)), atol=1e-12)
    assert len(seq.gt_trajectory()) == len(seq.odom_trajectory()) == F


def test_observations_are_noisy_projections(seq: SimSequence) -> None:
    """Pixels are ground-truth projections plus noise of the requested size, in the image."""
    for i in (0, len(seq) // 2, len(seq) - 1):
        f = seq.frames[i]
        assert len(f) >= 50
        assert np.all(f.camera_ids == 0)
        assert np.unique(f.feature_ids).size == len(f)
        h = (seq.points_w[f.feature_ids] - seq.centers_gt[i]) @ seq.R_wc_gt[i]
        assert np.all(h[:, 2] > 0)
        pix = seq.camera.denormalize(h[:, :2] / h[:, 2:3])
        err = np.linalg.norm(pix - f.pixels, axis=1)
        assert np.sqrt(np.mean(err ** 2)) == pytest.approx(seq.noise_px * np.sqrt(2), rel=0.3)
        np.testing.assert_allclose(seq.camera.denormalize(f.normalized), f.pixels, atol=1e-6)
        assert np.all((f.pixels >= 0) & (f.pixels < [seq.camera.width + 2,
                                                     seq.camera.height + 2]))


def test_tracks_are_local_and_contiguous(seq: SimSequence) -> None:
    """A feature is seen on consecutive keyframes only, most of them on two or more."""
    lengths = track_lengths(seq)
    assert lengths.max() <= 40
    seen = lengths > 0
    assert np.mean(lengths[seen] >= 2) > 0.7
    counts = observation_counts(seq)
    assert counts.shape == (len(seq),)
    # Contiguous: a feature seen at keyframes i and j is seen at every keyframe in between.
    first = np.full(seq.points_w.shape[0], -1)
    last = np.full(seq.points_w.shape[0], -1)
    for i, f in enumerate(seq.frames):
        first[f.feature_ids[first[f.feature_ids] < 0]] = i
        last[f.feature_ids] = i
    np.testing.assert_array_equal((last - first + 1)[seen], lengths[seen])


def test_same_seed_same_sequence() -> None:
    """A seed reproduces the sequence exactly; another seed changes it."""
    a = simulate_sequence('street', 15, seed=7)
    b = simulate_sequence('street', 15, seed=7)
    c = simulate_sequence('street', 15, seed=8)
    np.testing.assert_array_equal(a.centers_odom, b.centers_odom)
    np.testing.assert_array_equal(a.frames[-1].pixels, b.frames[-1].pixels)
    assert not np.array_equal(a.frames[-1].pixels, c.frames[-1].pixels)


def test_street_is_forward_motion_with_far_features() -> None:
    """The street moves 1 m per keyframe along x with a gentle weave; many features are far."""
    seq = simulate_sequence('street', 100, seed=0)
    steps = np.diff(seq.centers_gt, axis=0)
    assert np.all(steps[:, 0] == pytest.approx(1.0))  # 10 m/s at 10 Hz
    assert np.max(np.abs(seq.centers_gt[:, 1:])) < 0.35  # gentle weave
    depth = np.linalg.norm(seq.points_w[np.concatenate([f.feature_ids for f in seq.frames])]
                           - seq.centers_gt[0], axis=1)
    assert np.mean(depth > 50.0) > 0.2  # a good share of far features


def test_drift_is_about_the_requested_fraction() -> None:
    """Front-end drift ends near the requested fraction of the distance; zero is exact."""
    seq = simulate_sequence('street', 200, seed=0, drift=0.02)
    distance = np.sum(np.linalg.norm(np.diff(seq.centers_gt, axis=0), axis=1))
    end_error = np.linalg.norm(seq.centers_odom[-1] - seq.centers_gt[-1])
    assert 0.005 * distance < end_error < 0.04 * distance
    exact = simulate_sequence('street', 20, seed=0, drift=0.0)
    np.testing.assert_allclose(exact.centers_odom, exact.centers_gt, atol=1e-9)
    np.testing.assert_allclose(exact.R_wc_odom, exact.R_wc_gt, atol=1e-9)


def test_rotation_scenario_has_no_baseline() -> None:
    """The rotation scenario turns by more than 10 degrees without moving the camera."""
    seq = simulate_sequence('rotation', 30, seed=0)
    assert np.all(seq.centers_gt == 0.0)
    assert np.max(np.rad2deg(so3.angle(seq.R_wc_gt[0], seq.R_wc_gt))) > 10.0


def test_a_stop_holds_still_and_keeps_its_features() -> None:
    """At rest the pose holds and the tracker keeps its features; it slows and speeds up."""
    plain = simulate_sequence('street', 120, seed=4)
    seq = simulate_sequence('street', 120, seed=4, stop=(40, 30))
    np.testing.assert_array_equal(seq.centers_gt[:10], plain.centers_gt[:10])
    np.testing.assert_array_equal(seq.centers_gt[40:70], np.tile(seq.centers_gt[40], (30, 1)))
    np.testing.assert_array_equal(seq.R_wc_gt[40:70], np.tile(seq.R_wc_gt[40], (30, 1, 1)))
    step = np.linalg.norm(np.diff(seq.centers_gt, axis=0), axis=1)
    assert np.all(np.diff(step[10:40]) < 0) and np.all(np.diff(step[69:99]) > 0)
    assert step[39] < 0.05 * step[0] and step[99] == pytest.approx(step[0], rel=0.01)
    for f in seq.frames[42:70]:   # keyframe 40 still moved: tracks ended there
        np.testing.assert_array_equal(f.feature_ids, seq.frames[41].feature_ids)
    assert not np.array_equal(seq.frames[41].pixels, seq.frames[42].pixels)  # new noise
    np.testing.assert_allclose(seq.centers_odom[40:70], np.tile(seq.centers_odom[40], (30, 1)))


def test_a_stop_can_turn_on_the_spot() -> None:
    """turn_deg: at rest the camera yaws out to the angle and back; elsewhere as without."""
    still = simulate_sequence('street', 120, seed=4, stop=(40, 30))
    seq = simulate_sequence('street', 120, seed=4, stop=(40, 30), turn_deg=60.0)
    np.testing.assert_array_equal(seq.centers_gt, still.centers_gt)
    np.testing.assert_array_equal(seq.R_wc_gt[:40], still.R_wc_gt[:40])
    np.testing.assert_array_equal(seq.R_wc_gt[70:], still.R_wc_gt[70:])
    turned = np.rad2deg(so3.angle(still.R_wc_gt[40:70], seq.R_wc_gt[40:70]))
    assert turned[15] == pytest.approx(60.0) and turned[0] == pytest.approx(0.0, abs=1e-5)
    assert seq.frames[50].feature_ids.shape != still.frames[50].feature_ids.shape or \
        not np.array_equal(seq.frames[50].feature_ids, still.frames[50].feature_ids)
    with pytest.raises(ValueError, match='turn_deg needs a stop'):
        simulate_sequence('street', 20, turn_deg=30.0)


@pytest.mark.parametrize('distortion', ['none', 'plumb_bob', 'equidistant'])
def test_distortion_models(distortion: str) -> None:
    """Each distortion model's normalized coordinates map back onto the pixels."""
    seq = simulate_sequence('aerial', 5, distortion=distortion, noise_px=0.0)
    assert seq.camera.distortion_model == distortion
    f = seq.frames[2]
    np.testing.assert_allclose(seq.camera.denormalize(f.normalized), f.pixels, atol=1e-6)


@pytest.mark.parametrize('kwargs', [{'scenario': 'city'}, {'n_keyframes': 1},
                                    {'noise_px': -1.0}, {'rate_hz': 0.0},
                                    {'distortion': 'fisheye'}, {'max_track_length': 1},
                                    {'stop': (-1, 5)}, {'stop': (10, 0)}])
def test_invalid_arguments(kwargs: dict[str, object]) -> None:
    """Unknown scenarios, distortions or counts are a ValueError naming the argument."""
    with pytest.raises(ValueError, match=r'simulate_sequence|scenario|distortion'):
        simulate_sequence(**kwargs)  # type: ignore[arg-type]
