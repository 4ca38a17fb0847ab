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
"""Relative-motion priors between pose pairs, added to the reduced camera system.

A front-end's keyframe-to-keyframe motion is precise locally (and metric for a VIO), where a
monocular window is weakest: its scale and, with distant structure, its positions along the
image plane. :class:`RelativePosePrior` holds weighted factors between poses a and b of a
problem (camera -> world rotations ``R`` and centres ``P``), with the residual

    r_rot   = w_rot   * log(R_ab^T R_a^T R_b)
    r_trans = W_trans (R_a^T (P_b - P_a) - t_ab)

for the measured relative rotation ``R_ab`` and translation ``t_ab`` (in the frame of a).
With a ``huber`` threshold k, a factor's cost is Huber's on the norm of its residual
(``|r|^2 / 2`` up to k, ``k |r| - k^2 / 2`` beyond) and it enters the normal equations with
the weight ``min(1, k / |r|)``: a measured step that is no motion pulls with a bounded force.
They touch only pose columns, so they enter the normal equations after the observations:
H_aa, H_bb, H_ab and the pose gradient of the covisible pairs (the Schur complement then
reduces the features as before). The pose increment is the solver's: ``R <- R Exp(dphi)``,
``P <- P + dP``, columns [dphi, dP].

A front-end's step errors are white noise plus a drift (a heading bias, a slowly changing
scale) that single steps do not show. Factors weighted to the white noise alone would carry
the drift into the map; :class:`StepChanges` holds the white noise's own information: factors
on the change of the step error from one step to the next (steps a -> b and b -> c),

    r_change = D (e_bc - e_ab),   e = [log(R_ab^T R_a^T R_b), R_a^T (P_b - P_a) - t_ab],

in which a drift that stays over a step cancels (``D``: a diagonal rotation weight and a 3x3
translation weight).

A stereo rig's map takes its scale from the baseline, yet its step lengths should keep the
front-end's proportions. :class:`WindowScale` measures part of each step's length against
the scale of its group of steps (a window), a nuisance set at every evaluation to the value
that fits the lengths best: the factors then hold the steps to each other and leave the
group's common scale to the vision.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
from typing import NamedTuple

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import so3
from pmba_ros.core.normal_equations import NormalEquations, SchurStructure
from pmba_ros.errors import ProblemError

#: np.sum(x) is this reduction behind a generic wrapper: the same sums, for less.
_add = np.add.reduce


def right_jacobian_inverse(omega: FloatArray) -> FloatArray:
    """Return J_r^-1 of SO(3) at rotation vectors ``omega`` (M, 3), shape (M, 3, 3)."""
    theta = np.linalg.norm(omega, axis=1)
    K = so3.hat(omega)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0,
                    1.0 / t ** 2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(np.where(small, 1.0, t))))
    return np.eye(3) + 0.5 * K + coef[:, None, None] * (K @ K)


@dataclass(frozen=True, eq=False)
class RelativePosePrior:
    """Weighted relative-motion factors between poses of one problem.

    Attributes:
        a: First pose of each factor, shape (M,).
        b: Second pose, shape (M,).
        R_ab: Measured relative rotation R_a^T R_b, shape (M, 3, 3).
        t_ab: Measured relative translation R_a^T (P_b - P_a), shape (M, 3).
        w_rot: Rotation weight (1 / sigma, rad^-1), shape (M,).
        W_trans: Translation weight (square-root information, in the frame of a),
            shape (M, 3, 3).
        huber: Threshold on the norm of a factor's (6) residuals beyond which its cost grows
            linearly (inf: least squares).
        changes: Factors on the change of the step error between consecutive factors
            (:class:`StepChanges`), with the same Huber threshold; None: none.
        window_scale: Where given, each step's length is measured partly against its
            group's own scale (:class:`WindowScale`), and ``t_ab`` holds the lengths at the
            reference scale.
    """

    a: IntArray
    b: IntArray
    R_ab: FloatArray
    t_ab: FloatArray
    w_rot: FloatArray
    W_trans: FloatArray
    huber: float = math.inf
    changes: StepChanges | None = None
    window_scale: WindowScale | None = None

    def __post_init__(self) -> None:
        """Check shapes and weights.

        Raises:
            ProblemError: On mismatched shapes, a factor of a pose with itself or weights
                that are negative or not finite.
        """
        M = self.a.shape[0]
        shapes = (self.b.shape == (M,) and self.R_ab.shape == (M, 3, 3)
                  and self.t_ab.shape == (M, 3) and self.w_rot.shape == (M,)
                  and self.W_trans.shape == (M, 3, 3))
        if not shapes:
            msg = ('pose prior: a, b, R_ab, t_ab, w_rot, W_trans need shapes M, M, (M, 3, 3), '
                   '(M, 3), M, (M, 3, 3)')
            raise ProblemError(msg)
        if np.any(self.a == self.b):
            msg = 'pose prior: a factor between a pose and itself'
            raise ProblemError(msg)
        if not (np.all(np.isfinite(self.w_rot)) and np.all(np.isfinite(self.W_trans))
                and np.all(self.w_rot >= 0)):
            msg = 'pose prior: weights must be finite (and w_rot >= 0)'
            raise ProblemError(msg)
        if not self.huber > 0:
            msg = f'pose prior: the Huber threshold must be > 0, got {self.huber}'
            raise ProblemError(msg)
        if self.changes is not None and not self.changes.fits(self):
            msg = 'pose prior: step changes must join consecutive factors (b of one = a of next)'
            raise ProblemError(msg)
        if self.window_scale is not None and not self.window_scale.fits(M):
            msg = ('pose prior: window_scale needs a share in [0, 1] and a group per factor, '
                   'finite')
            raise ProblemError(msg)

    def __len__(self) -> int:
        """Return the number of factors."""
        return int(self.a.shape[0])

    def evaluate(self, R: FloatArray, P: FloatArray) -> PriorEvaluation:
        """Return the factors' residuals and cost at poses (R, P), with what linearizing reuses."""
        Ra = R[self.a]
        RaT_Rb = np.swapaxes(Ra, 1, 2) @ R[self.b]
        omega = so3.log(np.swapaxes(self.R_ab, 1, 2) @ RaT_Rb)   # log(R_ab^T R_a^T R_b)
        rel_t = np.einsum('mji,mj->mi', Ra, P[self.b] - P[self.a])
        t_ab, held = self.t_ab, 0.0
        if self.window_scale is not None:
            t_ab, held = self.window_scale.targets(self, rel_t)
        r = np.empty((len(self), 6))
        np.multiply(self.w_rot[:, None], omega, out=r[:, :3])
        np.einsum('mij,mj->mi', self.W_trans, rel_t - t_ab, out=r[:, 3:])
        # np.sum's reductions (np.add.reduce) without its wrapper: the same sums.
        weights, cost = _huber(r, self.huber)
        ev = PriorEvaluation(r, cost + held, Ra, RaT_Rb, omega, rel_t, weights, t_ab)
        if self.changes is None or not len(self.changes):
            return ev
        changes = self.changes.evaluate(self, ev)
        return replace(ev, cost=ev.cost + changes.cost, changes=changes)

    def residuals(self, R: FloatArray, P: FloatArray) -> FloatArray:
        """Return the weighted residuals, shape (M, 6): rotation, then translation."""
        return self.evaluate(R, P).residuals

    def cost(self, R: FloatArray, P: FloatArray) -> float:
        """Return the factors' cost, 1/2 |r|^2 within the Huber threshold (the solver's)."""
        if len(self) == 0:
            return 0.0
        return self.evaluate(R, P).cost

    def jacobian(self, ev: PriorEvaluation) -> FloatArray:
        """Return d r / d [dphi_a, dP_a, dphi_b, dP_b] at an evaluation, shape (M, 6, 12)."""
        return _weighted(self.w_rot, self.W_trans, step_error_jacobian(ev))

    def hat_blocks(self, ev: PriorEvaluation, cov: FloatArray,
                   free_block: IntArray) -> FloatArray:
        """Return each factor's block of the hat matrix J Sigma J^T, shape (M, 6, 6).

        ``cov``: the poses' covariance (n_blocks * 6 square, a solver's block order),
        ``free_block``: pose -> block (-1: held, no covariance). J is the factor's
        Jacobian at ``ev`` with its Huber weight. The diagonal holds the residuals'
        leverages: 1 - leverage is the share of a residual's variance it keeps at the fit
        (its redundancy). A factor between held poses has none (NaN): no fit shares in it.
        """
        dim = cov.shape[0]
        padded = np.zeros((dim + 1, dim + 1))   # the last row and column: held poses
        padded[:dim, :dim] = cov

        def columns(pose: IntArray) -> IntArray:
            block = free_block[pose][:, None]
            return np.where(block >= 0, 6 * block + np.arange(6), dim)

        idx = np.concatenate([columns(self.a), columns(self.b)], axis=1)
        J = np.sqrt(ev.weights)[:, None, None] * self.jacobian(ev)
        hat = J @ padded[idx[:, :, None], idx[:, None, :]] @ np.swapaxes(J, 1, 2)
        hat[(free_block[self.a] < 0) & (free_block[self.b] < 0)] = np.nan
        return np.asarray(hat)

    def jacobians(self, R: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return d r / d [dphi_a, dP_a] and d r / d [dphi_b, dP_b], each (M, 6, 6)."""
        J = self.jacobian(self.evaluate(R, P))
        return J[:, :, :6], J[:, :, 6:]

    def bind(self, structure: SchurStructure, free_block: IntArray) -> PriorAssembly:
        """Return where the factors' J^T J and J^T r blocks go in a problem's equations.

        Fixed poses contribute no columns. A cross block is added where its two poses are a
        covisible pair of the structure (consecutive keyframes of a window are); elsewhere
        only the diagonal blocks are (a block-Jacobi approximation of the factor).

        Args:
            structure: The problem's Schur structure.
            free_block: Pose -> block index (-1 for fixed poses).
        """
        steps = FactorBlocks.bind(structure, free_block, np.stack([self.a, self.b], axis=1))
        changes = None
        if self.changes is not None and len(self.changes):
            first = self.changes.first
            poses = np.stack([self.a[first], self.b[first], self.b[first + 1]], axis=1)
            changes = FactorBlocks.bind(structure, free_block, poses)
        return PriorAssembly(self, steps, changes, free_block, structure.n_blocks)

    def add_to(self, structure: SchurStructure, eqs: NormalEquations, R: FloatArray,
               P: FloatArray, free_block: IntArray) -> NormalEquations:
        """Return ``eqs`` (unscaled) with the factors' J^T J and J^T r added (see :meth:`bind`).

        Args:
            structure: The problem's Schur structure.
            eqs: Normal equations of the observations.
            R: Rotations of the problem's poses, (n_cams, 3, 3).
            P: Centres, (n_cams, 3).
            free_block: Pose -> block index (-1 for fixed poses).
        """
        if len(self) == 0:
            return eqs
        return self.bind(structure, free_block).add_to(eqs, self.evaluate(R, P))


@dataclass(frozen=True, eq=False)
class PriorEvaluation:
    """The factors at one pose estimate.

    Attributes:
        residuals: Weighted residuals (M, 6): rotation, then translation.
        cost: The factors' cost (1/2 |residuals|^2 within the Huber threshold).
        Ra: Rotations of the poses a (M, 3, 3).
        RaT_Rb: R_a^T R_b (M, 3, 3).
        omega: log(R_ab^T R_a^T R_b) (M, 3).
        rel_t: R_a^T (P_b - P_a) (M, 3).
        weights: Each factor's weight in the normal equations, min(1, huber / |r|), (M,).
        t_ab: The measured steps the residuals are taken against (M, 3): the prior's, or
            with a :class:`WindowScale` at its groups' scales.
        changes: The step-change factors' evaluation (None without them).
    """

    residuals: FloatArray
    cost: float
    Ra: FloatArray
    RaT_Rb: FloatArray
    omega: FloatArray
    rel_t: FloatArray
    weights: FloatArray
    t_ab: FloatArray
    changes: ChangeEvaluation | None = None


@dataclass(frozen=True, eq=False)
class FactorBlocks:
    """Where the blocks of factors over k poses go in one problem's normal equations.

    Attributes:
        k: Poses per factor.
        h_factor, h_row, h_col, h_pair: Block (h_row, h_col) of factor h_factor's J^T J (rows
            and columns: the factor's poses, in its order) is added to the upper pair block
            h_pair of U.
        g_factor, g_side, g_block: Pose g_side of factor g_factor's J^T r is added to the
            gradient of pose block g_block.
    """

    k: int
    h_factor: IntArray
    h_row: IntArray
    h_col: IntArray
    h_pair: IntArray
    g_factor: IntArray
    g_side: IntArray
    g_block: IntArray

    @classmethod
    def bind(cls, structure: SchurStructure, free_block: IntArray,
             poses: IntArray) -> FactorBlocks:
        """Return the blocks of factors over ``poses`` (M, k) (as RelativePosePrior.bind)."""
        nb = structure.n_blocks
        keys = structure.pair_rows.astype(np.int64) * nb + structure.pair_cols
        order = np.argsort(keys)
        sorted_keys = keys[order]
        M, k = poses.shape
        blocks = free_block[poses]
        # Every (i <= j) pose pair of every factor; a pair block's row is its lower block.
        i, j = np.triu_indices(k)
        x, y = blocks[:, i].T.ravel(), blocks[:, j].T.ravel()
        lo, hi = np.minimum(x, y), np.maximum(x, y)
        want = lo.astype(np.int64) * nb + hi
        pos = np.minimum(np.searchsorted(sorted_keys, want), max(len(sorted_keys) - 1, 0))
        keep = (len(sorted_keys) > 0) & (sorted_keys[pos] == want) & (lo >= 0)
        upper = np.repeat(i, M), np.repeat(j, M)
        swap = x > y
        row = np.where(swap, upper[1], upper[0])[keep]
        col = np.where(swap, upper[0], upper[1])[keep]
        factor = np.tile(np.arange(M), i.size)[keep]
        free = blocks >= 0
        g_factor, g_side = np.nonzero(free)
        return cls(k, factor, row, col, order[pos[keep]], g_factor, g_side, blocks[free])

    def add(self, U: FloatArray, g: FloatArray, J: FloatArray, r: FloatArray,
            w: FloatArray) -> None:
        """Add the weighted J^T J and J^T r of factors with Jacobians J (M, d, 6k) to U and g."""
        M, k = J.shape[0], self.k
        H = (w[:, None, None] * (np.swapaxes(J, 1, 2) @ J)).reshape(M, k, 6, k, 6)
        grad = (w[:, None] * np.einsum('mji,mj->mi', J, r)).reshape(M, k, 6)
        np.add.at(U, self.h_pair, H[self.h_factor, self.h_row, :, self.h_col, :])
        np.add.at(g, self.g_block, grad[self.g_factor, self.g_side])


@dataclass(frozen=True, eq=False)
class PriorAssembly:
    """A prior bound to one problem's Schur structure (:meth:`RelativePosePrior.bind`).

    Attributes:
        prior: The factors.
        steps: Blocks of the step factors (poses a, b).
        changes: Blocks of the step-change factors (poses a, b, c), or None.
        free_block: Pose -> block index (-1 for fixed poses).
        n_blocks: Free pose blocks of the problem.
    """

    prior: RelativePosePrior
    steps: FactorBlocks
    changes: FactorBlocks | None
    free_block: IntArray
    n_blocks: int

    def low_rank(self, ev: PriorEvaluation) -> tuple[FloatArray, FloatArray] | None:
        """Return the curvature the window scale takes out of :meth:`add_to`'s, or None.

        A :class:`WindowScale` group's fitted scale follows its steps, so the cost is far
        less curved along a scaling of the group (or along its trend) than the factors'
        with the scale held: its Gauss-Newton Hessian is ``J^T J - U_k^T G_k^-1 U_k`` per
        group k, ``U_k = sum_i w_i q_i |t_i| (1, tau_i) dL_i^T`` (q_i: the information on
        the length against the group's scale, w_i: the Huber weight, dL_i: the gradient of
        the solved step's length, G_k: :meth:`WindowScale.fit`'s). Returns the rows
        ``L_k^-1 U_k`` (``G_k = L_k L_k^T``) over the pose columns (n_blocks * 6) and their
        divisors (ones), unscaled.
        """
        ws = self.prior.window_scale
        if ws is None or not len(self.prior):
            return None
        prior = self.prior
        fit = ws.fit(prior, ev.rel_t, ev.weights)
        G, length = fit.normal, fit.length
        q = ev.weights * ws.share * fit.info
        grad = np.einsum('mi,mij->mj', fit.along, step_error_jacobian(ev)[:, 3:])   # (M, 12)
        B = ws.basis()
        n = G.shape[0]
        U = np.zeros((n, self.n_blocks + 1, 2, 6))   # the last block: held poses
        coef = (q * length)[:, None] * B   # (M, 2)
        for side, pose in enumerate((prior.a, prior.b)):
            block = np.where(self.free_block[pose] >= 0, self.free_block[pose], self.n_blocks)
            side_grad = grad[:, None, 6 * side:6 * side + 6]
            np.add.at(U, (ws.group, block), coef[:, :, None] * side_grad)
        U = U.transpose(0, 2, 1, 3)
        # U^T G^-1 U = (L^-1 U)^T (L^-1 U) with G = L L^T: rows with d = 1.
        L = np.linalg.cholesky(G)
        rows = np.linalg.solve(L, U[:, :, :-1].reshape(n, 2, -1)).reshape(2 * n, -1)
        keep = np.any(rows != 0.0, axis=1)
        return rows[keep], np.ones(int(keep.sum()))

    def add_to(self, eqs: NormalEquations, ev: PriorEvaluation) -> NormalEquations:
        """Return ``eqs`` (unscaled) with the factors' J^T J and J^T r at ``ev`` added."""
        U = eqs.U.copy()
        g = eqs.g_pose.copy()
        E = step_error_jacobian(ev)   # both kinds of factor are built from it
        prior = self.prior
        self.steps.add(U, g, _weighted(prior.w_rot, prior.W_trans, E), ev.residuals, ev.weights)
        if self.changes is not None and ev.changes is not None and prior.changes is not None:
            J = prior.changes.jacobian(ev, E)
            self.changes.add(U, g, J, ev.changes.residuals, ev.changes.weights)
        return NormalEquations(U, eqs.W, eqs.V, g, eqs.g_feat)


@dataclass(frozen=True, eq=False)
class StepChanges:
    """Factors on the change of the step error between consecutive factors of a prior.

    Factor i joins the prior's factors ``first[i]`` (a -> b) and ``first[i] + 1`` (b -> c);
    its residual is ``[w_rot (e_bc - e_ab)_rot, W_trans (e_bc - e_ab)_trans]`` with the
    unweighted step errors e (see the module docstring).

    Attributes:
        first: The first factor of each pair, shape (M,).
        w_rot: Rotation weight, shape (M,).
        W_trans: Translation weight (square-root information), shape (M, 3, 3).
    """

    first: IntArray
    w_rot: FloatArray
    W_trans: FloatArray

    def __len__(self) -> int:
        """Return the number of factors."""
        return int(self.first.shape[0])

    def fits(self, prior: RelativePosePrior) -> bool:
        """Return whether each pair is two consecutive factors of ``prior``, weights finite."""
        M, n = len(self), len(prior)
        shapes = self.w_rot.shape == (M,) and self.W_trans.shape == (M, 3, 3)
        if not shapes or (M and (self.first.min() < 0 or self.first.max() + 1 >= n)):
            return False
        return bool(np.all(prior.b[self.first] == prior.a[self.first + 1])
                    and np.all(np.isfinite(self.w_rot)) and np.all(np.isfinite(self.W_trans)))

    def evaluate(self, prior: RelativePosePrior, ev: PriorEvaluation) -> ChangeEvaluation:
        """Return the factors at the prior's evaluation ``ev``."""
        e = np.concatenate([ev.omega, ev.rel_t - ev.t_ab], axis=1)
        d = e[self.first + 1] - e[self.first]
        r = np.empty_like(d)
        np.multiply(self.w_rot[:, None], d[:, :3], out=r[:, :3])
        np.einsum('mij,mj->mi', self.W_trans, d[:, 3:], out=r[:, 3:])
        weights, cost = _huber(r, prior.huber)
        return ChangeEvaluation(r, cost, weights)

    def jacobian(self, ev: PriorEvaluation, E: FloatArray | None = None) -> FloatArray:
        """Return d r / d [a, b, c] (each [dphi, dP]) at the prior's evaluation, (M, 6, 18).

        ``E``: the prior's :func:`step_error_jacobian` at ``ev``, where the caller has it.
        """
        E = step_error_jacobian(ev) if E is None else E
        E_ab, E_bc = E[self.first], E[self.first + 1]
        J = np.concatenate([-E_ab[:, :, :6], E_bc[:, :, :6] - E_ab[:, :, 6:], E_bc[:, :, 6:]],
                           axis=2)
        return _weighted(self.w_rot, self.W_trans, J)


@dataclass(frozen=True, eq=False)
class WindowScale:
    """Step lengths measured partly against their group's own scale (a stereo rig's window).

    A factor's length part merges two Gaussian factors on the length L of the solved step:
    against the prior's ``t_ab`` (the reference scale; information share ``1 - share``) and
    against ``s |t_ab|`` (share ``share``), s the group's scale over the reference's at the
    factor: a level and a trend along the group, ``s = theta . (1, tau)`` (:meth:`basis`), so
    that a front-end's slowly drifting scale is not taken for the map's. Each evaluation
    sets theta to the best fit of the group's lengths (:meth:`fit`). The residuals are taken
    against the merged target ``t_ab ((1 - share) + share s)``, and the cost adds the part the
    merge leaves out, ``1/2 sum(i share (1 - share) |t_ab|^2 (s - 1)^2)`` (i: the factor's
    information on its length): the sum is the cost of both factors at that s. As theta is
    the best fit for the poses evaluated, the cost's gradient is that of the factors with it
    held (their Jacobians), and a group scaled as a whole, or along its trend, changes the
    second part only as its residuals scale (:meth:`PriorAssembly.low_rank`).

    Attributes:
        share: Each factor's share of its length information against the group's scale,
            in [0, 1], shape (M,).
        group: Each factor's group (consecutive steps sharing one scale), shape (M,), >= 0.
    """

    share: FloatArray
    group: IntArray

    def fits(self, M: int) -> bool:
        """Return whether there is one share in [0, 1] and one group >= 0 per factor."""
        return bool(self.share.shape == (M,) and self.group.shape == (M,)
                    and np.all(np.isfinite(self.share)) and np.all(self.share >= 0)
                    and np.all(self.share <= 1) and (M == 0 or self.group.min() >= 0))

    def basis(self) -> FloatArray:
        """Return each factor's scale basis, rows (1, tau) (M, 2); tau in [-1/2, 1/2] by group."""
        M = self.group.shape[0]
        n = int(self.group.max()) + 1 if M else 0
        index = np.arange(M, dtype=float)
        first, last = np.full(n, np.inf), np.full(n, -np.inf)
        np.minimum.at(first, self.group, index)
        np.maximum.at(last, self.group, index)
        tau = (index - 0.5 * (first + last)[self.group]) / np.maximum(last - first, 1.0)[
            self.group]
        return np.column_stack([np.ones(M), tau])

    def fit(self, prior: RelativePosePrior, rel_t: FloatArray,
            weights: FloatArray | None = None) -> ScaleFit:
        """Return the groups' fitted scales at solved steps ``rel_t`` (:class:`ScaleFit`).

        With i each factor's information on its length, theta minimizes
        ``sum(w share i (L - |t_ab| theta . (1, tau))^2)`` over each group (L: the solved
        step ``rel_t`` along the measured one; w: the Huber ``weights``, where given), with
        a vanishing ridge towards the reference (1, 0): a group without information keeps
        the reference scale.
        """
        length = np.sqrt(_add(prior.t_ab * prior.t_ab, axis=1))
        along = prior.t_ab / np.maximum(length, 1e-300)[:, None]
        w = np.einsum('mij,mj->mi', prior.W_trans, along)
        info = _add(w * w, axis=1)
        q = self.share * info if weights is None else weights * self.share * info
        B = self.basis()
        n = int(self.group.max()) + 1
        G = np.zeros((n, 2, 2))
        BB = B[:, :, None] * B[:, None, :]
        np.add.at(G, self.group, (q * length * length)[:, None, None] * BB)
        rhs = np.zeros((n, 2))
        np.add.at(rhs, self.group, (q * length * _add(rel_t * along, axis=1))[:, None] * B)
        trace = G[:, 0, 0] + G[:, 1, 1]
        ridge = np.where(trace > 0, 1e-12 * trace, 1.0)
        G += ridge[:, None, None] * np.eye(2)
        rhs[:, 0] += ridge
        theta = np.linalg.solve(G, rhs[:, :, None])[:, :, 0]
        return ScaleFit(_add(B * theta[self.group], axis=1), G, info, length, along)

    def targets(self, prior: RelativePosePrior,
                rel_t: FloatArray) -> tuple[FloatArray, float]:
        """Return each step's merged target (M, 3) at solved steps ``rel_t``; the cost left out."""
        if not self.group.size:
            return prior.t_ab, 0.0
        fit = self.fit(prior, rel_t)
        t_ab = prior.t_ab * ((1.0 - self.share) + self.share * fit.scale)[:, None]
        left = fit.info * self.share * (1.0 - self.share) * fit.length ** 2
        return t_ab, 0.5 * float(_add(left * (fit.scale - 1.0) ** 2))


class ScaleFit(NamedTuple):
    """A :class:`WindowScale` fit at one pose estimate.

    Attributes:
        scale: Each factor's fitted scale s over the reference's, shape (M,).
        normal: Each group's normal matrix of theta (with its ridge), shape (n, 2, 2).
        info: Each factor's information on its length, shape (M,).
        length: The measured steps' lengths ``|t_ab|``, shape (M,).
        along: Their directions, shape (M, 3).
    """

    scale: FloatArray
    normal: FloatArray
    info: FloatArray
    length: FloatArray
    along: FloatArray


@dataclass(frozen=True, eq=False)
class ChangeEvaluation:
    """The step-change factors at one pose estimate: residuals (M, 6), cost, Huber weights."""

    residuals: FloatArray
    cost: float
    weights: FloatArray


def step_error_jacobian(ev: PriorEvaluation) -> FloatArray:
    """Return d e / d [dphi_a, dP_a, dphi_b, dP_b] of the unweighted step errors, (M, 6, 12)."""
    M = ev.omega.shape[0]
    E = np.zeros((M, 6, 12))
    Jr_inv = right_jacobian_inverse(ev.omega)
    E[:, :3, :3] = -Jr_inv @ np.swapaxes(ev.RaT_Rb, 1, 2)
    E[:, :3, 6:9] = Jr_inv
    RaT = np.swapaxes(ev.Ra, 1, 2)
    E[:, 3:, :3] = so3.hat(ev.rel_t)
    E[:, 3:, 3:6] = -RaT
    E[:, 3:, 9:] = RaT
    return E


def _weighted(w_rot: FloatArray, W_trans: FloatArray, E: FloatArray) -> FloatArray:
    """Return the rows of E (M, 6, n) weighted: rotation rows by w_rot, translation by W_trans."""
    J = np.empty_like(E)
    np.multiply(w_rot[:, None, None], E[:, :3], out=J[:, :3])
    np.matmul(W_trans, E[:, 3:], out=J[:, 3:])
    return J


def _huber(r: FloatArray, huber: float) -> tuple[FloatArray, float]:
    """Return each factor's weight min(1, huber / |r|) and the factors' Huber cost."""
    norm = np.sqrt(_add(r * r, axis=1))
    outer = norm > huber
    weights = np.ones(r.shape[0])
    costs = 0.5 * norm * norm
    if outer.any():
        weights[outer] = huber / norm[outer]
        costs[outer] = huber * norm[outer] - 0.5 * huber * huber
    return weights, float(_add(costs))
