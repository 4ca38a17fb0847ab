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

"""Live node benchmark: odometry latency of pmba_node over DDS at real time.

Run (needs the ``ros`` extra)::

    python benchmarks/bench_node.py                     # 150-keyframe street, 10 keyframes/s
    python benchmarks/bench_node.py --keyframes 300 --seed 2 --check
    python benchmarks/bench_node.py --keyframes 600 --seed 3 -p mode:=global

It writes a simulated street recording, starts ``pmba_node`` as a process with its default
parameters (``config/pmba.yaml``) and ``pmba play`` as an independent publisher process, both
on a private ``ROS_DOMAIN_ID`` with localhost discovery, and listens here to the keyframe
poses going in and ``pmba/odometry`` coming out. A keyframe's latency is the time from its
pose's arrival here to the arrival of the first odometry with its stamp, over the whole run
(the global initialization included); the time to the last (corrected, optimized) odometry
is printed too. ``--check`` exits non-zero unless every keyframe got odometry, the last path
holds every keyframe, and the latency median is under 20 ms and its 95th percentile under
50 ms.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return env


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)


def main() -> int:
    """Run the benchmark and print the latency figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--keyframes', type=int, default=150)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--domain', type=int, default=random.randint(1, 100),
                        help='ROS_DOMAIN_ID of the run (a private one by default)')
    parser.add_argument('--check', action='store_true', help='fail above the targets')
    parser.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='a node parameter over the parameter file (repeatable)')
    args = parser.parse_args()

    from nav_msgs.msg import Odometry
    from nav_msgs.msg import Path as PathMsg
    from pmba_ros.sim.bag import write_sequence_bag
    from pmba_ros.sim.sequence import simulate_sequence
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message

    with tempfile.TemporaryDirectory(prefix='pmba_bench_node_') as tmp:
        bag = Path(tmp) / 'street'
        seq = simulate_sequence('street', n_keyframes=args.keyframes, seed=args.seed)
        info = write_sequence_bag(seq, bag)
        env = _env(args.domain)
        os.environ.update(env)      # the listener discovers like the two processes
        context = Context()
        rclpy.init(context=context, domain_id=args.domain)
        executor = SingleThreadedExecutor(context=context)
        listener = rclpy.create_node('bench_listener', context=context)
        executor.add_node(listener)
        qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
        # pmba play publishes transient local; readers that are too lose no first message.
        latched = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        arrivals: dict[int, float] = {}
        first_out: dict[int, float] = {}
        last_out: dict[int, float] = {}
        paths: list[Any] = []

        def on_keyframe(msg: Any) -> None:
            arrivals.setdefault(_stamp_ns(msg), time.monotonic())

        def on_odometry(msg: Any) -> None:
            now = time.monotonic()
            first_out.setdefault(_stamp_ns(msg), now)
            last_out[_stamp_ns(msg)] = now

        listener.create_subscription(Odometry, '/keyframe_pose', on_keyframe, latched)
        listener.create_subscription(Odometry, '/pmba/odometry', on_odometry, qos)
        # Raw: a long run's Path is large, and deserializing every one here would slow this
        # listener down, and with it the latencies it measures; only the last one is read.
        listener.create_subscription(PathMsg, '/pmba/path', paths.append, qos, raw=True)
        # The node's log goes to a file: an unread pipe would block it once full.
        node_log = (Path(tmp) / 'node.log').open('w+', encoding='utf-8')
        node = subprocess.Popen(
            [sys.executable, '-m', 'pmba_ros.node', '--ros-args', '--params-file',
             str(ROOT / 'config' / 'pmba.yaml'), '-p', 'features_qos:=transient_local',
             '-p', 'keyframe_qos:=transient_local', '-p', 'camera_info_qos:=transient_local',
             *(a for p in args.param for a in ('-p', p))],
            env=env, stdout=node_log, stderr=node_log,
            text=True, preexec_fn=_default_sigint)
        player = None
        try:
            print(f'street: {info.n_keyframes} keyframes, {info.duration_s:.1f} s at real time; '
                  f'domain {args.domain}')
            player = subprocess.Popen(
                [sys.executable, '-m', 'pmba_ros', 'play', str(bag), '--topics', '/features',
                 '/keyframe_pose', '/camera_info', '--delay', '2', '--wait-for-subscribers',
                 '120'],
                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

            def complete() -> bool:
                return (len(first_out) >= args.keyframes and bool(paths)
                        and len(deserialize_message(paths[-1], PathMsg).poses)
                        >= args.keyframes)

            deadline = time.monotonic() + info.duration_s + 300.0
            while time.monotonic() < deadline and player.poll() is None:
                executor.spin_once(timeout_sec=0.05)
            deadline = time.monotonic() + 60.0      # the back-end catching up
            while time.monotonic() < deadline and not complete():
                executor.spin_once(timeout_sec=0.05)
        finally:
            node.send_signal(signal.SIGINT)
            try:
                node.wait(timeout=10)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait()
            node_log.seek(0)
            stderr = node_log.read()
            node_log.close()
            if player is not None and player.poll() is None:
                player.kill()
            executor.shutdown()
            listener.destroy_node()
            rclpy.shutdown(context=context)

    stamps = sorted(arrivals)
    lat = np.array([first_out[s] - arrivals[s] for s in stamps if s in first_out]) * 1e3
    corrected = np.array([last_out[s] - arrivals[s] for s in stamps if s in last_out]) * 1e3
    in_path = len(deserialize_message(paths[-1], PathMsg).poses) if paths else 0
    print(f'keyframes in: {len(stamps)}, with odometry: {lat.size}, in the last path: '
          f'{in_path}; node exit code {node.returncode}')
    if lat.size:
        print(f'odometry latency (first message), ms: median {np.median(lat):.1f}, '
              f'p95 {np.percentile(lat, 95):.1f}, max {lat.max():.1f}')
        print(f'optimized (last message), ms: median {np.median(corrected):.1f}, '
              f'p95 {np.percentile(corrected, 95):.1f}, max {corrected.max():.1f}')
    if node.returncode != 0 or lat.size < len(stamps):
        print(stderr[-3000:], file=sys.stderr)
    if args.check:
        ok = (lat.size == args.keyframes == in_path and float(np.median(lat)) < 20.0
              and float(np.percentile(lat, 95)) < 50.0)
        print('check:', 'ok' if ok else 'FAILED')
        return 0 if ok else 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
