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
"""One trust-region step of :func:`pmba_ros.core.solve.solve`.

The scaled normal equations at a state, and the state a step leads to, its rays kept towards
their bearings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import dogleg, so3
from pmba_ros.core import normal_equations as ne
from pmba_ros.core.loss import Loss
from pmba_ros.core.models import Evaluation, Model
from pmba_ros.core.pose_prior import PriorAssembly, PriorEvaluation, RelativePosePrior
from pmba_ros.core.refit import refit_features


@dataclass
class State:
    """A solver state: poses, features, and their cost and residuals."""

    R_wc: FloatArray
    centers_w: FloatArray
    feats: Any
    cost: float
    evaluation: Evaluation
    prior: PriorEvaluation | None = None


class Linearized:
    """Scaled normal equations at one state, and what dogleg retries reuse."""

    def __init__(self, model: Model[Any], structure: ne.SchurStructure, state: State,
                 loss: Loss, loss_scale: float, jacobi: bool, col_mask: np.ndarray,
                 prior: PriorAssembly | None = None) -> None:
        """Linearize ``model`` at ``state`` (with the prior's factors) and scale the system."""
        lin = model.linearize(state.R_wc, state.centers_w, state.feats, state.evaluation)
        if loss is not Loss.NONE:
            lin = model.engine.robust_rows(lin, loss, loss_scale)   # the rows are new
        eqs = ne.assemble(structure, lin)
        low_rank = None
        if prior is not None and state.prior is not None:
            eqs = prior.add_to(eqs, state.prior)
            low_rank = prior.low_rank(state.prior)
        scaled = model.engine.jacobi_scale(structure, eqs, col_mask, jacobi)
        self.eqs, self.c_pose, self.c_feat = scaled.eqs, scaled.c_pose, scaled.c_feat
        self.low_rank = None if low_rank is None else (   # in the scaled system's x = d / c
            low_rank[0] * (scaled.c_pose * col_mask).reshape(-1), low_rank[1])
        self.D_pose, self.D_feat = scaled.D_pose, scaled.D_feat
        self.g_pose, self.g_feat = scaled.g_pose, scaled.g_feat
        self.gradient_max = scaled.gradient_max
        self.prior_evaluation = state.prior
        self.col_mask = col_mask
        self.structure = structure
        self.gn: tuple[np.ndarray, np.ndarray] | None = None
        self.factor: FloatArray | None = None
        self._cauchy: float | None = None

    def cauchy_alpha(self) -> float:
        """Return the Cauchy step length of this linearization (computed once)."""
        if self._cauchy is None:
            g = np.concatenate([self.g_pose.ravel(), self.g_feat.ravel()])
            x_pose = np.where(self.col_mask, self.g_pose / self.D_pose, 0.0)
            Jg_sq = self._quadratic_form(x_pose, self.g_feat / self.D_feat)
            self._cauchy = dogleg.cauchy_alpha(g, Jg_sq)
        return self._cauchy

    def to_delta(self, z_pose: FloatArray, z_feat: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Map a scaled-space step z to parameter increments delta = c * z / D."""
        return (np.where(self.col_mask, z_pose / self.D_pose * self.c_pose, 0.0),
                z_feat / self.D_feat * self.c_feat)

    def model_change(self, d_pose: FloatArray, d_feat: FloatArray) -> float:
        """Return the predicted cost decrease -(J d)^T (r + J d / 2) = -(g^T d + d^T H d / 2).

        Evaluated on the normal equations of the scaled Jacobian, x = d / c.
        """
        x_pose, x_feat = d_pose / self.c_pose, d_feat / self.c_feat
        g_x = sum_products(self.eqs.g_pose, x_pose, self.eqs.g_feat, x_feat)
        return -(g_x + 0.5 * self._quadratic_form(x_pose, x_feat))

    def _quadratic_form(self, x_pose: FloatArray, x_feat: FloatArray) -> float:
        """Return x^T H x of the scaled system, less the window scales' curvature."""
        quad = ne.quadratic_form(self.structure, self.eqs, x_pose, x_feat)
        if self.low_rank is not None:
            quad -= float(add((self.low_rank[0] @ x_pose.reshape(-1)) ** 2 / self.low_rank[1]))
        return quad

    def solve(self, mu: float) -> tuple[FloatArray, FloatArray]:
        """Solve (J~^T J~ + mu D^2) y = -J~^T r and return the scaled step b = D y."""
        y_pose, y_feat, factor = ne.solve_schur_factored(
            self.structure, self.eqs, mu * self.D_pose ** 2, mu * self.D_feat ** 2, self.col_mask,
            self.low_rank)
        if mu == dogleg.MIN_MU:   # S itself, to rounding: a covariance needs no new one
            self.factor = factor
        return y_pose * self.D_pose, y_feat * self.D_feat

    def prior_leverage(self, factors: RelativePosePrior, free_block: np.ndarray) -> FloatArray:
        """Return the prior's hat-matrix blocks (Sigma: C Sigma_y C, y = d/c); NaN if singular."""
        ev = self.prior_evaluation
        try:
            cov = ne.pose_covariance(self.structure, self.eqs, dogleg.MIN_MU * self.D_feat ** 2,
                                     self.col_mask, self.factor)
        except ne.ReducedSystemError:
            ev = None
        if ev is None:
            return np.full((len(factors), 6, 6), np.nan)
        if self.low_rank is not None:   # the inverse of S less u^T diag(1/d) u (Woodbury)
            u, Z = self.low_rank[0], cov @ self.low_rank[0].T
            cov = cov + Z @ np.linalg.solve(np.diag(self.low_rank[1]) - u @ Z, Z.T)
        c = self.c_pose.reshape(-1)
        return factors.hat_blocks(ev, cov * c[:, None] * c[None, :], free_block)


def retract(model: Model[Any], state: State, free_block: np.ndarray, d_pose: FloatArray,
            d_feat: FloatArray) -> tuple[FloatArray, FloatArray, Any]:
    """Return the poses and features of ``state`` moved by a step (held poses stay)."""
    R = state.R_wc.copy()
    P = state.centers_w.copy()
    free = free_block >= 0
    blocks = free_block[free]
    R[free] = R[free] @ so3.exp(d_pose[blocks, :3])
    P[free] = P[free] + d_pose[blocks, 3:]
    return R, P, model.retract(state.feats, d_feat)


def trial_state(model: Model[Any], lin: Linearized, state: State, free_block: np.ndarray,
                d_pose: FloatArray, d_feat: FloatArray, model_change: float,
                evaluate: Callable[[FloatArray, FloatArray, Any], State],
                loss: Loss, loss_scale: float) -> tuple[State, float]:
    """Return the state a step leads to and the decrease the linear model predicts for it.

    ``model_change`` is the step's predicted decrease, changed here if the step is.

    Where the step turns a ray away from its bearing, the features' own steps that do are
    halved (:meth:`~pmba_ros.core.models.Model.halve_turning_steps`); the features whose
    rays the poses' step turns are then fitted to the new poses
    (:func:`~pmba_ros.core.refit.refit_features`), so that the trust region judges the
    poses' step, not a linearization of those features that no longer holds.
    """
    trial = evaluate(*retract(model, state, free_block, d_pose, d_feat))
    if not model.turned_away(state.evaluation, trial.evaluation).size:
        return trial, model_change
    halved = model.halve_turning_steps(state.R_wc, state.centers_w, state.feats,
                                       state.evaluation, d_feat)
    if halved is not None:
        model_change = lin.model_change(d_pose, halved)
        trial = evaluate(*retract(model, state, free_block, d_pose, halved))
    turned = model.turned_away(state.evaluation, trial.evaluation)
    if turned.size:
        trial = evaluate(trial.R_wc, trial.centers_w,
                         refit_features(model, trial.R_wc, trial.centers_w, trial.feats,
                                        turned, loss, loss_scale))
    return trial, model_change


#: np.sum(x) is this reduction behind a generic wrapper: the same sum, for less.
add = np.add.reduce


def sum_products(a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray) -> float:
    """Return np.sum(a * b) + np.sum(c * d) (x ** 2 is x * x: squared norms too)."""
    return float(add(a * b, axis=None) + add(c * d, axis=None))
