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
"""Compile (or load) the solver's compiled loops ahead of the work that needs them.

numba compiles each loop of :mod:`pmba_ros.core.compiled` at its first call and keeps the
machine code in its cache (:mod:`pmba_ros.core.jit`). The first call after an install or an
upgrade therefore compiles them all, which takes tens of seconds; later processes load them
in about a second. :func:`warm_up` solves a tiny problem that reaches every loop with the
argument types the solver, the back-end and the initialization use, so that this happens in
``pmba warmup`` (run by ``scripts/setup_venv``) or before a CLI command that solves, with a
message, rather than inside the first keyframe; the node compiles them in the background
(:func:`warm_up_in_background`) and solves with the numpy engine meanwhile.
A marker next to numba's cache records that the current loops were compiled, so the callers
can tell beforehand whether the wait will be long (:func:`is_warm`).
"""

from __future__ import annotations

from collections.abc import Callable
import hashlib
import logging
import os
from pathlib import Path
import platform
import subprocess
import sys
import threading
import time

import numpy as np
from pmba_ros.core import compiled, conversions, jit, so3
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.core.compiled import epipolar, gather, linear_rays, track_pairs
from pmba_ros.core.engine import COMPILED, compiled_available, EngineName
from pmba_ros.core.loss import Loss
from pmba_ros.core.problem import BAProblem, make_problem, Parameterization
from pmba_ros.core.solve import solve, SolveOptions, SolverKind

logger = logging.getLogger(__name__)

#: What a first compilation takes, for the message shown before it (wall time on a
#: 2-core machine, from idle to loaded).
EXPECTED_COMPILE_S = (15, 60)


def expected_compile_text() -> str:
    """Return the expected compile time as users are told it ('15-60 s')."""
    lo, hi = EXPECTED_COMPILE_S
    return f'{lo}-{hi} s'


def _marker() -> Path | None:
    """Return the file that says the current loops are in the cache (None: nothing cached)."""
    folder = jit.cache_folder()
    if folder is None:
        return None
    stamps = [f'{src.name}:{src.stat().st_mtime_ns}:{src.stat().st_size}'
              for src in sorted(Path(compiled.__file__).parent.glob('*.py'))]
    key = '|'.join([*stamps, jit.numba_version(), platform.python_version(),
                    platform.machine(), sys.platform])
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    return folder / f'pmba_warmup-{digest}.ok'


def is_warm() -> bool:
    """Return whether the loops load from the cache (True when they are off)."""
    if not compiled_available():
        return True
    marker = _marker()
    return marker is not None and marker.exists()


def _tiny_problem() -> BAProblem:
    """Return six cameras moving forward past 40 points, with a perturbed start."""
    rng = np.random.default_rng(0)
    n_cams, n_points = 6, 40
    # Cameras look along +x (camera z = world x), 1 m apart, as on a street.
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]).T
    R_wc = np.repeat(R[None], n_cams, axis=0)
    centers = np.stack([np.arange(n_cams, dtype=float), np.zeros(n_cams), np.zeros(n_cams)],
                       axis=1)
    points = np.column_stack([rng.uniform(10.0, 30.0, n_points),
                              rng.uniform(-3.0, 3.0, (n_points, 2))])
    intr = Intrinsics.uniform(n_cams, 500.0, 500.0, 320.0, 240.0)
    cam_idx = np.tile(np.arange(n_cams), n_points)
    feat_idx = np.repeat(np.arange(n_points), n_cams)
    h_c = np.einsum('kji,kj->ki', R_wc[cam_idx], points[feat_idx] - centers[cam_idx])
    pixels = project(h_c, intr, cam_idx) + rng.normal(0.0, 0.5, (cam_idx.size, 2))
    fixed = np.zeros(n_cams, dtype=bool)
    fixed[:2] = True
    dR = so3.exp(rng.normal(0.0, 0.01, (n_cams, 3)))
    dR[:2] = np.eye(3)
    return make_problem(R_wc @ dR, centers, intr, cam_idx, feat_idx, pixels,
                        points_w=points + rng.normal(0.0, 0.3, points.shape), fixed=fixed)


def warm_up() -> float:
    """Compile or load every compiled loop now; return the seconds it took.

    Returns 0.0 without numba or with ``PMBA_NUMBA=0``. Writes the :func:`is_warm` marker.
    """
    if not compiled_available():
        return 0.0
    t0 = time.perf_counter()
    problem = _tiny_problem()
    # The compiled engine by name: while this runs in the background, 'auto' is numpy.
    feats, _ = conversions.xyz_to_parallax(problem, problem.R_wc, problem.centers_w,
                                           np.asarray(problem.points_w), engine=COMPILED)
    solve(problem, SolveOptions(param=Parameterization.PMBA, solver=SolverKind.DOGLEG,
                                loss=Loss.CAUCHY, max_iterations=2,
                                engine=EngineName.COMPILED), feats)
    # The global initialization's anchor search (xyz_to_parallax above has its own pass).
    conversions.select_anchors(problem, problem.R_wc, centers_w=problem.centers_w,
                               engine=COMPILED)
    # The global initialization's position steps (init.cls), on the same problem's indices.
    obs = problem.obs
    assoc, main = feats.assoc_idx.astype(np.int64), feats.main_idx.astype(np.int64)
    coeff, sin_t = np.zeros((problem.n_feats, 2, 3, 3)), np.zeros(problem.n_feats)
    # Every term in block 0: the slots' values do not matter for the compilation.
    slots = (np.zeros(problem.n_obs, dtype=np.int64),
             np.zeros((problem.n_obs, 2, 2), dtype=np.int64),
             np.zeros((problem.n_feats, 2, 2), dtype=np.int64))
    for feat in (obs.feat_idx, np.array(obs.feat_idx)):
        # Read-only indices (the problem's) and writable ones.
        linear_rays.ray_normal_blocks(feat, coeff, sin_t, np.zeros((problem.n_obs, 3, 3)),
                                      *slots, 1)
    ones = np.ones(problem.n_obs)
    # Writable rays and centres, as init.nls hands them (the problem's arrays are read-only).
    N, e, _ = linear_rays.ray_errors(obs.cam_idx, obs.feat_idx, assoc, main, coeff, sin_t,
                                     np.array(obs.bearings_c), np.array(problem.centers_w),
                                     ones, ones)
    _, y = linear_rays.nls_weights(N, e, ones, ones)
    linear_rays.ray_depths(obs.cam_idx, obs.feat_idx, assoc, main, coeff, sin_t,
                           np.array(obs.bearings_c), problem.centers_w)
    linear_rays.cheirality_row_norms(obs.feat_idx, coeff, sin_t, np.array(obs.bearings_c))
    linear_rays.ray_gradient(obs.cam_idx, obs.feat_idx, assoc, main, coeff, sin_t, y,
                             problem.n_cams)
    # The checks of the EG pairs' models (init.two_view), on gathered (writable) bearings.
    b = obs.bearings_c[np.arange(problem.n_obs)]
    seg = np.zeros(problem.n_obs, dtype=np.int64)
    E, R = np.zeros((1, 3, 3)), np.tile(np.eye(3), (1, 2, 1, 1))
    epi, _, _, _ = epipolar.epipolar_votes(E, R, np.ones((1, 3)), np.ones(1), b, b, seg)
    epipolar.rotation_covariances(b, b, seg, epi, 1)
    epipolar.median_angles(np.eye(3)[None], b, b, seg, epi, 1)
    # refine_translations reads the problem's (read-only) bearings in place.
    idx, ends = np.arange(problem.n_obs), np.array([0, problem.n_obs])
    epipolar.epipolar_scatter(np.eye(3)[None], obs.bearings_c, idx, idx, ends)
    epipolar.translation_votes(np.eye(3)[None], np.ones((1, 3)), obs.bearings_c, idx, idx, ends)
    linear_rays.linear_ray_values(obs.cam_idx, obs.feat_idx, assoc, main, coeff, sin_t,
                                  problem.centers_w)
    # The joins of tracks into camera pairs (init.covisibility), all of them and a sample.
    order = np.lexsort((obs.cam_idx, obs.feat_idx))
    f, c = obs.feat_idx[order], obs.cam_idx[order]
    counts = track_pairs.count_pairs(f, c, problem.n_cams)
    for sample in (None, 3):
        track_pairs.join_pairs(f, c, problem.n_cams, problem.n_cams, counts > 0, counts, sample)
    # The back-end's window gathering (filtered and thinned, and the initialization's).
    ids, offsets = np.array(obs.feat_idx), np.array([0, problem.n_obs])
    gather.ordered_tracks(ids, offsets, np.unique(ids), 3, True)
    gather.ordered_tracks(ids, offsets, None, 0, False)
    marker = _marker()
    if marker is not None:
        try:
            marker.touch()
        except OSError:
            pass   # the cache folder went away: the next start compiles or says so again
    return time.perf_counter() - t0


CHILD_TIMEOUT_S = 1800.0
"""A compilation still running after this (thirty times the expected) is taken as hung."""


def compile_in_child() -> bool:
    """Run :func:`warm_up` in a child interpreter; return whether it succeeded.

    numba's compiler is mostly Python: in a thread it would hold this process's interpreter
    lock for most of a minute, and the solves beside it would crawl. The child fills the
    on-disk cache this process then loads from; it runs on this process's module path
    (``-P``: not on its working folder), so it compiles the same files.
    """
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    code = 'from pmba_ros.core.warmup import warm_up; warm_up()'
    proc = subprocess.run([sys.executable, '-P', '-c', code], env=env, capture_output=True,
                          text=True, timeout=CHILD_TIMEOUT_S, check=False)
    if proc.returncode != 0:
        logger.warning('compiling the solver loops in a child process failed (exit code %d): '
                       '%s', proc.returncode, proc.stderr.strip()[-2000:])
    return proc.returncode == 0


def warm_up_in_background(done: Callable[[float | None], None]) -> threading.Thread:
    """Compile the loops beside this process's work; the 'auto' engine is numpy until then.

    For a process that should not wait for a first compilation (the node: its front-end does
    not wait either). A thread waits for :func:`compile_in_child` (where the loops can be
    cached), then loads them, or compiles them itself. ``done`` gets the seconds it all
    took, or None if it failed (the numpy engine then stays).
    """
    jit.NOT_READY.set()
    t0 = time.perf_counter()

    def run() -> None:
        try:
            if jit.CACHING:
                compile_in_child()
            warm_up()
        except Exception:   # numba's own errors are not one family
            logger.exception('compiling the solver loops failed: the numpy engine stays')
            done(None)
            return
        jit.NOT_READY.clear()
        done(time.perf_counter() - t0)

    thread = threading.Thread(target=run, name='pmba_compile', daemon=True)
    thread.start()
    return thread


def warm_up_beside_input(say: Callable[[str], None]) -> None:
    """Load the compiled loops now, or compile them in the background, telling ``say``.

    A process that takes input as it comes (the node) should not wait for a first
    compilation, as its input does not: that runs beside the solves (numpy until it is done).
    Loading compiled loops takes about a second and comes before the input.
    """
    if is_warm():
        seconds = warm_up()
        if seconds > 1.0:
            say(f'solver loops ready in {seconds:.1f} s')
        return
    say(f'compiling the solver loops in the background (once per install; expected '
        f'{expected_compile_text()}); solving without them until then')
    warm_up_in_background(lambda s: say(
        'compiling the solver loops failed: solving without them' if s is None
        else f'solver loops compiled in {s:.1f} s: solving with them'))
