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
"""Nonlinear position-only refinement with rotations and features frozen (PMBA eq. 13).

Minimises sum_k rho(||xi(N-bar_k(P)) - r_k||^2) over the camera centres P, with the linearised
rays N-bar_k of eq. (12) (see :mod:`pmba_ros.init.cls`) and a Cauchy loss
rho(s) = f^2 log(1 + s / f^2). The solver is a vectorised Levenberg-Marquardt with iteratively
reweighted normal equations: the normal matrix is assembled in its non-zero 3x3 blocks
(camera pairs that share a feature, :mod:`pmba_ros.init.normal_blocks`) and factored dense
for small problems, sparse (SuperLU) for large ones.

Gauge: the cost is invariant to translation and scale of P (N-bar is linear and homogeneous),
so P_root is held fixed and so is the largest coordinate of P_k - P_root of one camera k
(ParallaxBA's rule, pmba.md §2).

==========  ============  ==========  ===================================================
paper       code          shape       meaning
==========  ============  ==========  ===================================================
N-bar_k     N             (K,3)       linearised ray, eq. (12)
e_k         e             (K,3)       xi(N-bar_k) - r_k, eq. (13)
J_N         J_N           (K,3,3)     (I - N^ N^T) / |N|
f           f_scale       (K,) or 1   Cauchy scale (ray units, ~ px / focal)
==========  ============  ==========  ===================================================
"""

from __future__ import annotations

from dataclasses import dataclass
import logging

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray
from pmba_ros.core.compiled import linear_rays as compiled_linear_rays
from pmba_ros.core.engine import EngineName, resolve
from pmba_ros.init import normal_blocks
from pmba_ros.init.cls import LinearRays

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class NlsResult:
    """Result of the position-only NLS (eq. 13).

    Attributes:
        centers_w: Camera centres, shape (M, 3).
        initial_cost: Robust cost 1/2 sum rho(|e|^2) at the start.
        final_cost: Robust cost at the end.
        residual: RMS of |e_k| (unweighted) at the end (ray units).
        iterations: LM iterations.
        converged: True if a tolerance was met before the iteration limit.
    """

    centers_w: FloatArray
    initial_cost: float
    final_cost: float
    residual: float
    iterations: int
    converged: bool


def _cauchy(sq: FloatArray, f_scale: float | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return rho(s) and rho'(s) of the Cauchy loss for squared norms s."""
    f2 = f_scale * f_scale
    z = sq / f2
    return f2 * np.log1p(z), 1.0 / (1.0 + z)


def _errors(lin: LinearRays, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return N-bar (K, 3) and e = xi(N-bar) - r (K, 3), eq. (13)."""
    N = lin.evaluate(P, EngineName.NUMPY)
    norm = np.linalg.norm(N, axis=1, keepdims=True)
    return N, N / np.maximum(norm, 1e-300) - lin.rays  # eq. (13)


def robust_cost(lin: LinearRays, P: FloatArray, f_scale: float | FloatArray,
                weights: FloatArray | None = None) -> float:
    """Return 1/2 sum_k w_k rho(||xi(N-bar_k(P)) - r_k||^2) (eq. 13 with a Cauchy loss)."""
    return _evaluate(lin, P, f_scale, 1.0 if weights is None else weights)[0]


def _evaluate(lin: LinearRays, P: FloatArray, f_scale: float | FloatArray,
              w: float | FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """Return the robust cost, N-bar and e at P (the next linearization reuses them)."""
    N, e = _errors(lin, P)
    rho, _ = _cauchy(np.sum(e * e, axis=1), f_scale)
    return 0.5 * float(np.sum(w * rho)), N, e


def _normal_blocks(lin: LinearRays, N: FloatArray, e: FloatArray,
                   f_scale: float | FloatArray, w: FloatArray, n_cams: int,
                   ) -> tuple[FloatArray, FloatArray]:
    """Return the IRLS normal matrix's blocks (B, 3, 3) and gradient (3M,) of eq. (13)."""
    norm = np.maximum(np.linalg.norm(N, axis=1), 1e-150)
    Nh = N / norm[:, None]
    # J_N = (I - N^ N^T) / |N| is symmetric, J_N^T J_N = (I - N^ N^T) / |N|^2.
    proj = np.eye(3)[None] - Nh[:, :, None] * Nh[:, None, :]
    _, drho = _cauchy(np.sum(e * e, axis=1), f_scale)
    # DEVIATION(eq. 13): Cauchy-weighted (IRLS) instead of plain L2 (pmba.md §8 item 5).
    wk = w * drho
    # Unused observations (weight 0) may have N = 0: keep their 0 * inf out.
    w_n = np.where(wk > 0.0, wk / norm, 0.0)
    blocks = lin.normal_blocks((w_n / norm)[:, None, None] * proj, EngineName.NUMPY)
    y = w_n[:, None] * np.einsum('kij,kj->ki', proj, e)
    return blocks, lin.gradient(y, n_cams, EngineName.NUMPY)


class _Compiled:
    """The compiled loops of the NLS (:mod:`pmba_ros.core.compiled.linear_rays`).

    They give :func:`_evaluate` and :func:`_normal_blocks` to rounding, in one pass over
    the observations instead of a few dozen numpy calls.
    """

    def __init__(self, lin: LinearRays, f_scale: float | FloatArray, w: FloatArray) -> None:
        f = np.asarray(f_scale, dtype=float)
        self.lin = lin
        # Writable copies: the loops are compiled (and warmed up) for writable arrays only.
        self.f2 = np.broadcast_to(f * f, (lin.n_obs,)).copy()
        self.w = np.array(w, dtype=float)

    def evaluate(self, P: FloatArray) -> tuple[float, FloatArray, FloatArray]:
        """Return :func:`_evaluate` at P."""
        lin = self.lin
        N, e, w_rho = compiled_linear_rays.ray_errors(
            lin.cam, lin.feat, lin.assoc, lin.main, lin.anchor_coeff, lin.sin_t, lin.rays, P,
            self.f2, self.w)
        return 0.5 * float(np.sum(w_rho)), N, e

    def normal_blocks(self, N: FloatArray, e: FloatArray, n_cams: int,
                      ) -> tuple[FloatArray, FloatArray]:
        """Return :func:`_normal_blocks` at N-bar, e."""
        lin = self.lin
        A, y = compiled_linear_rays.nls_weights(N, e, self.f2, self.w)
        blocks = lin.normal_blocks(A, EngineName.COMPILED)
        g = compiled_linear_rays.ray_gradient(lin.cam, lin.feat, lin.assoc, lin.main,
                                              lin.anchor_coeff, lin.sin_t, y, n_cams)
        return blocks, g


def gauge_coordinate(centers_w: FloatArray, root: int, cameras: BoolArray) -> tuple[int, int]:
    """Return (camera, axis) of the coordinate fixed for the scale: the largest |P_k - P_root|."""
    d = np.abs(centers_w - centers_w[root])
    d[~cameras] = -1.0
    d[root] = -1.0
    k, axis = np.unravel_index(int(np.argmax(d)), d.shape)
    return int(k), int(axis)


def solve_nls(lin: LinearRays, centers_w: FloatArray, root: int, *,
              f_scale: float | FloatArray,
              weights: FloatArray | None = None, cameras: BoolArray | None = None,
              max_iterations: int = 50, function_tolerance: float = 1e-5,
              step_tolerance: float = 1e-10,
              engine: EngineName | str = EngineName.AUTO,
              sparse: bool | None = None) -> NlsResult:
    """Refine camera centres by eq. (13) with a Cauchy loss (LM on the normal equations).

    Args:
        lin: Linearised rays (eq. 12) of all observations.
        centers_w: Starting centres (M, 3), e.g. from the CLS (eq. 14).
        root: Reference camera (held fixed).
        f_scale: Cauchy scale in ray units (about 3 px / focal length), one for all
            observations or one each (K,): a pixel scale divided by each observer's focal
            length, so that cameras of different focal lengths are judged in their own
            pixels.
        weights: Optional observation weights (K,).
        cameras: Optional mask (M,) of cameras to solve for (others are held fixed).
        max_iterations: LM iteration limit.
        function_tolerance: Stop when the relative cost decrease is below this.
        step_tolerance: Stop when the relative step norm is below this.
        engine: The compiled loops (``'auto'``: where numba runs) or this module's numpy code.
        sparse: Factor the normal matrix sparse (True), dense (False), or by the number of
            unknowns and blocks (None, :func:`pmba_ros.init.normal_blocks.use_sparse`).

    Returns:
        The refined centres and diagnostics.

    References:
        PMBA eq. (13). DEVIATION(eq. 13): a Cauchy loss instead of plain L2, because frozen
        noisy theta-bar of low-parallax features act as outliers (pmba.md §4.7, §8 item 5).
    """
    M = centers_w.shape[0]
    K = lin.n_obs
    w = np.ones(K) if weights is None else np.asarray(weights, dtype=float)
    cams = np.ones(M, dtype=bool) if cameras is None else np.asarray(cameras, dtype=bool)
    P = np.array(centers_w, dtype=float)
    free = np.repeat(cams, 3)
    free[3 * root:3 * root + 3] = False
    k_fix, axis_fix = gauge_coordinate(P, root, cams)
    free[3 * k_fix + axis_fix] = False
    fidx = np.flatnonzero(free)
    layout = (lin.pattern.sparse_layout(M, fidx)
              if normal_blocks.use_sparse(fidx.size, lin.pattern.n_blocks, sparse) else None)
    fast = _Compiled(lin, f_scale, w) if resolve(engine).name is EngineName.COMPILED else None
    cost, N, e = fast.evaluate(P) if fast is not None else _evaluate(lin, P, f_scale, w)
    initial_cost = cost
    lam = 1e-4
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        blocks, g_all = (fast.normal_blocks(N, e, M) if fast is not None
                         else _normal_blocks(lin, N, e, f_scale, w, M))
        H = (layout.matrix(blocks) if layout is not None
             else lin.pattern.dense(blocks, M)[np.ix_(fidx, fidx)])
        g = g_all[fidx]
        d = H.diagonal()
        diag = np.maximum(d, 1e-12 * max(float(np.max(d)), 1e-300))
        accepted = False
        while lam < 1e12:
            try:
                step = -normal_blocks.solve_spd(H, lam * diag, g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            P_new = P.copy()
            P_new.reshape(-1)[fidx] += step
            new_cost, N_new, e_new = (fast.evaluate(P_new) if fast is not None
                                      else _evaluate(lin, P_new, f_scale, w))
            if new_cost < cost:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            converged = True
            break
        logger.debug('NLS it %d cost %.6e lam %.1e', it, new_cost, lam)
        rel_dec = (cost - new_cost) / max(cost, 1e-300)
        rel_step = float(np.linalg.norm(step)) / max(float(np.linalg.norm(P[cams])), 1e-300)
        P, cost, N, e = P_new, new_cost, N_new, e_new
        lam = max(lam / 10.0, 1e-12)
        if rel_dec < function_tolerance or rel_step < step_tolerance:
            converged = True
            break
    used = w > 0
    residual = float(np.sqrt(np.mean(np.sum(e[used] ** 2, axis=1)))) if used.any() else 0.0
    logger.info('NLS: cost %.4e -> %.4e in %d iterations (rms %.3e)', initial_cost, cost,
                it, residual)
    return NlsResult(P, initial_cost, cost, residual, it, converged)
