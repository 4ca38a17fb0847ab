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
"""Engine benchmark: PMBA-Dogleg and XYZ-LM of this engine against scipy and Ceres.

Run::

    python benchmarks/bench_engine.py                          # Ladybug-49 and synthetic
    python benchmarks/bench_engine.py --datasets ladybug --threads 1 --quiet

One table per dataset, one row per method, all from the same start:

* ``PMBA-Dogleg``: :func:`pmba_ros.core.solve.solve` with default options, on every core
  where the problem is large enough to split (:mod:`pmba_ros.core.compiled.chunks`), and on
  one thread.
* ``XYZ-LM``: the same engine with ``param='xyz', solver='lm'``.
* ``scipy trf``: :func:`scipy.optimize.least_squares` (``method='trf'``, ``x_scale='jac'``,
  ``tr_solver='lsmr'`` with at most 200 LSMR iterations per step, wall time capped by
  ``--scipy-budget-s``) on the XYZ pixel residuals with the analytic sparse Jacobian of
  :meth:`~pmba_ros.core.models.XyzModel.linearize`; each rotation is ``R0 Exp(delta)`` and
  its columns are multiplied by the SO(3) right Jacobian of ``delta``. The gauge is free.
* ``Ceres LM``: C++ Ceres (pyceres) on the problem pycolmap builds in C++ from a
  reconstruction: COLMAP's ``ReprojErrorCost`` with the RADIAL camera model (OPENCV when
  fx != fy), constant intrinsics, poses as ``cam_from_world`` (quaternion xyzw +
  translation, ``R_cw = R_wc^T``, ``t = -R_cw C``) on the quaternion x R^3 manifold, free
  gauge, ``SPARSE_SCHUR`` + Levenberg-Marquardt with Ceres' default tolerances (the
  engine's defaults). Timed with ``--threads`` threads (default 1, the fair comparison) and
  with 2 threads. Skipped with a note if pyceres or pycolmap is missing.

Columns: iterations (accepted and rejected steps), linear solves (factorizations of the
reduced camera system; LSMR solves for scipy), wall seconds of the solve (problem set-up of
scipy and Ceres excluded, the engine's own set-up included), seconds per iteration, pixel
RMS before and after, the wall time relative to the Ceres row, and the process's peak
resident memory while the method ran (problem data and libraries included). The RMS is computed the
same way for every method: sqrt of the mean squared 2-D error over all observations of
``project(R_wc^T (X - C))``. PMBA's start is its parallax features converted back to points
(the conversion moves points seen behind a camera, so its initial RMS can differ).

COLMAP's cost function returns a zero residual for a point behind the camera, while the
engine and scipy (BAL convention) project it through the same formula, so on BAL problems
with such observations Ceres minimizes a slightly different objective; the sanity check
after each table compares Ceres and XYZ-LM over all observations and over the observations
in front of their cameras.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
import math
import os
from pathlib import Path
import platform
import shlex
import sys
import time
from typing import Any

import numpy as np
from pmba_ros._process import tune_process
from pmba_ros.core import conversions, so3
from pmba_ros.core.camera import project
from pmba_ros.core.compiled import chunks
from pmba_ros.core.conversions import initial_features
from pmba_ros.core.models import XyzModel
from pmba_ros.core.problem import BAProblem, XyzFeatures
from pmba_ros.core.solve import solve, SolveOptions, SolveResult
from pmba_ros.io.bal import read_bal
from pmba_ros.sim.scenes import synthetic_large, table3_scene
import scipy
import scipy.optimize
import scipy.sparse

SHARED = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'
LADYBUG = SHARED / 'bal' / 'problem-49-7776-pre.txt'
TRAFALGAR = SHARED / 'bal' / 'problem-21-11315-pre.txt'
DATASETS = ('ladybug', 'synthetic')
#: Also selectable with --datasets: BAL Trafalgar-21 and a ring of 400 cameras, ~964k observations.
MORE_DATASETS = ('trafalgar', 'large')
METHODS = ('pmba', 'xyz', 'scipy', 'ceres')
RMS_TOLERANCE = 0.02
"""Largest relative difference of the final RMS of Ceres and XYZ-LM the sanity check allows."""
LSMR_MAXITER = 200
"""LSMR iterations per scipy trust-region solve."""


@dataclass
class Row:
    """One method's result on one dataset.

    Attributes:
        method: Method label.
        iterations: Iterations (accepted and rejected steps).
        linear_solves: Linear solves (factorizations, or LSMR solves for scipy).
        seconds: Wall time of the solve.
        initial_rms: Pixel RMS at the start.
        final_rms: Pixel RMS at the end.
        note: Termination reason or other remarks.
        solution: Final (R_wc, centers_w, points_w), for the sanity checks.
        peak_rss_mb: The process's peak resident memory during the solve (MB; NaN where
            Linux' peak counter cannot be reset).
    """

    method: str
    iterations: int
    linear_solves: int
    seconds: float
    initial_rms: float
    final_rms: float
    note: str = ''
    solution: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    peak_rss_mb: float = math.nan


def measured(run: Callable[[], Row]) -> Row:
    """Run one method and record the process's peak resident memory while it ran.

    Linux only: writing 5 to /proc/self/clear_refs resets the peak (VmHWM) first.
    """
    try:
        with open('/proc/self/clear_refs', 'w', encoding='ascii') as fh:
            fh.write('5')
    except OSError:
        return run()
    row = run()
    with open('/proc/self/status', encoding='ascii') as fh:
        for line in fh:
            if line.startswith('VmHWM:'):
                row.peak_rss_mb = int(line.split()[1]) / 1024
    return row


def reprojection_errors(problem: BAProblem, R_wc: np.ndarray, centers_w: np.ndarray,
                        points_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return each observation's 2-D pixel error (K, 2) and camera-frame depth (K,).

    Args:
        problem: The problem (observations and intrinsics).
        R_wc: Camera -> world rotations (M, 3, 3).
        centers_w: Camera centres (M, 3).
        points_w: Points (N, 3).

    Returns:
        ``project(R_wc^T (X - C)) - pixels`` and the z of ``R_wc^T (X - C)``.
    """
    o = problem.obs
    h = np.einsum('kji,kj->ki', R_wc[o.cam_idx], points_w[o.feat_idx] - centers_w[o.cam_idx])
    return project(h, problem.intrinsics, o.cam_idx) - o.pixels, h[:, 2]


def rms_px(problem: BAProblem, R_wc: np.ndarray, centers_w: np.ndarray,
           points_w: np.ndarray, front_only: bool = False) -> float:
    """Return the pixel RMS, sqrt of the mean squared 2-D reprojection error.

    Args:
        problem: The problem.
        R_wc: Camera -> world rotations (M, 3, 3).
        centers_w: Camera centres (M, 3).
        points_w: Points (N, 3); observations of non-finite points are left out.
        front_only: Count only observations in front of their camera (z > 0).

    Returns:
        The RMS in pixels over the counted observations.
    """
    err, z = reprojection_errors(problem, R_wc, centers_w, points_w)
    sq = np.sum(err * err, axis=1)
    keep = np.isfinite(sq)
    if front_only:
        keep &= z > 0
    return float(np.sqrt(np.mean(sq[keep]))) if np.any(keep) else math.nan


# --- this engine ------------------------------------------------------------------------------


def run_engine(problem: BAProblem, label: str, options: SolveOptions) -> Row:
    """Solve with this engine.

    Args:
        problem: The problem (its poses and points are the start).
        label: Method label.
        options: Solver options.

    Returns:
        The row; the RMS values use :func:`rms_px` on the start and result points.
    """
    result: SolveResult = solve(problem, options)
    solved = result.problem
    _, feats0 = initial_features(solved, options.param)
    X0 = conversions.to_xyz(solved.R_wc, solved.centers_w, feats0)
    initial = rms_px(solved, np.asarray(solved.R_wc), np.asarray(solved.centers_w), X0)
    final = rms_px(solved, result.R_wc, result.centers_w, result.points_w)
    notes = [result.termination.value]
    n_inf = int(np.sum(~np.all(np.isfinite(result.points_w), axis=1)))
    if n_inf:
        notes.append(f'{n_inf} pts at inf left out of RMS')
    if solved.n_feats != problem.n_feats:
        notes.append(f'{problem.n_feats - solved.n_feats} feats dropped')
    return Row(label, result.iterations, result.linear_solves, result.time_s, initial, final,
               ', '.join(notes), (result.R_wc, result.centers_w, result.points_w))


# --- scipy ------------------------------------------------------------------------------------


def so3_right_jacobian(omega: np.ndarray) -> np.ndarray:
    """Return the right Jacobian of SO(3), Exp(w + d) ~ Exp(w) Exp(Jr(w) d), shape (..., 3, 3).

    Args:
        omega: Rotation vectors (..., 3).

    Returns:
        ``I - (1 - cos t) / t^2 [w]x + (t - sin t) / t^3 [w]x^2`` (series for small t).
    """
    theta_sq = np.sum(omega * omega, axis=-1)
    small = theta_sq < 1e-8
    theta = np.sqrt(np.where(small, 1.0, theta_sq))
    a = np.where(small, 0.5 - theta_sq / 24.0, (1.0 - np.cos(theta)) / (theta * theta))
    b = np.where(small, 1.0 / 6.0 - theta_sq / 120.0,
                 (theta - np.sin(theta)) / (theta * theta * theta))
    K = so3.hat(omega)
    return np.eye(3) - a[..., None, None] * K + b[..., None, None] * (K @ K)


class ScipyXyzProblem:
    """XYZ-BA as a scipy least-squares problem: x = [delta (3M), centres (3M), points (3N)].

    Rotations are ``R0 Exp(delta)``; residuals and the analytic sparse Jacobian (CSR, nine
    non-zeros per row) come from :class:`~pmba_ros.core.models.XyzModel`.
    """

    def __init__(self, problem: BAProblem) -> None:
        """Precompute the Jacobian's sparsity pattern.

        Args:
            problem: The problem; its poses and points are the start.
        """
        self.problem = problem
        self.model = XyzModel(problem)
        self.M, self.N, K = problem.n_cams, problem.n_feats, problem.n_obs
        self.R0 = np.array(problem.R_wc)
        cam, feat = problem.obs.cam_idx, problem.obs.feat_idx
        c3 = np.arange(3)
        cols = np.concatenate([3 * cam[:, None] + c3, 3 * self.M + 3 * cam[:, None] + c3,
                               6 * self.M + 3 * feat[:, None] + c3], axis=1)  # (K, 9)
        self.indices = np.repeat(cols[:, None, :], 2, axis=1).reshape(-1).astype(np.int32)
        self.indptr = np.arange(0, 18 * K + 1, 9, dtype=np.int64)
        self.shape = (2 * K, 6 * self.M + 3 * self.N)
        self.x0 = np.concatenate([np.zeros(3 * self.M), np.ravel(problem.centers_w),
                                  np.ravel(problem.points_w)])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return (delta, R_wc, centers_w, points_w) of a parameter vector."""
        M = self.M
        delta = x[:3 * M].reshape(M, 3)
        return (delta, self.R0 @ so3.exp(delta), x[3 * M:6 * M].reshape(M, 3),
                x[6 * M:].reshape(self.N, 3))

    def fun(self, x: np.ndarray) -> np.ndarray:
        """Return the stacked pixel residuals (2K,)."""
        _, R, C, X = self.unpack(x)
        return self.model.residuals(R, C, XyzFeatures(X)).ravel()

    def jac(self, x: np.ndarray) -> scipy.sparse.csr_matrix:
        """Return the analytic sparse Jacobian (2K, 6M + 3N)."""
        delta, R, C, X = self.unpack(x)
        lin = self.model.linearize(R, C, XyzFeatures(X))
        Jr = so3_right_jacobian(delta)[self.problem.obs.cam_idx]
        data = np.concatenate([lin.J_obs[:, :, :3] @ Jr, lin.J_obs[:, :, 3:], lin.J_feat], axis=2)
        return scipy.sparse.csr_matrix((data.reshape(-1), self.indices, self.indptr),
                                       shape=self.shape)


class _BudgetExceeded(Exception):
    """Raised from the residual function when the scipy time budget is used up."""


def run_scipy(problem: BAProblem, budget_s: float = math.inf) -> Row:
    """Solve XYZ-BA with scipy.optimize.least_squares (trf, LSMR, Jacobian scaling).

    Tolerances follow the engine's: ftol 1e-6 (relative cost change), xtol 1e-8, gtol 1e-10.
    LSMR is capped at ``LSMR_MAXITER`` iterations per solve (scipy's default, min(m, n), made
    Ladybug-49 four times slower and stopped at a higher cost).

    Args:
        problem: The problem.
        budget_s: Wall-time budget; when it is used up the solve stops at the lowest-cost
            point evaluated so far (trf is monotone, so that is its current iterate).

    Returns:
        The row; iterations = function evaluations - 1 (trial steps), linear solves = LSMR
        solves (one per Jacobian evaluation).
    """
    t0 = time.perf_counter()
    sp = ScipyXyzProblem(problem)
    setup = time.perf_counter() - t0
    best: dict[str, Any] = {'cost': math.inf, 'x': sp.x0, 'nfev': 0, 'njev': 0}

    def fun(x: np.ndarray) -> np.ndarray:
        if time.perf_counter() - t0 > budget_s:
            raise _BudgetExceeded
        r = sp.fun(x)
        best['nfev'] += 1
        cost = float(r @ r)
        if cost < best['cost']:
            best.update(cost=cost, x=x.copy())
        return r

    def jac(x: np.ndarray) -> scipy.sparse.csr_matrix:
        best['njev'] += 1
        return sp.jac(x)

    t0 = time.perf_counter()
    try:
        res = scipy.optimize.least_squares(fun, sp.x0, jac=jac, method='trf', x_scale='jac',
                                           tr_solver='lsmr',
                                           tr_options={'maxiter': LSMR_MAXITER},
                                           ftol=1e-6, xtol=1e-8, gtol=1e-10)
        x, nfev, njev = res.x, int(res.nfev), int(res.njev)
        status = {0: 'max_nfev', 1: 'gtol', 2: 'ftol', 3: 'xtol', 4: 'ftol+xtol'}
        term = str(status.get(res.status, res.status))
    except _BudgetExceeded:
        x, nfev, njev = best['x'], best['nfev'], best['njev']
        term = f'STOPPED at the {budget_s:g} s budget, not converged'
    seconds = time.perf_counter() - t0
    _, R, C, X = sp.unpack(x)
    initial = rms_px(problem, sp.R0, np.asarray(problem.centers_w), np.asarray(problem.points_w))
    note = f'{term}, set-up {setup:.2f} s excluded'
    return Row(f'scipy trf (lsmr<={LSMR_MAXITER})', nfev - 1, njev, seconds, initial,
               rms_px(problem, R, C, X), note, (R, C, X))


# --- Ceres ------------------------------------------------------------------------------------


def ceres_versions() -> str | None:
    """Return the pyceres / pycolmap / Ceres versions, or None if either is missing."""
    try:
        import pyceres
        import pycolmap
    except ImportError:
        return None
    return (f'pyceres {getattr(pyceres, "__version__", "?")}, pycolmap {pycolmap.__version__}, '
            f'Ceres {getattr(pyceres, "__ceres_version__", "?")}')


def build_colmap(problem: BAProblem) -> Any:
    """Return a pycolmap Reconstruction holding the problem's start (ids = index + 1).

    Args:
        problem: The problem.

    Returns:
        The reconstruction: one RADIAL (or OPENCV if fx != fy) camera with a trivial rig and
        frame per pose, each image's keypoints its observations, one 3-D point per feature.
    """
    import pycolmap

    rec = pycolmap.Reconstruction()
    obs, intr = problem.obs, problem.intrinsics
    counts = np.bincount(obs.cam_idx, minlength=problem.n_cams)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    order = np.argsort(obs.cam_idx, kind='stable')
    point2d_idx = np.empty(problem.n_obs, dtype=np.int64)
    point2d_idx[order] = np.arange(problem.n_obs) - np.repeat(starts, counts)
    for i in range(problem.n_cams):
        fx, fy, cx, cy = (float(v[i]) for v in (intr.fx, intr.fy, intr.cx, intr.cy))
        k1, k2 = float(intr.k1[i]), float(intr.k2[i])
        kp = np.ascontiguousarray(obs.pixels[order[starts[i]:starts[i] + counts[i]]])
        span = np.max(np.abs(kp - [cx, cy]), axis=0, initial=1.0) if kp.size else [1.0, 1.0]
        size = {'width': int(max(2 * cx, 2 * span[0])) + 2,
                'height': int(max(2 * cy, 2 * span[1])) + 2}
        if fx == fy:
            cam = pycolmap.Camera(model='RADIAL', params=[fx, cx, cy, k1, k2], camera_id=i + 1,
                                  **size)
        else:
            cam = pycolmap.Camera(model='OPENCV', params=[fx, fy, cx, cy, k1, k2, 0.0, 0.0],
                                  camera_id=i + 1, **size)
        rec.add_camera_with_trivial_rig(cam)
        R_cw = np.asarray(problem.R_wc[i]).T
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(R_cw), -R_cw @ problem.centers_w[i])
        image = pycolmap.Image(name=f'{i}', keypoints=kp, camera_id=i + 1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pose)
    offsets = problem.feature_offsets()
    image_ids = (obs.cam_idx + 1).tolist()
    p2d = point2d_idx.tolist()
    for j in range(problem.n_feats):
        track = pycolmap.Track([pycolmap.TrackElement(image_ids[k], p2d[k])
                                for k in range(offsets[j], offsets[j + 1])])
        rec.add_point3D(problem.points_w[j], track)
    return rec


def run_ceres(problem: BAProblem, threads: int) -> Row:
    """Solve with C++ Ceres: sparse-Schur Levenberg-Marquardt on COLMAP's cost functions.

    Args:
        problem: The problem.
        threads: Ceres' ``num_threads``.

    Returns:
        The row (seconds = wall time of ``pyceres.solve``, including Ceres' preprocessing).
    """
    import pyceres
    import pycolmap

    t0 = time.perf_counter()
    rec = build_colmap(problem)
    options = pycolmap.BundleAdjustmentOptions(
        refine_focal_length=False, refine_principal_point=False, refine_extra_params=False,
        print_summary=False)
    config = pycolmap.BundleAdjustmentConfig()
    for i in range(problem.n_cams):
        config.add_image(i + 1)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.UNSPECIFIED)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(options, config, rec)
    setup = time.perf_counter() - t0
    solver_options = pyceres.SolverOptions()  # Ceres' defaults: the engine's tolerances
    solver_options.minimizer_type = pyceres.MinimizerType.TRUST_REGION
    solver_options.trust_region_strategy_type = pyceres.TrustRegionStrategyType.LEVENBERG_MARQUARDT
    solver_options.linear_solver_type = pyceres.LinearSolverType.SPARSE_SCHUR
    solver_options.num_threads = threads
    summary = pyceres.SolverSummary()
    t0 = time.perf_counter()
    pyceres.solve(solver_options, adjuster.problem, summary)
    seconds = time.perf_counter() - t0
    R = np.empty((problem.n_cams, 3, 3))
    C = np.empty((problem.n_cams, 3))
    for i in range(problem.n_cams):
        cam_from_world = rec.image(i + 1).cam_from_world()
        R_cw = cam_from_world.rotation.matrix()
        R[i] = R_cw.T
        C[i] = -R_cw.T @ cam_from_world.translation
    X = np.array([rec.point3D(j + 1).xyz for j in range(problem.n_feats)])
    initial = rms_px(problem, np.asarray(problem.R_wc), np.asarray(problem.centers_w),
                     np.asarray(problem.points_w))
    term = str(summary.termination_type).rsplit('.', maxsplit=1)[-1].lower()
    note = (f'{term}, {summary.num_threads_used} thr, '
            f'{str(summary.sparse_linear_algebra_library_type).rsplit(".", maxsplit=1)[-1]}, '
            f'set-up {setup:.2f} s excluded')
    return Row(f'Ceres LM sparse-Schur ({threads} thr)',
               summary.num_successful_steps + summary.num_unsuccessful_steps,
               summary.num_linear_solves, seconds, initial, rms_px(problem, R, C, X), note,
               (R, C, X))


# --- report -----------------------------------------------------------------------------------


#: Memory written once before the first timed row (bytes).
TOUCH_BYTES = 2 << 30


def warm_up() -> None:
    """Solve a tiny scene once per parameterization and write 2 GB once before timing.

    One-time import and first-call costs of numpy / scipy are then not charged to the first
    timed solve (Ceres' set-up is excluded too). The first write to memory a process has not
    used yet is slow (on a virtual machine, much slower), and the rows that come later reuse
    what the first one paid for: written here once, it is charged to no row.
    """
    scene = table3_scene(seed=0)
    for param, solver in (('pmba', 'dogleg'), ('xyz', 'lm')):
        solve(scene.start, SolveOptions(param=param, solver=solver, max_iterations=3))
    np.ones(TOUCH_BYTES // 8)


def print_environment(user_env: dict[str, str]) -> None:
    """Print the command line, versions, BLAS and thread settings (``user_env``: as started)."""
    print('command:', shlex.join([sys.executable, *sys.argv]))
    print(f'python {platform.python_version()} on {platform.machine()}, '
          f'{os.cpu_count()} CPUs; numpy {np.__version__}, scipy {scipy.__version__}')
    try:
        blas = np.show_config(mode='dicts')['Build Dependencies']['blas']
        print(f'numpy BLAS: {blas.get("name")} {blas.get("version", "")}')
    except (KeyError, TypeError, ValueError) as err:
        print(f'numpy BLAS: unknown ({err})')
    print('thread variables set by the user:', user_env or 'none')
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        print('threadpoolctl: not installed (thread pools not listed)')
    else:
        for pool in threadpool_info():
            print(f'threadpool: {pool.get("internal_api")} {pool.get("version")} '
                  f'num_threads={pool.get("num_threads")} ({pool.get("filepath")})')
    print('ceres:', ceres_versions() or 'pyceres/pycolmap not installed: Ceres rows skipped')
    print()


def print_table(name: str, problem: BAProblem, rows: list[Row], ref: Row | None) -> None:
    """Print one dataset's table.

    Args:
        name: Dataset label.
        problem: The problem (sizes in the title).
        rows: Results.
        ref: The row whose wall time is the ratio's denominator (Ceres, --threads threads).
    """
    print(f'== {name}: {problem.n_cams} cameras, {problem.n_feats} points, '
          f'{problem.n_obs} observations ==')
    header = (f'{"method":<32}{"iters":>6}{"solves":>7}{"seconds":>10}{"s/iter":>9}'
              f'{"rms0 px":>10}{"rms px":>9}{"x Ceres":>9}{"peak MB":>9}  note')
    print(header)
    print('-' * len(header))
    for r in rows:
        per_iter = r.seconds / r.iterations if r.iterations else math.nan
        ratio = r.seconds / ref.seconds if ref is not None and ref.seconds > 0 else math.nan
        print(f'{r.method:<32}{r.iterations:>6}{r.linear_solves:>7}{r.seconds:>10.3f}'
              f'{per_iter:>9.4f}{r.initial_rms:>10.4f}{r.final_rms:>9.4f}{ratio:>9.2f}'
              f'{r.peak_rss_mb:>9.0f}  {r.note}')


def sanity_check(problem: BAProblem, ceres: Row | None, xyz: Row | None) -> bool:
    """Print how close Ceres' final RMS is to XYZ-LM's; return False if not within tolerance.

    Args:
        problem: The problem.
        ceres: The Ceres row.
        xyz: The XYZ-LM row.

    Returns:
        True if both are present and their final RMS agree within ``RMS_TOLERANCE`` over all
        observations or over the observations in front of their cameras, or if a row is
        missing.
    """
    if ceres is None or xyz is None or ceres.solution is None or xyz.solution is None:
        return True
    behind0 = int(np.sum(reprojection_errors(problem, np.asarray(problem.R_wc),
                                             np.asarray(problem.centers_w),
                                             np.asarray(problem.points_w))[1] <= 0))
    all_c, all_x = ceres.final_rms, xyz.final_rms
    front_c = rms_px(problem, *ceres.solution, front_only=True)
    front_x = rms_px(problem, *xyz.solution, front_only=True)
    rel_all = abs(all_c - all_x) / all_x
    rel_front = abs(front_c - front_x) / front_x
    ok = min(rel_all, rel_front) <= RMS_TOLERANCE
    print(f'sanity: final RMS Ceres vs XYZ-LM: all observations {all_c:.4f} vs {all_x:.4f} '
          f'({100 * rel_all:+.2f} %), in front of the camera {front_c:.4f} vs {front_x:.4f} '
          f'({100 * rel_front:+.2f} %): {"OK" if ok else "MISMATCH"}')
    if behind0:
        print(f'        {behind0} observations start behind their camera: COLMAP gives them a'
              ' zero residual, the engine and scipy project them (BAL convention)')
    return ok


def load(name: str) -> tuple[BAProblem | None, str]:
    """Return a dataset's problem (or None) and a description / skip note."""
    if name == 'ladybug':
        if not LADYBUG.exists():
            return None, f'skipped ladybug: {LADYBUG} not found'
        return read_bal(LADYBUG), f'BAL Ladybug-49 ({LADYBUG.name})'
    if name == 'trafalgar':
        if not TRAFALGAR.exists():
            return None, f'skipped trafalgar: {TRAFALGAR} not found'
        return read_bal(TRAFALGAR), f'BAL Trafalgar-21 ({TRAFALGAR.name})'
    if name == 'large':
        return (synthetic_large(seed=0, n_cams=400, n_points=21300).start,
                'synthetic_large(seed=0, 400 cams, 21300 points)')
    return synthetic_large(seed=0).start, 'synthetic_large(seed=0, 100 cams, 20000 points)'


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print one table per dataset.

    Returns:
        0, or 1 if a sanity check failed.
    """
    user_env = {k: os.environ[k] for k in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS',
                                           'MKL_NUM_THREADS') if k in os.environ}
    tune_process()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--datasets', default=','.join(DATASETS),
                        help='comma-separated subset of: '
                        + ', '.join(DATASETS + MORE_DATASETS))
    parser.add_argument('--methods', default=','.join(METHODS),
                        help='comma-separated subset of: ' + ', '.join(METHODS))
    parser.add_argument('--threads', type=int, default=1,
                        help="Ceres' num_threads of the reference row (a 2-thread row is added)")
    parser.add_argument('--scipy-budget-s', type=float, default=600.0,
                        help='wall-time budget of the scipy solve per dataset (s)')
    parser.add_argument('--engine', choices=['auto', 'numpy', 'compiled'], default='auto',
                        help="the engine rows' SolveOptions.engine (numpy or numba loops)")
    parser.add_argument('--quiet', action='store_true', help='print only the tables')
    args = parser.parse_args(argv)
    datasets = [d for d in args.datasets.split(',') if d]
    methods = [m for m in args.methods.split(',') if m]
    bad = (sorted(set(datasets) - set(DATASETS + MORE_DATASETS))
           + sorted(set(methods) - set(METHODS)))
    if bad or args.threads < 1:
        parser.error(f'unknown datasets/methods {bad}' if bad else '--threads must be >= 1')
    have_ceres = ceres_versions() is not None

    def log(msg: str) -> None:
        if not args.quiet:
            print(msg, flush=True)

    print_environment(user_env)
    warm_up()
    ok = True
    for name in datasets:
        problem, label = load(name)
        if problem is None:
            print(label + '\n')
            continue
        log(f'[{name}] {label}')
        rows: list[Row] = []
        xyz_row = ceres_row = None
        if 'pmba' in methods:
            # As users run it (every core on a large problem), and on one thread.
            for limit in sorted({chunks.threads_for(problem.n_obs), 1}, reverse=True):
                log(f'[{name}] PMBA-Dogleg ({limit} thr) ...')
                chunks.set_max_threads(limit)
                try:
                    rows.append(measured(partial(run_engine, problem,
                                                 f'PMBA-Dogleg ({limit} thr)',
                                                 SolveOptions(engine=args.engine))))
                finally:
                    chunks.set_max_threads(None)
        if 'xyz' in methods:
            log(f'[{name}] XYZ-LM ...')
            xyz_row = measured(partial(run_engine, problem, 'XYZ-LM (engine)',
                                       SolveOptions(param='xyz', solver='lm',
                                                    engine=args.engine)))
            rows.append(xyz_row)
        if 'scipy' in methods:
            log(f'[{name}] scipy least_squares trf ...')
            rows.append(measured(partial(run_scipy, problem, args.scipy_budget_s)))
        notes = []
        if 'ceres' in methods and have_ceres:
            for threads in sorted({args.threads, 2}):
                log(f'[{name}] Ceres ({threads} threads) ...')
                row = measured(partial(run_ceres, problem, threads))
                rows.append(row)
                if threads == args.threads:
                    ceres_row = row
        elif 'ceres' in methods:
            notes.append('Ceres skipped: pyceres/pycolmap not installed')
        print_table(label, problem, rows, ceres_row)
        for note in notes:
            print(note)
        ok &= sanity_check(problem, ceres_row, xyz_row)
        print()
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
