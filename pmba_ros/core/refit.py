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
"""Features re-fitted to poses held: damped Gauss-Newton on each feature's own observations.

A long step of the poses can carry an observer past a near feature: the feature, moved
with its anchors, ends behind that observer, and the one ray's error, at its bound, outweighs
what the step gains everywhere else (:meth:`~pmba_ros.core.models.Model.turned_away`).
The step itself may be good; the feature's linearized step is not. Fitting such features
anew to the trial's poses (each a 3-parameter problem, the poses held) judges the poses'
step on its own merit, as embedded point iterations do (Jeong et al., "Pushing the
envelope of modern methods for bundle adjustment", 2012).
"""

from __future__ import annotations

from dataclasses import fields
from typing import cast

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core.loss import Loss, rho
from pmba_ros.core.models import F, Model
from pmba_ros.core.problem import take_features

REFIT_ITERATIONS = 10
"""Damped Gauss-Newton iterations of a re-fit (a trial's features start near their fit)."""

_DAMPING = (1e-4, 10.0, 1e8)
"""Levenberg-Marquardt damping per feature: start, factor on a failed step, most."""


def refit_features(model: Model[F], R_wc: FloatArray, centers_w: FloatArray, feats: F,
                   which: IntArray, loss: Loss, loss_scale: float,
                   iterations: int = REFIT_ITERATIONS) -> F:
    """Return ``feats`` with the features ``which`` (ascending) fitted to the poses held.

    Each moves only where its own robust cost falls, for up to ``iterations`` damped
    Gauss-Newton steps; the other features are untouched.
    """
    sub = model.restricted(which)
    starts = sub.problem.feature_offsets()[:-1]
    fit = cast(F, take_features(feats, which))   # the same type as feats

    def costs(state: F) -> FloatArray:
        res = sub.evaluate(R_wc, centers_w, state).residuals
        value, _ = rho(np.add.reduce(res * res, axis=1), loss, loss_scale)
        out: FloatArray = np.add.reduceat(value, starts)
        return np.where(np.isfinite(out), out, np.inf)

    cost = costs(fit)
    damping = np.full(which.size, _DAMPING[0])
    for _ in range(iterations):
        lin = sub.linearize(R_wc, centers_w, fit)
        if loss is not Loss.NONE:
            lin = sub.engine.robust_rows(lin, loss, loss_scale)
        J, r = lin.J_feat, lin.residuals
        H = np.add.reduceat(np.einsum('kdi,kdj->kij', J, J), starts)
        g = np.add.reduceat(np.einsum('kdi,kd->ki', J, r), starts)
        diag = np.maximum(np.diagonal(H, axis1=1, axis2=2), 1e-12)
        A = H + (damping[:, None] * diag)[:, :, None] * np.eye(3)
        try:
            delta = -np.linalg.solve(A, g[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            break
        trial = sub.retract(fit, np.where(np.isfinite(delta), delta, 0.0))
        trial_cost = costs(trial)
        better = trial_cost < cost
        fit = _where(better, trial, fit)
        cost = np.where(better, trial_cost, cost)
        damping = np.clip(np.where(better, damping / _DAMPING[1], damping * _DAMPING[1]),
                          _DAMPING[0], _DAMPING[2])
    return _put(feats, which, fit)


def _where(mask: BoolArray, a: F, b: F) -> F:
    """Return per feature a where mask, else b."""
    columns = {}
    for f in fields(a):
        x, y = np.asarray(getattr(a, f.name)), np.asarray(getattr(b, f.name))
        columns[f.name] = np.where(mask.reshape((-1,) + (1,) * (x.ndim - 1)), x, y)
    return type(a)(**columns)


def _put(feats: F, which: IntArray, part: F) -> F:
    """Return feats with the features ``which`` replaced by ``part``."""
    columns = {}
    for f in fields(feats):
        column = np.array(getattr(feats, f.name))
        column[which] = getattr(part, f.name)
        columns[f.name] = column
    return type(feats)(**columns)
