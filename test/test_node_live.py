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

"""pmba_node as a process, launch-free, fed a simulated recording live over DDS.

Each test runs the node with ``--ros-args --params-file config/pmba.yaml`` plus remaps on
its own ``ROS_DOMAIN_ID`` (localhost discovery only), publishes a recording at its recorded
rate (``pmba play`` as a second process, or a driver node here), and checks what comes
back: every keyframe in the path, odometry for every keyframe, diagnostics, the services
through real clients, and the exit on SIGINT / SIGTERM. One runs the node as ``colcon build``
installs it and ``ros2 run`` starts it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time
from typing import Any

import numpy as np
from pmba_ros.backend import outputs as out
from pmba_ros.backend.frontends import PAIRINGS
from pmba_ros.backend.msg_backend import RclpyBackend
from pmba_ros.cli.main import main as pmba
from pmba_ros.core import so3
from pmba_ros.sim.inputs import make_camera_info, make_tracks
from pmba_ros.sim.sequence import simulate_sequence
import pytest
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

from .ros_helpers import isolated_env, isolated_node, spin_until, transient_local_qos

ROOT = Path(__file__).resolve().parents[1]
PARAMS = ROOT / 'config' / 'pmba.yaml'
N_KEYFRAMES = 24
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = transient_local_qos(200)
# The node's inputs read transient local too (see transient_local_qos).
LATCHED_INPUTS = ('-p', 'features_qos:=transient_local', '-p', 'keyframe_qos:=transient_local',
                  '-p', 'camera_info_qos:=transient_local')


def _default_sigint() -> None:
    # A background shell starts children with SIGINT ignored; the node must see it.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


# pmba_node whose initialization BA takes a minute unless stopped: it checks in with the
# node's worker as the solver's iterations do.
SLOW_INIT_NODE = """
import sys, time
from pmba_ros.init import pipeline
real_solve = pipeline.solve
def slow_solve(*args, callback=None, **kwargs):
    print('slow solve started', flush=True)
    for _ in range(6000):
        callback(None)
        time.sleep(0.01)
    return real_solve(*args, callback=callback, **kwargs)
pipeline.solve = slow_solve
from pmba_ros.node import main
main(sys.argv[1:])
"""


def start_node(domain: int, log: Path, *ros_args: str,
               program: tuple[str, ...] = (sys.executable, '-m', 'pmba_ros.node'),
               params: Path = PARAMS, env: dict[str, str] | None = None,
               ) -> subprocess.Popen[str]:
    """Start pmba_node with the params file and ``ros_args`` on ``domain``, logging to ``log``.

    ``program``: the command line before ``--ros-args``; ``env``: the environment to isolate
    (this process's by default). A file, not a pipe: a pipe nobody reads while the node runs
    blocks it once full.
    """
    with log.open('w', encoding='utf-8') as out_file:
        return subprocess.Popen(
            [*program, '--ros-args', '--params-file', str(params), '-p', 'init_batch_size:=10',
             *ros_args],
            env=isolated_env(domain, env), stdout=out_file, stderr=subprocess.STDOUT,
            text=True, preexec_fn=_default_sigint)


def keyframe_stamps(bag: Path, topic: str = '/keyframe_pose') -> np.ndarray:
    """Return the stamps, in ns, of a recording's keyframe poses (on ``topic``)."""
    from pmba_ros.io.bags import iter_messages

    return np.array([m.msg.header.stamp.sec * 10**9 + m.msg.header.stamp.nanosec
                     for m in iter_messages([bag], [topic])])


def kill(*procs: subprocess.Popen[str] | None) -> None:
    """Kill the processes still running (a test's clean-up after a failure)."""
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()


@dataclass
class Listener:
    """A node on the test's side: subscriptions to the outputs and service clients."""

    context: Context
    executor: SingleThreadedExecutor
    node: Any
    got: dict[str, list[Any]] = field(default_factory=dict)

    def stamps(self, key: str) -> set[int]:
        """Return the header stamps, in ns, of the messages received under ``key``."""
        return {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in self.got[key]}

    def call(self, srv_type: Any, name: str, request: Any) -> Any:
        """Call a service and return its response."""
        client = self.node.create_client(srv_type, name)
        assert spin_until(self.executor, client.service_is_ready, 10.0), name
        future = client.call_async(request)
        assert spin_until(self.executor, future.done, 20.0), name
        return future.result()


@pytest.fixture
def listener(monkeypatch: pytest.MonkeyPatch) -> Iterator[Listener]:
    """Return a listener on a fresh domain, subscribed to the node's outputs."""
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from nav_msgs.msg import Path as PathMsg

    with isolated_node(monkeypatch, 'live_listener') as (domain, executor, node):
        result = Listener(node.context, executor, node, {'path': [], 'odom': [], 'diag': []})
        result.domain = domain  # type: ignore[attr-defined]
        node.create_subscription(PathMsg, '/pmba/path', result.got['path'].append, RELIABLE)
        node.create_subscription(Odometry, '/pmba/odometry', result.got['odom'].append,
                                 RELIABLE)
        node.create_subscription(DiagnosticArray, '/diagnostics', result.got['diag'].append,
                                 RELIABLE)
        yield result


def driver_publishers(listener: Listener, pose_type: Any, features: str,
                      pose: str) -> tuple[Any, Any, Any]:
    """Return the test's latched publishers of tracks, keyframe poses and CameraInfo."""
    from sensor_msgs.msg import CameraInfo, PointCloud

    node = listener.node
    return (node.create_publisher(PointCloud, features, LATCHED),
            node.create_publisher(pose_type, pose, LATCHED),
            node.create_publisher(CameraInfo, '/camera_info', LATCHED))


def stop(proc: subprocess.Popen[str], sig: int, log: Path) -> tuple[float, str]:
    """Send ``sig``; return the seconds until the process ended and its log."""
    t0 = time.monotonic()
    proc.send_signal(sig)
    try:
        proc.wait(timeout=10.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        pytest.fail(f'pmba_node ignored signal {sig}: {log.read_text(encoding="utf-8")}')
    return time.monotonic() - t0, log.read_text(encoding='utf-8')


def wait_until_up(listener: Listener, proc: subprocess.Popen[str], log: Path) -> None:
    """Wait for the node's first diagnostics (it subscribed before creating its timers)."""
    up = spin_until(listener.executor, lambda: bool(listener.got['diag'])
                    or proc.poll() is not None, timeout_s=120.0)
    if proc.poll() is not None or not up:
        proc.kill()
        proc.wait()
        pytest.fail(f'pmba_node did not come up: {log.read_text(encoding="utf-8")}')


def check_outputs(listener: Listener, stamps_ns: np.ndarray) -> None:
    """Every keyframe in the last path, odometry for each, both diagnostics statuses."""
    n = len(stamps_ns)
    assert spin_until(listener.executor, lambda: bool(listener.got['path'])
                      and len(listener.got['path'][-1].poses) == n, timeout_s=60.0)
    path = listener.got['path'][-1]
    assert [p.header.stamp.sec * 10**9 + p.header.stamp.nanosec for p in path.poses] == \
        [int(s) for s in stamps_ns]
    # Another topic: the last keyframe's odometry may reach the listener after the path.
    assert spin_until(listener.executor,
                      lambda: {int(s) for s in stamps_ns} <= listener.stamps('odom'),
                      timeout_s=10.0)
    names = {s.name for a in listener.got['diag'] for s in a.status}
    assert {'pmba_node: node', 'pmba_node: back-end'} <= names


@pytest.mark.slow
def test_vins_mono_odometry_from_pmba_play_then_sigint(listener: Listener,
                                                       tmp_path: Path) -> None:
    """The launch file's VINS-Mono pairing by hand, a VINS-Mono recording; SIGINT exits 0 fast.

    Its body poses name no child frame: the extrinsic comes from VINS' own topic.
    """
    bag = tmp_path / 'mono'
    assert pmba(['simulate', '--keyframes', str(N_KEYFRAMES), '--seed', '3', '--frontend',
                 'vins_mono', '--extrinsic', 'euroc', '--out', str(bag)]) == 0
    pairing = PAIRINGS['vins_mono']
    domain = listener.domain  # type: ignore[attr-defined]
    log = tmp_path / 'node.log'
    node = start_node(
        domain, log, *LATCHED_INPUTS, '-p', 'max_time_s:=1',
        *(arg for name, value in pairing['parameters'].items()
          for arg in ('-p', f'{name}:={value}')),
        *(arg for src, dst in pairing['remappings'] for arg in ('-r', f'{src}:={dst}')))
    player = None
    try:
        wait_until_up(listener, node, log)
        player = subprocess.Popen(
            [sys.executable, '-m', 'pmba_ros', 'play', str(bag), '--wait-for-subscribers',
             '30', '--topics', *(dst for _, dst in pairing['remappings'])],
            env=isolated_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        stamps = keyframe_stamps(bag, dict(pairing['remappings'])['keyframe_pose'])
        assert len(stamps) == N_KEYFRAMES
        check_outputs(listener, stamps)
        sources = [v.value for a in listener.got['diag'] for st in a.status for v in st.values
                   if v.key == 'extrinsic_source']
        assert sources[-1] == 'extrinsic_topic' and 'identity' not in sources, sources
        assert player.wait(timeout=30) == 0
        seconds, stderr = stop(node, signal.SIGINT, log)
        assert node.returncode == 0, stderr
        assert seconds < 2.0
        assert 'Traceback' not in stderr
    finally:
        kill(node, player)


@pytest.mark.slow
@pytest.mark.parametrize('sim_time', [False, True], ids=['wall_time', 'use_sim_time'])
def test_a_recording_played_in_a_loop_starts_the_node_over(listener: Listener,
                                                           tmp_path: Path,
                                                           sim_time: bool) -> None:
    """``pmba play --loop``: each pass's stamps start over; the node starts over with them.

    Also with ``use_sim_time`` and ``/clock`` going back with each pass (``ros2 bag play
    --loop --clock``). Before, every message after the first pass was rejected as out of
    order.
    """
    bag = tmp_path / 'street'
    assert pmba(['simulate', '--keyframes', str(N_KEYFRAMES), '--seed', '4', '--out',
                 str(bag)]) == 0
    domain = listener.domain  # type: ignore[attr-defined]
    log = tmp_path / 'node.log'
    clock = ('-p', 'use_sim_time:=true') if sim_time else ()
    node = start_node(domain, log, *LATCHED_INPUTS, '-p', 'max_time_s:=1', *clock)
    player = None
    try:
        if not sim_time:   # with sim time its timers wait for /clock
            wait_until_up(listener, node, log)
        player = subprocess.Popen(
            [sys.executable, '-m', 'pmba_ros', 'play', str(bag), '--loop', '--rate', '2',
             '--wait-for-subscribers', '30', '--topics', '/features', '/keyframe_pose',
             '/camera_info', *(['--clock'] if sim_time else [])],
            env=isolated_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

        def restarted() -> bool:
            return any(v.key == 'count.input_restarts' and v.value == '1'
                       for a in listener.got['diag'] for s in a.status for v in s.values)

        def full_paths() -> int:
            return sum(len(p.poses) == N_KEYFRAMES for p in listener.got['path'])

        assert spin_until(listener.executor, lambda: full_paths() >= 1, timeout_s=90.0)
        first = listener.got['path'][-1]
        assert spin_until(listener.executor, restarted, timeout_s=60.0)
        assert spin_until(listener.executor,
                          lambda: restarted() and len(listener.got['path'][-1].poses) < 10,
                          timeout_s=30.0)
        assert spin_until(listener.executor, lambda: full_paths() >= 2, timeout_s=60.0)
        again = [p for p in listener.got['path'] if len(p.poses) == N_KEYFRAMES][-1]
        assert [p.header.stamp for p in again.poses] == [p.header.stamp for p in first.poses]
        _, stderr = stop(node, signal.SIGINT, log)
        assert node.returncode == 0 and 'Traceback' not in stderr, stderr
    finally:
        kill(node, player)


@pytest.mark.slow
def test_vins_fusion_pose_stamped_driver_services_then_sigterm(listener: Listener,
                                                               tmp_path: Path) -> None:
    """VINS-Fusion layout with PoseStamped keyframes from a driver node at 10 Hz."""
    from geometry_msgs.msg import PoseStamped
    from std_srvs.srv import SetBool, Trigger

    domain = listener.domain  # type: ignore[attr-defined]
    log = tmp_path / 'node.log'
    node = start_node(domain, log, *LATCHED_INPUTS, '-p', 'keyframe_type:=pose_stamped',
                      '-p', f'save_directory:={tmp_path / "saved"}',
                      '-r', 'features:=/vins/feature', '-r', 'keyframe_pose:=/vins/pose')
    seq = simulate_sequence('street', n_keyframes=N_KEYFRAMES, seed=4)
    backend = RclpyBackend()
    pubs = driver_publishers(listener, PoseStamped, '/vins/feature', '/vins/pose')
    try:
        wait_until_up(listener, node, log)
        assert spin_until(listener.executor, lambda: min(
            p.get_subscription_count() for p in pubs) > 0, timeout_s=30.0)
        period = float(np.median(np.diff(seq.stamps_ns))) * 1e-9
        t0 = time.monotonic()
        for i in range(len(seq)):
            stamp = int(seq.stamps_ns[i])
            pubs[2].publish(make_camera_info(stamp, 'camera', seq.camera, backend))
            pubs[0].publish(make_tracks(seq.frames[i], 'vins_fusion', backend))
            pubs[1].publish(out.make_pose_stamped(stamp, 'odom', seq.centers_odom[i],
                                                  so3.to_quat_xyzw(seq.R_wc_odom[i]), backend))
            spin_until(listener.executor, lambda: False,
                       timeout_s=max(0.0, t0 + (i + 1) * period - time.monotonic()))
        check_outputs(listener, seq.stamps_ns)
        assert listener.call(SetBool, '/pmba_node/pause', SetBool.Request(data=True)).success
        saved = listener.call(Trigger, '/pmba_node/save', Trigger.Request())
        assert saved.success, saved.message
        tum = (tmp_path / 'saved' / 'pmba_keyframes.tum').read_text().splitlines()
        assert len([line for line in tum if not line.startswith('#')]) == N_KEYFRAMES
        assert listener.call(Trigger, '/pmba_node/reset', Trigger.Request()).success
        seconds, stderr = stop(node, signal.SIGTERM, log)
        assert node.returncode == 0, stderr
        assert seconds < 2.0
    finally:
        kill(node)


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT], ids=['SIGTERM', 'SIGINT'])
def test_a_signal_during_a_long_solve_ends_it(listener: Listener, tmp_path: Path,
                                              sig: int) -> None:
    """A signal while the initialization's BA runs, a ~/save waiting for it: exit 0 at once.

    The BA is abandoned, not finished (it would take a minute), nothing of it is published,
    the save is refused (an abandoned update leaves a half-updated state) and no error or
    traceback is printed. SIGTERM used to wait for the BA: the executor sat in the save,
    and rclpy's SIGTERM handler only shuts the context down.
    """
    from nav_msgs.msg import Odometry
    from std_srvs.srv import Trigger

    domain = listener.domain  # type: ignore[attr-defined]
    log = tmp_path / 'node.log'
    saved = tmp_path / 'saved'
    node = start_node(domain, log, *LATCHED_INPUTS, '-p', f'save_directory:={saved}',
                      program=(sys.executable, '-c', SLOW_INIT_NODE))
    seq = simulate_sequence('street', n_keyframes=12, seed=4)
    backend = RclpyBackend()
    driver = listener.node
    pubs = driver_publishers(listener, Odometry, '/features', '/keyframe_pose')
    try:
        wait_until_up(listener, node, log)
        pubs[2].publish(make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera, backend))
        for i in range(len(seq)):
            pubs[0].publish(make_tracks(seq.frames[i], 'vins_fusion', backend))
            pubs[1].publish(out.make_odometry(
                int(seq.stamps_ns[i]), 'odom', 'camera', seq.centers_odom[i],
                so3.to_quat_xyzw(seq.R_wc_odom[i]), np.eye(6) * 1e-3, backend))
        assert spin_until(listener.executor, lambda: 'slow solve started' in log.read_text(
            encoding='utf-8'), timeout_s=60.0), log.read_text(encoding='utf-8')
        client = driver.create_client(Trigger, '/pmba_node/save')
        assert spin_until(listener.executor, client.service_is_ready, 10.0)
        client.call_async(Trigger.Request())
        spin_until(listener.executor, lambda: False, 0.5)   # the save waits for the BA
        _, text = stop(node, sig, log)
        assert node.returncode == 0, text
        spin_until(listener.executor, lambda: False, 0.5)
        assert all(len(p.poses) < 10 for p in listener.got['path']), 'the BA was published'
        assert not saved.exists()
        assert 'Traceback' not in text and 'failed' not in text.lower(), text
    finally:
        kill(node)


def test_bad_parameter_is_one_fatal_line(listener: Listener, tmp_path: Path) -> None:
    """A wrong parameter value: one [FATAL] line naming it, exit code 1, no traceback."""
    log = tmp_path / 'node.log'
    node = start_node(listener.domain, log, '-p', 'loss:=squared')  # type: ignore[attr-defined]
    assert node.wait(timeout=120) == 1
    stderr = log.read_text(encoding='utf-8')
    fatal = [line for line in stderr.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and 'loss' in fatal[0]
    assert 'Traceback' not in stderr


# What a checkout holds besides the package: a workspace copy leaves it out (the venv's ROS
# wheels carry package.xml files colcon would take for packages of the workspace).
NOT_PACKAGE = shutil.ignore_patterns('.git', '.venv', 'build', 'install', 'log', 'out',
                                     '__pycache__', '*.egg-info', '.*_cache')


@pytest.fixture(scope='module', params=[(), ('--symlink-install',)],
                ids=['install', 'symlink_install'])
def colcon_workspace(request: pytest.FixtureRequest,
                     tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, bool]:
    """Return a workspace where ``colcon build`` built this package, and if it linked it."""
    colcon = Path(sys.executable).with_name('colcon')
    if not colcon.exists():
        pytest.skip('colcon is not installed (scripts/setup_venv installs it with the test '
                    'extras)')
    ws = tmp_path_factory.mktemp('ros2_ws')
    shutil.copytree(ROOT, ws / 'src' / 'pmba_ros', ignore=NOT_PACKAGE)
    proc = subprocess.run([str(colcon), 'build', '--packages-select', 'pmba_ros',
                           *request.param], cwd=ws, capture_output=True, text=True,
                          timeout=600, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return ws, bool(request.param)


def sourced_env(setup: Path) -> dict[str, str]:
    """Return the environment after ``source setup`` (a colcon ``setup.bash``) in bash."""
    proc = subprocess.run(['bash', '-c', f'source "{setup}" && env -0'], capture_output=True,
                          timeout=60, check=True)
    pairs = (item.split(b'=', 1) for item in proc.stdout.split(b'\0') if b'=' in item)
    return {k.decode(): v.decode() for k, v in pairs}


def ament_lookup(env: dict[str, str]) -> tuple[Path, Path]:
    """Return pmba_ros' prefix and share folder as ament_index_python finds them in ``env``.

    ``ros2 run`` takes a package's executables from its prefix's ``lib/<package>``, the launch
    file its parameter file from the share folder.
    """
    code = ('from ament_index_python.packages import get_package_prefix, '
            'get_package_share_directory\n'
            "print(get_package_prefix('pmba_ros'))\n"
            "print(get_package_share_directory('pmba_ros'))")
    proc = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                          timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    prefix, share = proc.stdout.splitlines()
    return Path(prefix), Path(share)


@pytest.mark.slow
def test_colcon_build_then_ros2_run_pmba_node(listener: Listener, tmp_path: Path,
                                              colcon_workspace: tuple[Path, bool]) -> None:
    """The README's ROS way: ``colcon build``, ``source install/setup.bash``, ``ros2 run``.

    ros2cli is not on PyPI: the node is started as ``ros2 run pmba_ros pmba_node`` starts it,
    the executable under ``lib/pmba_ros`` of the prefix ament_index_python gives, with the
    installed parameter file, and the installed ``pmba play`` feeds it. The workspace's copy
    runs (installed, or linked from ``build`` with ``--symlink-install``), not this checkout.
    A fresh install has no compiled loops yet: the node compiles them in the background and
    handles the recording meanwhile (before, it compiled for tens of seconds before it
    subscribed, and a running front-end's messages of that time were lost). The linked
    install runs without them (``PMBA_NUMBA=0``), for the test's time.
    """
    pytest.importorskip('ament_index_python')
    workspace, linked = colcon_workspace
    install = workspace / 'install'
    env = sourced_env(install / 'setup.bash')
    prefix, share = ament_lookup(env)
    assert prefix == install / 'pmba_ros'
    lib = prefix / 'lib' / 'pmba_ros'
    for name in ('package.xml', 'config/pmba.yaml', 'launch/pmba.launch.py'):
        assert (share / name).is_file(), name
    for name in ('pmba_node', 'pmba', 'pmba_bag_replay'):
        assert os.access(lib / name, os.X_OK), name
    where = subprocess.run([sys.executable, '-c', 'import pmba_ros; print(pmba_ros.__file__)'],
                           env=env, cwd=tmp_path, capture_output=True, text=True, timeout=60,
                           check=True)
    assert Path(where.stdout.strip()).is_relative_to(workspace), where.stdout

    bag = tmp_path / 'street'
    if linked:
        env['PMBA_NUMBA'] = '0'
    made = subprocess.run([str(lib / 'pmba'), 'simulate', '--keyframes', str(N_KEYFRAMES),
                           '--seed', '5', '--out', str(bag)], env=env, capture_output=True,
                          text=True, timeout=120, check=False)
    assert made.returncode == 0, made.stderr
    domain = listener.domain  # type: ignore[attr-defined]
    log = tmp_path / 'node.log'
    node = start_node(domain, log, *LATCHED_INPUTS, '-p', 'max_time_s:=1',
                      program=(str(lib / 'pmba_node'),), params=share / 'config' / 'pmba.yaml',
                      env=env)
    player = None
    try:
        wait_until_up(listener, node, log)
        player = subprocess.Popen(
            [str(lib / 'pmba'), 'play', str(bag), '--wait-for-subscribers', '30', '--topics',
             '/features', '/keyframe_pose', '/camera_info'],
            env=isolated_env(domain, env), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True)
        stamps = keyframe_stamps(bag)
        check_outputs(listener, stamps)
        assert player.wait(timeout=30) == 0
        if not linked:
            assert 'compiling the solver loops in the background' in log.read_text(
                encoding='utf-8')
            assert spin_until(listener.executor, lambda: 'solver loops compiled in' in
                              log.read_text(encoding='utf-8'), timeout_s=600.0)
        _, text = stop(node, signal.SIGINT, log)
        assert node.returncode == 0, text
        assert 'Traceback' not in text
    finally:
        kill(node, player)
