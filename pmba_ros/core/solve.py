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
"""One entry point, :func:`solve`, for PMBA, XYZ-BA and IDP-BA with Dogleg, LM or Gauss-Newton.

The loop follows Ceres' TrustRegionMinimizer (pmba.md §5.2): Jacobi scaling of the columns,
an ellipsoidal trust region in the scaled space, Schur-complement linear solves, and for
Dogleg, cheap retries that reuse the Gauss-Newton and Cauchy points after a rejected step.
The cost is Ceres' ``1/2 sum rho(|e|^2)``; ``rms_px`` is the pixel reprojection RMS of the
current estimate (sqrt of the mean squared 2-D error), the common metric of all
parameterizations.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
import math
import time
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import conversions, dogleg
from pmba_ros.core import normal_equations as ne
from pmba_ros.core.engine import EngineName, resolve
from pmba_ros.core.gauge import choose_gauge, free_gauge, scale_tension
from pmba_ros.core.loss import Loss, noise_scale_px
from pmba_ros.core.models import make_model, Model
from pmba_ros.core.pose_prior import RelativePosePrior
from pmba_ros.core.problem import (
    BAProblem,
    Features,
    Parameterization,
    permute_features,
    take_features,
)
from pmba_ros.core.start_checks import check_not_empty, non_finite_start_message
from pmba_ros.core.trust_step import add, Linearized, State, sum_products, trial_state
from pmba_ros.errors import SolverError


class SolverKind(str, Enum):
    """Trust-region strategies."""

    DOGLEG = 'dogleg'
    LM = 'lm'
    GN = 'gn'


class TerminationReason(str, Enum):
    """Why the solver stopped."""

    FUNCTION_TOLERANCE = 'function_tolerance'
    GRADIENT_TOLERANCE = 'gradient_tolerance'
    PARAMETER_TOLERANCE = 'parameter_tolerance'
    MIN_TRUST_REGION = 'min_trust_region_radius'
    MAX_ITERATIONS = 'max_iterations'
    MAX_TIME = 'max_time'
    INVALID_STEPS = 'too_many_invalid_steps'


_CONVERGED = {TerminationReason.FUNCTION_TOLERANCE, TerminationReason.GRADIENT_TOLERANCE,
              TerminationReason.PARAMETER_TOLERANCE, TerminationReason.MIN_TRUST_REGION}


@dataclass(frozen=True, slots=True)
class SolveOptions:
    """Options of :func:`solve`; defaults are Ceres' (include/ceres/solver.h).

    Attributes:
        param: Feature parameterization.
        solver: Trust-region strategy.
        loss: Robust loss.
        loss_scale_px: Loss scale in pixels (ray errors use loss_scale_px / median focal).
        max_iterations: Iteration budget (accepted and rejected steps).
        max_time_s: Wall-time budget in seconds.
        function_tolerance: Stop when an accepted step changes the cost by less than this,
            relative.
        gradient_tolerance: Stop when max |J^T r| falls below this.
        parameter_tolerance: Stop when |step| <= tol (|x| + tol).
        initial_trust_region_radius: Initial Delta (scaled space).
        jacobi_scaling: Scale Jacobian columns by 1 / (1 + |J_k|).
        pixel_weighted: PMBA only: map ray errors to pixels by the projection Jacobian at the
            measured bearing (see :class:`~pmba_ros.core.models.ParallaxModel`); False is
            the paper's isotropic chordal error.
        fix_gauge: Hold the root pose and one centre coordinate (ParallaxBA's gauge, pmba.md
            §2) instead of leaving the similarity freedom to the damping, as Ceres does
            (see :func:`~pmba_ros.core.gauge.free_gauge`).
        engine: ``'numpy'``, ``'compiled'`` (numba loops) or ``'auto'``: compiled where numba
            is installed and ``PMBA_NUMBA`` is not 0 (:mod:`pmba_ros.core.engine`). Both give
            the same iterates to rounding.
        prior_leverage: Also return the pose prior's leverages (``SolveResult.prior_leverage``).
        scale_tension: PMBA only: also return the cost's slope and curvature along a scaling
            of every pose, fixed ones too (``SolveResult.scale_tension``).
    """

    param: Parameterization = Parameterization.PMBA
    solver: SolverKind = SolverKind.DOGLEG
    loss: Loss = Loss.NONE
    loss_scale_px: float = 2.0
    max_iterations: int = 100
    max_time_s: float = math.inf
    function_tolerance: float = 1e-6
    gradient_tolerance: float = 1e-10
    parameter_tolerance: float = 1e-8
    initial_trust_region_radius: float = 1e4
    jacobi_scaling: bool = True
    pixel_weighted: bool = True
    fix_gauge: bool = False
    engine: EngineName = EngineName.AUTO
    prior_leverage: bool = False
    scale_tension: bool = False

    def __post_init__(self) -> None:
        """Coerce enum strings and validate ranges."""
        try:
            object.__setattr__(self, 'param', Parameterization(self.param))
            object.__setattr__(self, 'solver', SolverKind(self.solver))
            object.__setattr__(self, 'loss', Loss(self.loss))
            object.__setattr__(self, 'engine', EngineName(self.engine))
        except ValueError as err:
            msg = f'SolveOptions: {err}'
            raise ValueError(msg) from err
        if self.max_iterations < 0:
            msg = '`max_iterations` must be >= 0'
            raise ValueError(msg)
        if self.loss_scale_px <= 0 or self.initial_trust_region_radius <= 0:
            msg = '`loss_scale_px` and `initial_trust_region_radius` must be positive'
            raise ValueError(msg)

    def loss_scale(self, model: Model[Any]) -> float:
        """Return the loss scale in the model's residual units (ray errors: px / median focal)."""
        if model.pixel_residuals:
            return self.loss_scale_px
        return self.loss_scale_px / model.problem.intrinsics.median_focal


MISFIT_FACTOR = 3.0
"""A final RMS beyond this many times what the noise estimate gives is worth a warning."""


@dataclass(frozen=True, slots=True)
class IterationRecord:
    """One solver iteration.

    Attributes:
        iteration: Index (0 = the initial state).
        cost: Cost after the iteration.
        rms_px: Pixel reprojection RMS after the iteration.
        accepted: Whether the step was accepted.
        trust_radius: Trust-region radius after the update.
        step_norm: Norm of the step (scaled space).
        rho: Step quality (NaN: a step below the parameter tolerance, not taken: converged).
        linear_solves: Cumulative number of linear solves.
        time_s: Elapsed time since the start.
    """

    iteration: int
    cost: float
    rms_px: float
    accepted: bool
    trust_radius: float
    step_norm: float
    rho: float
    linear_solves: int
    time_s: float


@dataclass(frozen=True, eq=False)
class SolveResult:
    """The result of :func:`solve` (never aliases the input problem's arrays).

    Attributes:
        R_wc: Optimized camera -> world rotations (M, 3, 3).
        centers_w: Optimized camera centres (M, 3).
        features: Optimized features of the chosen parameterization.
        points_w: Euclidean points (N, 3) (inf for points at infinity).
        problem: The problem that was solved (after dropping unusable features).
        options: The options used.
        converged: True if a convergence criterion stopped the solver.
        termination: Why the solver stopped.
        iterations: Number of iterations (accepted and rejected).
        accepted_steps: Number of accepted steps.
        linear_solves: Number of factorizations of the reduced system.
        initial_cost, final_cost: Cost 1/2 sum rho(|e|^2) before and after.
        initial_rms_px, final_rms_px: Pixel reprojection RMS before and after.
        time_s: Wall time in seconds.
        history: Per-iteration records, starting with the initial state.
        noise_px: Per-axis pixel noise the final errors suggest (see ``noise_scale_px``).
        prior_residuals: The pose prior's weighted residuals at the result, (M, 6) (M = 0
            without a prior).
        prior_leverage: With ``options.prior_leverage``, the prior's blocks of the hat matrix
            at the last linearization, (M, 6, 6) (:meth:`RelativePosePrior.hat_blocks`),
            NaN where not computed.
        scale_tension: With ``options.scale_tension``, d cost / d s and d^2 cost / d s^2 at
            the result for centres (1 + s) P, fixed ones too
            (:func:`~pmba_ros.core.gauge.scale_tension`); NaN where not computed.
        bounded_cost: ``final_cost`` as under the Cauchy loss (equal to it with that loss):
            a few observations far off, which weigh linearly under Huber and quadratically
            without a loss, add little to it; a cost to compare across solves.
    """

    R_wc: FloatArray
    centers_w: FloatArray
    features: Features
    points_w: FloatArray
    problem: BAProblem
    options: SolveOptions
    converged: bool
    termination: TerminationReason
    iterations: int
    accepted_steps: int
    linear_solves: int
    initial_cost: float
    final_cost: float
    initial_rms_px: float
    final_rms_px: float
    time_s: float
    history: list[IterationRecord] = field(default_factory=list)
    noise_px: float = math.nan
    prior_residuals: FloatArray = field(default_factory=lambda: np.zeros((0, 6)))
    prior_leverage: FloatArray = field(default_factory=lambda: np.zeros((0, 6, 6)))
    scale_tension: tuple[float, float] = (math.nan, math.nan)
    bounded_cost: float = math.nan

    def summary(self) -> str:
        """Return a readable multi-line summary, like Ceres' BriefReport plus sizes."""
        p = self.problem
        head = (f'{self.options.param.value.upper()} / {self.options.solver.value}'
                f' (loss {self.options.loss.value}): {p.n_cams} poses, {p.n_feats} features,'
                f' {p.n_obs} observations')
        iters = (f'  iterations {self.iterations} (accepted {self.accepted_steps}),'
                 f' linear solves {self.linear_solves}, {self.time_s:.3f} s')
        state = 'converged' if self.converged else 'not converged'
        return '\n'.join([
            head,
            f'  cost     {self.initial_cost:.6e} -> {self.final_cost:.6e}',
            (f'  rms_px   {self.initial_rms_px:.4f} -> {self.final_rms_px:.4f}'
             f' (noise estimate {self.noise_px:.4f} px per axis)'),
            iters,
            f'  termination: {self.termination.value} ({state})'])

    def misfit(self) -> str:
        """Return why the final RMS is far above what the noise estimate gives, else ''.

        Gaussian errors of the estimated sigma per axis give an RMS of sigma sqrt(2); a few
        observations far off (wrong matches) or a part of the solution that is wrong (which
        the median-based estimate does not see) give more.
        """
        expected = math.sqrt(2.0) * self.noise_px
        if not (self.converged and expected > 0.0
                and self.final_rms_px > MISFIT_FACTOR * expected):
            return ''
        bound = ('the robust loss bounds them' if self.options.loss is not Loss.NONE
                 else 'a robust loss would bound them')
        return (f'final rms {self.final_rms_px:.4f} px is {self.final_rms_px / expected:.1f}x '
                f'what the noise estimate ({self.noise_px:.4f} px per axis) gives: some '
                f'observations fit far worse than most (wrong matches? {bound}) or part of '
                'the solution is wrong')

    def to_report(self) -> dict[str, Any]:
        """Return the JSON-able report of the ``solve`` CLI."""
        return {
            'param': self.options.param.value, 'solver': self.options.solver.value,
            'loss': self.options.loss.value, 'converged': self.converged,
            'termination': self.termination.value, 'iterations': self.iterations,
            'accepted_steps': self.accepted_steps, 'linear_solves': self.linear_solves,
            'initial_cost': self.initial_cost, 'final_cost': self.final_cost,
            'initial_rms_px': self.initial_rms_px, 'final_rms_px': self.final_rms_px,
            'noise_px': self.noise_px if math.isfinite(self.noise_px) else None,
            'time_s': self.time_s, 'n_cams': self.problem.n_cams,
            'n_feats': self.problem.n_feats, 'n_obs': self.problem.n_obs,
            'dropped': dict(self.problem.dropped),
            'history': [{'cost': h.cost, 'rms_px': h.rms_px, 'accepted': h.accepted,
                         'trust_radius': h.trust_radius, 'time_s': h.time_s}
                        for h in self.history]}


def solve(problem: BAProblem, options: SolveOptions | None = None,
          features: Features | None = None, *,
          callback: Callable[[IterationRecord], None] | None = None,
          pose_prior: RelativePosePrior | None = None) -> SolveResult:
    """Solve a bundle-adjustment problem.

    Args:
        problem: The problem; its poses are the start, and its points unless ``features``.
        options: Solver options (defaults: PMBA, Dogleg, no loss).
        features: Initial features of ``options.param`` (default: from ``problem.points_w``).
        callback: Called with each :class:`IterationRecord` (progress, plots).
        pose_prior: Relative-motion factors between the problem's poses, added to the cost
            and the reduced camera system (the costs reported include them).

    Returns:
        The result; ``result.problem`` is the problem actually solved (unusable features
        dropped and counted in its ``dropped``).

    Raises:
        ProblemError: If there are no initial features or they do not fit the problem.
        SolverError: If the start is not finite, nothing is free to optimize, or the
            compiled engine is asked for without numba.
    """
    options = options or SolveOptions()
    t0 = time.perf_counter()
    engine = resolve(options.engine)
    check_not_empty(problem)
    if features is None:
        problem, features = conversions.initial_features(problem, options.param, engine)
        check_not_empty(problem)
    conversions.check_features(problem, features, options.param)
    # The normal equations want features ordered by their number of observations; the
    # solve runs on that order and the result is returned in the caller's (a caller that
    # builds its problems in that order, as the back-end does, saves both permutations).
    order = ne.feature_order(problem.obs.feat_idx, problem.n_feats)
    permuted = bool(np.any(order != np.arange(problem.n_feats)))
    solved = permute_features(problem, order) if permuted else problem
    # The pixel weights of an absurd focal length overflow: the start's check below names
    # its camera, numpy's warnings would only precede that message.
    with np.errstate(over='ignore', invalid='ignore'):
        model: Model[Any] = make_model(options.param, solved,
                                       pixel_weighted=options.pixel_weighted, engine=engine)
    if options.fix_gauge:
        gauge = choose_gauge(problem.centers_w, problem.fixed, problem.obs.cam_idx,
                             problem.obs.feat_idx, problem.n_feats,
                             metric=problem.rig is not None)
    else:
        gauge = free_gauge(problem.n_cams, problem.fixed, problem.obs.cam_idx)
    free_block = gauge.free_block()
    features = take_features(features, order) if permuted else features
    structure = ne.SchurStructure.build(solved.obs.cam_idx, solved.obs.feat_idx,
                                        model.slots(features), problem.n_feats, free_block,
                                        model.anchor_cols, engine.schur_plan,
                                        engine.schur_anchors)
    col_mask = gauge.column_mask()
    loss_scale = options.loss_scale(model)

    # The prior's residuals at a state serve its cost and, once the state is accepted, its
    # linearization; where its blocks go in the equations is found once per solve.
    factors = pose_prior if pose_prior is not None and len(pose_prior) else None
    prior = factors.bind(structure, free_block) if factors is not None else None

    def evaluate(R: FloatArray, P: FloatArray, feats: Any) -> State:
        ev = model.evaluate(R, P, feats)
        pe = factors.evaluate(R, P) if factors is not None else None
        prior_cost = pe.cost if pe is not None else 0.0
        return State(R, P, feats, engine.robust_cost(ev.residuals, options.loss, loss_scale)
                     + prior_cost, ev, pe)

    def norm_of(state: State) -> float:
        """|x| of the parameters (rotations count 1 each), for the parameter tolerance."""
        return math.sqrt(problem.n_cams + float(add(state.centers_w ** 2, axis=None))
                         + model.parameter_norm_sq(state.feats))

    def rms_of(err: FloatArray) -> float:
        return math.sqrt(float(add(err * err, axis=None)) / err.size) if err.size else 0.0

    # A start that overflows is reported by the check below, naming its cameras, as above.
    with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
        state = evaluate(np.array(problem.R_wc), np.array(problem.centers_w), features)
    if not math.isfinite(state.cost):
        raise SolverError(non_finite_start_message(state.evaluation.residuals, solved))
    x_norm = norm_of(state)
    errors = model.reprojection_errors_px(state.evaluation)  # also for the noise estimate
    initial_cost, initial_rms = state.cost, rms_of(errors)
    history = [IterationRecord(0, initial_cost, initial_rms, True,
                               options.initial_trust_region_radius, 0.0, math.nan, 0, 0.0)]
    if callback:
        callback(history[0])
    radius = options.initial_trust_region_radius
    decrease_factor = 2.0
    mu = dogleg.MIN_MU
    linear_solves = 0
    accepted_steps = 0
    invalid = 0
    termination = TerminationReason.MAX_ITERATIONS
    lin: Linearized | None = None
    last_lin: Linearized | None = None
    rms = initial_rms
    it = 0
    while True:
        # Budgets first: a linearization that no step will use is wasted work. The time
        # budget allows at least one iteration, so a loaded machine still makes progress.
        if it >= options.max_iterations:
            termination = TerminationReason.MAX_ITERATIONS
            break
        if it > 0 and time.perf_counter() - t0 > options.max_time_s:
            termination = TerminationReason.MAX_TIME
            break
        if lin is None:
            lin = last_lin = Linearized(model, structure, state, options.loss, loss_scale,
                                        options.jacobi_scaling, col_mask, prior)
            if lin.gradient_max <= options.gradient_tolerance:
                termination = TerminationReason.GRADIENT_TOLERANCE
                break
        it += 1
        try:
            z_pose, z_feat, lin_solved = _propose(lin, options.solver, radius, mu)
        except ne.ReducedSystemError:
            linear_solves += 1
            invalid += 1
            mu = min(mu * dogleg.MU_INCREASE_FACTOR, dogleg.MAX_MU)
            radius *= 0.5
            if invalid > 5:
                termination = TerminationReason.INVALID_STEPS
                break
            continue
        linear_solves += lin_solved
        step_norm = math.sqrt(sum_products(z_pose, z_pose, z_feat, z_feat))
        d_pose, d_feat = lin.to_delta(z_pose, z_feat)
        delta_norm = math.sqrt(sum_products(d_pose, d_pose, d_feat, d_feat))
        if delta_norm <= options.parameter_tolerance * (x_norm + options.parameter_tolerance):
            termination = TerminationReason.PARAMETER_TOLERANCE
            # Its linear solve took as long as any: shown, with no step taken (rho NaN).
            history.append(IterationRecord(it, state.cost, rms, False, radius, step_norm,
                                           math.nan, linear_solves, time.perf_counter() - t0))
            if callback:
                callback(history[-1])
            break
        model_change = lin.model_change(d_pose, d_feat)
        if not (model_change > 0.0) or not math.isfinite(model_change):
            invalid += 1
            lin.gn = None
            mu = min(mu * dogleg.MU_INCREASE_FACTOR, dogleg.MAX_MU)
            if invalid > 5:
                termination = TerminationReason.INVALID_STEPS
                break
            continue
        invalid = 0
        trial, model_change = trial_state(model, lin, state, free_block, d_pose, d_feat,
                                          model_change, evaluate, options.loss, loss_scale)
        new_cost = trial.cost
        rho = dogleg.step_quality(state.cost, new_cost, model_change)
        accepted = rho > dogleg.MIN_RELATIVE_DECREASE
        if options.solver is SolverKind.LM:
            radius, decrease_factor = dogleg.lm_radius(radius, decrease_factor, rho, accepted)
        elif options.solver is SolverKind.DOGLEG:
            radius = dogleg.dogleg_radius(radius, rho, step_norm, accepted)
        else:
            radius = options.initial_trust_region_radius if accepted else 0.5 * step_norm
        radius = min(radius, 1e16)
        cost_change = state.cost - new_cost
        old_cost = state.cost
        if accepted:
            accepted_steps += 1
            state = trial
            errors = model.reprojection_errors_px(state.evaluation)
            rms = rms_of(errors)
            x_norm = norm_of(state)
            mu = max(dogleg.MIN_MU, mu / 5.0)
            lin = None
        record = IterationRecord(it, state.cost, rms, accepted, radius, step_norm, rho,
                                 linear_solves, time.perf_counter() - t0)
        history.append(record)
        if callback:
            callback(record)
        if accepted and abs(cost_change) <= options.function_tolerance * old_cost:
            termination = TerminationReason.FUNCTION_TOLERANCE
            break
        if radius < 1e-32:
            termination = TerminationReason.MIN_TRUST_REGION
            break

    noise_px = noise_scale_px(errors, int(np.count_nonzero(col_mask)) + 3 * problem.n_feats)
    final_feats = (take_features(state.feats, np.argsort(order))   # copies: never the caller's
                   if permuted or state.feats is features else state.feats)
    points = conversions.to_xyz(state.R_wc, state.centers_w, final_feats)
    leverage = np.full((len(factors) if factors is not None else 0, 6, 6), np.nan)
    if options.prior_leverage and factors is not None and last_lin is not None:
        leverage = last_lin.prior_leverage(factors, free_block)
    bounded_cost = state.cost
    if options.loss is not Loss.CAUCHY:
        bounded_cost = (engine.robust_cost(state.evaluation.residuals, Loss.CAUCHY, loss_scale)
                        + (state.prior.cost if state.prior is not None else 0.0))
    tension = (math.nan, math.nan)
    if options.scale_tension and options.param is Parameterization.PMBA:
        tension = scale_tension(lambda s: evaluate(state.R_wc, s * state.centers_w,
                                                   state.feats).cost, state.cost)
    return SolveResult(state.R_wc, state.centers_w, final_feats, points, problem, options,
                       termination in _CONVERGED, termination, it, accepted_steps,
                       linear_solves, initial_cost, state.cost, initial_rms, rms,
                       time.perf_counter() - t0, history, noise_px,
                       state.prior.residuals if state.prior is not None else np.zeros((0, 6)),
                       leverage, tension, bounded_cost)


def _propose(lin: Linearized, solver: SolverKind, radius: float, mu: float,
             ) -> tuple[FloatArray, FloatArray, int]:
    """Return a scaled step (pose, feature) and how many linear solves it took."""
    if solver is SolverKind.DOGLEG:
        solves = 0
        if lin.gn is None:
            lin.gn = lin.solve(mu)
            solves = 1
        b = np.concatenate([lin.gn[0].ravel(), lin.gn[1].ravel()])
        g = np.concatenate([lin.g_pose.ravel(), lin.g_feat.ravel()])
        step, _ = dogleg.dogleg_step(g, lin.cauchy_alpha(), b, radius)
        n_pose = lin.g_pose.size
        return (step[:n_pose].reshape(lin.g_pose.shape),
                step[n_pose:].reshape(lin.g_feat.shape), solves)
    if solver is SolverKind.LM:
        z_pose, z_feat = lin.solve(1.0 / radius)
        return z_pose, z_feat, 1
    # Gauss-Newton: the (almost) undamped step, shortened to the radius by backtracking.
    solves = 0
    if lin.gn is None:
        lin.gn = lin.solve(dogleg.MIN_MU)
        solves = 1
    norm = math.sqrt(sum_products(lin.gn[0], lin.gn[0], lin.gn[1], lin.gn[1]))
    shrink = min(1.0, radius / norm) if norm > 0 else 1.0
    return lin.gn[0] * shrink, lin.gn[1] * shrink, solves
