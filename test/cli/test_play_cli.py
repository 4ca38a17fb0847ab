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

"""``pmba play`` as a process publishing into a live graph (real rclpy, own DDS domain)."""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys
import time
from typing import Any

import numpy as np
from pmba_ros.backend import outputs as out
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.cli.main import main
from pmba_ros.io.bag_writer import open_writer
from pmba_ros.io.bags import jazzy_typestore
import pytest

from ..ros_helpers import domain_id, isolated_env, isolated_node, spin_until, transient_local_qos

RATE = 2.0
KEYFRAME_PERIOD_S = 0.1     # pmba simulate's default --rate-hz 10


@pytest.fixture(scope='module')
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Return a 12-keyframe simulated street (1.1 s recorded)."""
    bag = tmp_path_factory.mktemp('play') / 'street'
    assert main(['simulate', '--keyframes', '12', '--seed', '2', '--out', str(bag)]) == 0
    return bag


def play(args: list[str], domain: int) -> subprocess.Popen[str]:
    """Start ``pmba play`` on ``domain``."""
    return subprocess.Popen([sys.executable, '-m', 'pmba_ros', 'play', *args],
                            env=isolated_env(domain), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_play_keeps_timing_remaps_and_publishes_clock(sim_bag: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Every message arrives, keyframes spaced by period / rate, /clock follows the bag."""
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud

    with isolated_node(monkeypatch, 'play_listener') as (domain, executor, node):
        qos = transient_local_qos(100)
        got: dict[str, list[tuple[float, Any]]] = {'kf': [], 'tracks': [], 'clock': []}
        node.create_subscription(Odometry, '/keyframe_pose',
                                 lambda m: got['kf'].append((time.monotonic(), m)), qos)
        node.create_subscription(PointCloud, '/vins/feature',
                                 lambda m: got['tracks'].append((time.monotonic(), m)), qos)
        node.create_subscription(Clock, '/clock',
                                 lambda m: got['clock'].append((time.monotonic(), m)), qos)
        proc = play([str(sim_bag), '--rate', str(RATE), '--clock', '--wait-for-subscribers', '30',
                     '--topics', '/features', '/keyframe_pose', '--remap',
                     '/features:=/vins/feature'], domain)
        try:
            assert spin_until(executor, lambda: proc.poll() is not None, timeout_s=60.0)
            spin_until(executor, lambda: len(got['kf']) == 12, timeout_s=2.0)
            stdout, stderr = proc.communicate()
            assert proc.returncode == 0, stderr
            assert 'played 24 messages on 2 topics' in stdout
            assert len(got['kf']) == len(got['tracks']) == 12
            gaps = np.diff([t for t, _ in got['kf']])
            assert abs(float(np.median(gaps)) - KEYFRAME_PERIOD_S / RATE) < 0.02
            stamps = [m.clock.sec + m.clock.nanosec * 1e-9 for _, m in got['clock']]
            assert len(stamps) > 12 and np.all(np.diff(stamps) >= 0)
            first_kf = got['kf'][0][1].header.stamp
            assert abs(stamps[0] - (first_kf.sec + first_kf.nanosec * 1e-9)) < 0.1
        finally:
            if proc.poll() is None:
                proc.kill()


@pytest.mark.slow
def test_play_errors(sim_bag: Path, tmp_path: Path) -> None:
    """Missing bag and message types rclpy lacks give one error line and exit 1."""
    domain = domain_id()
    proc = play([str(tmp_path / 'nope')], domain)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 1 and 'no such bag' in stderr and 'Traceback' not in stderr
    tf_bag = tmp_path / 'tf'
    backend = RosbagsBackend(jazzy_typestore())
    with open_writer(tf_bag) as writer:
        writer.write('/tf', out.make_tf(1, 'map', 'odom', np.zeros(3), [0, 0, 0, 1.0],
                                        backend), 1)
        writer.write('/chatter', backend.new('std_msgs/msg/String', data='hi'), 2)
    try:
        import tf2_msgs  # noqa: F401
        pytest.skip('tf2_msgs is installed: no missing message type to test with')
    except ImportError:
        pass
    proc = play([str(tf_bag)], domain)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 1 and 'Traceback' not in stderr
    assert 'tf2_msgs/msg/TFMessage' in stderr and '--topics' in stderr
    proc = play([str(tf_bag), '--topics', '/chatter', '--delay', '0'], domain)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert 'played 1 messages' in stdout


@pytest.mark.slow
@pytest.mark.parametrize('signal_name', ['SIGINT', 'SIGTERM'])
def test_play_loop_plays_the_recording_again_until_interrupted(
        sim_bag: Path, monkeypatch: pytest.MonkeyPatch, signal_name: str) -> None:
    """``--loop``: the keyframes again, stamped as the first time and paced again, to a signal.

    SIGTERM (``kill``, ``timeout``, systemd) ends it as SIGINT does: before, rclpy shut its
    context down under a publish, and play ended in a traceback and exit code 1.
    """
    import signal

    from nav_msgs.msg import Odometry

    with isolated_node(monkeypatch, 'loop_listener') as (domain, executor, node):
        got: list[tuple[float, int]] = []
        node.create_subscription(
            Odometry, '/keyframe_pose', lambda m: got.append(
                (time.monotonic(), m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec)),
            transient_local_qos(100))
        proc = play([str(sim_bag), '--rate', '4', '--loop', '--wait-for-subscribers', '30',
                     '--topics', '/keyframe_pose'], domain)
        try:
            assert spin_until(executor, lambda: len(got) >= 30, timeout_s=60.0), len(got)
            proc.send_signal(getattr(signal, signal_name))
            _, stderr = proc.communicate(timeout=30)
            assert proc.returncode == 0 and 'Traceback' not in stderr, stderr
        finally:
            if proc.poll() is None:
                proc.kill()
    stamps = [s for _, s in got]
    assert stamps[12:24] == stamps[:12] and stamps[24:30] == stamps[:6]
    gaps = np.diff([t for t, _ in got[12:24]])
    assert abs(float(np.median(gaps)) - KEYFRAME_PERIOD_S / 4) < 0.02
