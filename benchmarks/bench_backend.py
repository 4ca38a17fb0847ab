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
"""Benchmark of the online back-end (not a test): ATE, per-keyframe latency, memory.

Usage::

    python benchmarks/bench_backend.py ate --mode sliding
    python benchmarks/bench_backend.py ate --keyframes 300 --seed 3 --noise-px 1.0
    python benchmarks/bench_backend.py ate --no-tracks 80:30 --scenario loop --seed 1
    python benchmarks/bench_backend.py ate --no-tracks 80:30:8 --min-observations 5
    python benchmarks/bench_backend.py ate --no-tracks 80:30 --jump-at 95 --seed 1
    python benchmarks/bench_backend.py latency --keyframes 200
    python benchmarks/bench_backend.py latency --keyframes 1500 --serialize --deterministic
    python benchmarks/bench_backend.py memory --keyframes 2000

``ate``: ATE and RPE (Sim(3) alignment) of the optimized keyframes and of the front-end on a
simulated scenario (street by default), deterministic config, with the pixel noise the
back-end measured; ``--no-tracks FIRST:COUNT[:KEEP]`` empties the tracks of COUNT keyframes
from FIRST (a tunnel; or keeps KEEP tracks of the same features), ``--jump-at K`` makes the
front-end's frame jump at keyframe K; both add the steps into and out of the stretch and
into K (their errors against the ground truth's steps, m, after the Sim(3) alignment).
``latency``: wall and CPU time of each ``step()`` that processes a keyframe
(association, solve, outputs), with the node's default budgets. ``memory``: tracemalloc and
RSS every ``--every`` keyframes over a long street; the optimization state (stored
observations, features in the problem) must stay flat, the outputs (path, retired landmarks)
grow by design. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
import tracemalloc
from typing import Any

import numpy as np
from pmba_ros._process import tune_process
from pmba_ros.backend import outputs as out
from pmba_ros.backend.config import BackendConfig
from pmba_ros.backend.logic import BackendLogic
from pmba_ros.backend.msg_backend import RosbagsBackend
from pmba_ros.core import so3
from pmba_ros.eval.align import umeyama_alignment
from pmba_ros.eval.metrics import ate, rpe
from pmba_ros.eval.trajectory import Trajectory
from pmba_ros.io import cdr
from pmba_ros.sim.inputs import make_camera_info, make_tracks
from pmba_ros.sim.sequence import SimSequence, simulate_sequence

logger = logging.getLogger('bench_backend')


def _feed(logic: BackendLogic, seq: SimSequence, backend: RosbagsBackend, i: int,
          encoders: dict[str, cdr.Encoder] | None = None,
          ) -> tuple[float, float, list[tuple[str, Any]]]:
    """Feed keyframe i; return wall and CPU seconds of the processing step and its outputs.

    With ``encoders`` (one per topic) the outputs are serialized to CDR too, as the replay's
    writer does.
    """
    logic.on_tracks(make_tracks(seq.frames[i], 'vins_fusion', backend))
    logic.step()
    logic.on_keyframe(out.make_odometry(int(seq.stamps_ns[i]), 'odom', 'camera',
                                        seq.centers_odom[i], so3.to_quat_xyzw(seq.R_wc_odom[i]),
                                        np.eye(6) * 1e-3, backend))
    t0, c0 = time.perf_counter(), time.process_time()
    outputs = logic.step()
    if encoders is not None:
        for topic, msg in outputs:
            if encoders.setdefault(topic, cdr.Encoder()).encode(msg, msg.__msgtype__) is None:
                backend.serialize(msg)
    return time.perf_counter() - t0, time.process_time() - c0, outputs


def _start(config: BackendConfig, seq: SimSequence) -> tuple[BackendLogic, RosbagsBackend]:
    """Start."""
    backend = RosbagsBackend()
    logic = BackendLogic(config, backend)
    logic.on_camera_info(make_camera_info(int(seq.stamps_ns[0]), 'camera', seq.camera,
                                          backend))
    return logic, backend


def bench_ate(args: argparse.Namespace) -> dict[str, Any]:
    """Bench ate."""
    seq = simulate_sequence(args.scenario, args.keyframes, seed=args.seed,
                            noise_px=args.noise_px, drift=args.drift,
                            features_per_keyframe=args.features_per_keyframe)
    first, count, keep = args.no_tracks
    seq = seq.with_few_tracks(first, count, keep)
    fe_traj = seq.odom_trajectory()   # the reference: without the jump
    if args.jump_at:   # a restarted front-end
        seq = seq.with_odom_jump(args.jump_at, 0.3, np.array([3.0, -1.0, 0.5]))
    cfg = BackendConfig(mode=args.mode, window_size=args.window, deterministic=True,
                        min_observations=args.min_observations,
                        max_iterations=args.iterations)
    logic, backend = _start(cfg, seq)
    t0 = time.perf_counter()
    path_len = 0
    for i in range(len(seq)):
        for topic, msg in _feed(logic, seq, backend, i)[2]:
            if topic == cfg.path_topic:
                path_len = len(msg.poses)
    opt, gt = logic.optimized_trajectory(), seq.gt_trajectory()
    be, fe = ate(opt, gt, 'sim3').rmse, ate(fe_traj, gt, 'sim3').rmse
    rpe_be, rpe_fe = rpe(opt, gt, align='sim3').rmse, rpe(fe_traj, gt, align='sim3').rmse
    ends = {}
    if count or args.jump_at:
        into = sorted({first, first + count, args.jump_at} - {0})
        ends = {'steps_into': into, 'step_errors_m': _step_errors(opt, gt, into),
                'step_errors_frontend_m': _step_errors(fe_traj, gt, into)}
    return {**ends, 'bench': 'ate', 'scenario': args.scenario, 'mode': args.mode,
            'seed': args.seed, 'keyframes': len(seq), 'noise_px': args.noise_px,
            'drift': args.drift,
            'path_poses': path_len, 'init_attempts': logic.estimator.init_attempts,
            'ate_backend_m': be, 'ate_frontend_m': fe,
            'ratio': be / fe, 'rpe_ratio': rpe_be / rpe_fe,
            'noise_estimate_px': logic.estimator.pixel_noise.sigma,
            'wall_s': time.perf_counter() - t0}


def _step_errors(traj: Trajectory, gt: Trajectory, into: list[int]) -> list[float]:
    """Return the errors of the steps into keyframes ``into``, Sim(3)-aligned, m."""
    fit = umeyama_alignment(traj.positions_xyz, gt.positions_xyz, with_scale=True)
    p = fit.scale * traj.positions_xyz @ fit.rotation.T
    d = np.diff(p, axis=0) - np.diff(gt.positions_xyz, axis=0)
    return [float(np.linalg.norm(d[k - 1])) for k in into if 0 < k < len(gt)]


def bench_latency(args: argparse.Namespace) -> dict[str, Any]:
    """Bench latency."""
    seq = simulate_sequence('street', args.keyframes, seed=args.seed)
    kwargs: dict[str, Any] = {'mode': 'sliding', 'window_size': args.window,
                              'deterministic': args.deterministic}
    if args.iterations:
        kwargs['max_iterations'] = args.iterations
    if args.max_time is not None:
        kwargs['max_time_s'] = args.max_time
    cfg = BackendConfig(**kwargs)
    logic, backend = _start(cfg, seq)
    wall, cpu = [], []
    steps = np.full(len(seq), np.nan)
    encoders: dict[str, cdr.Encoder] | None = {} if args.serialize else None
    for i in range(len(seq)):
        w, c, _ = _feed(logic, seq, backend, i, encoders)
        if logic.estimator.state == 'tracking' and i >= cfg.init_batch_size:
            wall.append(1e3 * w)
            cpu.append(1e3 * c)
            steps[i] = 1e3 * c
    solve = np.asarray(logic.stats.solve_ms[1:])

    def stats(v: list[float] | np.ndarray) -> dict[str, float]:
        """Stats."""
        return {'median_ms': float(np.median(v)), 'p95_ms': float(np.percentile(v, 95)),
                'max_ms': float(np.max(v))}

    iterations = np.asarray(logic.stats.iterations[1:])
    return {'bench': 'latency', 'window': args.window, 'keyframes': len(seq),
            'max_iterations': cfg.max_iterations,
            'max_time_s': None if cfg.deterministic else cfg.max_time_s,
            'iterations_mean': float(iterations.mean()),
            'zero_iteration_refines': int(np.sum(iterations == 0)),
            'step_wall': stats(wall), 'step_cpu': stats(cpu), 'solve_wall': stats(solve),
            'flatness': _flatness(steps),
            'load_average': os.getloadavg()[0],
            'blas_threads': _blas_threads()}


def _flatness(step_cpu_ms: np.ndarray) -> dict[str, float] | None:
    """Median step CPU time of keyframes 100-300 and of the last 200, and their ratio."""
    n = step_cpu_ms.shape[0]
    if n < 500:
        return None
    early = float(np.nanmedian(step_cpu_ms[100:300]))
    late = float(np.nanmedian(step_cpu_ms[n - 200:]))
    return {'kf_100_300_ms': early, 'last_200_ms': late, 'ratio': late / early}


def _blas_threads() -> list[int]:
    """Return the thread count of each BLAS pool (empty without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return []
    return [int(p['num_threads']) for p in threadpool_info() if p.get('user_api') == 'blas']


def _rss_mb() -> float:
    """Rss mb."""
    with open('/proc/self/statm', encoding='ascii') as fh:
        return int(fh.read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 2**20


def bench_memory(args: argparse.Namespace) -> dict[str, Any]:
    """Bench memory."""
    seq = simulate_sequence('street', args.keyframes, seed=args.seed)
    cfg = BackendConfig(mode='sliding', window_size=args.window, deterministic=True,
                        max_iterations=1)
    logic, backend = _start(cfg, seq)
    tracemalloc.start()
    rows = []
    for i in range(len(seq)):
        _feed(logic, seq, backend, i)
        if (i + 1) % args.every == 0:
            est = logic.estimator
            current, _ = tracemalloc.get_traced_memory()
            rows.append({'keyframe': i + 1, 'traced_mb': current / 2**20, 'rss_mb': _rss_mb(),
                         'stored_observation_sets': len(est.kf.obs),
                         'features_in_problem': len(est.features),
                         'retired_landmarks': len(est.landmarks),
                         'cached_path_poses': len(logic._pose_cache)})
    tracemalloc.stop()
    state = [r['stored_observation_sets'] for r in rows[1:]]
    feats = [r['features_in_problem'] for r in rows[1:]]
    return {'bench': 'memory', 'keyframes': len(seq), 'window': args.window, 'rows': rows,
            'stored_observation_sets_max': max(state), 'features_in_problem_max': max(feats),
            'traced_growth_mb': rows[-1]['traced_mb'] - rows[0]['traced_mb'],
            'rss_growth_mb': rows[-1]['rss_mb'] - rows[0]['rss_mb']}


def _span(text: str) -> tuple[int, int, int]:
    """Parse FIRST:COUNT[:KEEP]."""
    first, count, keep = [*text.split(':'), '0'][:3]
    return int(first), int(count), int(keep)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark verb given on the command line."""
    tune_process()
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bench', choices=('ate', 'latency', 'memory'))
    parser.add_argument('--mode', choices=('sliding', 'global'), default='sliding')
    parser.add_argument('--keyframes', type=int, default=None)
    parser.add_argument('--window', type=int, default=20)
    parser.add_argument('--iterations', type=int, default=None)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--scenario', choices=('street', 'aerial', 'loop'), default='street',
                        help='ate: simulated scenario')
    parser.add_argument('--noise-px', type=float, default=0.5, help='ate: pixel noise sigma')
    parser.add_argument('--drift', type=float, default=0.02, help='ate: front-end drift')
    parser.add_argument('--features-per-keyframe', type=int, default=15,
                        help='ate: new features per keyframe (10x at the first); 2: a front-end '
                        'tracking few features')
    parser.add_argument('--no-tracks', type=_span, default=(0, 0, 0),
                        metavar='FIRST:COUNT[:KEEP]',
                        help='ate: keyframes FIRST..FIRST+COUNT-1 bring no tracks (KEEP: '
                        'only KEEP, the same features throughout)')
    parser.add_argument('--jump-at', type=int, default=0, metavar='K',
                        help="ate: the front-end's frame jumps at keyframe K (turned 0.3 rad, "
                        'moved 3 m); the front-end without the jump is the reference')
    parser.add_argument('--min-observations', type=int,
                        default=BackendConfig().min_observations,
                        help='ate: the parameter min_observations')
    parser.add_argument('--every', type=int, default=200)
    parser.add_argument('--deterministic', action='store_true',
                        help='latency: no time budget (fixed iterations; CPU time is then the '
                        'unloaded-machine estimate)')
    parser.add_argument('--max-time', type=float, default=None, help='latency: max_time_s')
    parser.add_argument('--serialize', action='store_true',
                        help='latency: serialize the outputs to CDR in the timed step, as the '
                        'replay does')
    args = parser.parse_args(argv)
    if args.keyframes is None:
        args.keyframes = 2000 if args.bench == 'memory' else 200
    if args.bench == 'ate' and args.iterations is None:
        args.iterations = BackendConfig().max_iterations
    logging.basicConfig(level=logging.WARNING)
    result = {'ate': bench_ate, 'latency': bench_latency, 'memory': bench_memory}[args.bench](
        args)
    print(json.dumps(result, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
