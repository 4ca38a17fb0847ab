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
"""The three parameterizations behind one interface, so one solver runs them all."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from pmba_ros._typing import FloatArray, IntArray
from pmba_ros.core import baselines, residuals, rig
from pmba_ros.core.engine import default_engine, Engine
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.problem import (
    BAProblem,
    IdpFeatures,
    ParallaxFeatures,
    Parameterization,
    restrict_features,
    XyzFeatures,
)
from pmba_ros.errors import ProblemError

F = TypeVar('F', ParallaxFeatures, XyzFeatures, IdpFeatures)

RAY_TURN_HALVINGS = 5
"""Halvings of a feature's step that turns a ray away (:meth:`Model.halve_turning_steps`)
before the feature sits the step out."""


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Residuals at one state, and what the reprojection error and linearization reuse.

    Attributes:
        residuals: Residuals, shape (K, d).
        rays_c: Each observation's predicted direction in its camera frame, shape (K, 3).
        geometry: Model-specific intermediates for :meth:`Model.linearize`, or None.
    """

    residuals: FloatArray
    rays_c: FloatArray
    geometry: Any = None


class Model(ABC, Generic[F]):
    """Residuals, Jacobians and feature retraction of one parameterization.

    Attributes:
        pixel_residuals: True if residuals are pixels (False: unit-ray chordal errors).
        anchor_cols: Pose columns (start, stop) that each anchor slot (slot 1, 2, ...) touches.
    """

    pixel_residuals: bool
    anchor_cols: tuple[tuple[int, int], ...] = ()

    def __init__(self, problem: BAProblem, engine: Engine | None = None) -> None:
        """Bind the model to a problem's observations and intrinsics, and to an engine.

        ``engine`` defaults to :func:`~pmba_ros.core.engine.default_engine`.
        """
        self.problem = problem
        self.obs = problem.obs
        self.engine = engine or default_engine()

    @abstractmethod
    def bound_to(self, problem: BAProblem) -> Model[F]:
        """Return a model like this one (its options and engine) bound to another problem."""

    def restricted(self, which: IntArray) -> Model[F]:
        """Return this model of the features ``which`` (ascending) and their observations alone."""
        keep = np.zeros(self.problem.n_feats, bool)
        keep[which] = True
        return self.bound_to(restrict_features(self.problem, keep))

    @abstractmethod
    def slots(self, feats: F) -> IntArray:
        """Return the pose of each observation's Jacobian slots, shape (K, S), -1 unused."""

    @abstractmethod
    def evaluate(self, R_wc: FloatArray, centers_w: FloatArray, feats: F) -> Evaluation:
        """Return the residuals at a state, with the predicted camera-frame directions."""

    def residuals(self, R_wc: FloatArray, centers_w: FloatArray, feats: F) -> FloatArray:
        """Return residuals, shape (K, d)."""
        return self.evaluate(R_wc, centers_w, feats).residuals

    @abstractmethod
    def linearize(self, R_wc: FloatArray, centers_w: FloatArray, feats: F,
                  evaluation: Evaluation | None = None,
                  ) -> Linearization:
        """Return residuals and Jacobian (:mod:`pmba_ros.core.jacobian`), anchor_cols slots.

        ``evaluation`` is :meth:`evaluate` at the same state, if the caller has it.
        """

    @abstractmethod
    def retract(self, feats: F, delta: FloatArray) -> F:
        """Return features moved by delta (N, 3)."""

    @abstractmethod
    def parameter_norm_sq(self, feats: F) -> float:
        """Return the squared norm of the feature parameters (for the parameter tolerance)."""

    def turned_away(self, before: Evaluation, after: Evaluation) -> IntArray:
        """Return the features whose step turned a ray away: none here (PMBA's: its own)."""
        return np.zeros(0, np.int64)

    def halve_turning_steps(self, R_wc: FloatArray, centers_w: FloatArray, feats: F,
                            evaluation: Evaluation, d_feat: FloatArray) -> FloatArray | None:
        """Return ``d_feat`` with the steps of features that turn a ray away halved (None: none).

        Such a feature has left the region the linear model describes (a far feature along
        the path: the ray's chordal error jumps towards its bound and the whole step is
        rejected). Its step is halved, up to :data:`RAY_TURN_HALVINGS` times, then held; the
        rest of the step goes ahead. Judged with the poses held (``evaluation`` is theirs):
        a ray the poses' step turns is the trust region's to judge (halving the features
        for it trapped some at worse minima).
        """
        out = d_feat.copy()
        for halving in range(RAY_TURN_HALVINGS + 1):
            own = self.turned_away(evaluation,
                                   self.evaluate(R_wc, centers_w, self.retract(feats, out)))
            if own.size == 0:
                return out if halving else None
            out[own] *= 0.5 if halving < RAY_TURN_HALVINGS else 0.0
        return out

    def reprojection_errors_px(self, evaluation: Evaluation) -> FloatArray:
        """Return the pixel reprojection error norm of every observation, shape (K,).

        With the cameras' own ``pixel_jac``, to first order: their pixels are not the
        intrinsics' pinhole (at a fisheye's border that pinhole's are many times larger).
        """
        jac = self.obs.pixel_jac
        if jac is not None:
            d = evaluation.rays_c - self.obs.bearings_c
            out: FloatArray = np.linalg.norm(np.einsum('kij,kj->ki', jac, d), axis=1)
            return out
        return self.engine.reprojection_errors(evaluation.rays_c, self.problem.intrinsics,
                                               self.obs.cam_idx, self.obs.pixels)


class ParallaxModel(Model[ParallaxFeatures]):
    """PMBA: ray-direction errors of parallax-angle features (eqs. 6-8).

    With ``pixel_weighted`` the chordal error is taken in the observer's frame (eq. 7, the
    same norm as eq. 8) and mapped to pixels by the projection's Jacobian at the measured
    bearing, a constant matrix per observation: ``r = W (R_i^T xi(N) - v)``, W = d pi/d h(v)
    with a third row along v that keeps |r| increasing with the ray's angle
    (:func:`~pmba_ros.core.residuals.pixel_weights`).

    DEVIATION(eq. 8): the paper's isotropic chordal error weighs every ray alike, so cameras
    with long focal lengths (BAL Trafalgar: 1362-12325 px) and image borders are under-weighted
    against the pixel noise model and the pixel RMS of its optimum is a few percent above
    XYZ-BA's. The weighting keeps the parameterization, its bounded far-feature behaviour and
    the Schur structure; ``pixel_weighted=False`` gives the paper's exact objective.

    A problem with a :class:`~pmba_ros.core.problem.Rig` is evaluated on the camera poses of
    :mod:`pmba_ros.core.rig` and its observer Jacobians mapped back to the rig poses.
    """

    pixel_residuals = False
    anchor_cols = residuals.ANCHOR_COLS

    def __init__(self, problem: BAProblem, pixel_weighted: bool = False,
                 engine: Engine | None = None) -> None:
        """Bind the model; precompute the per-observation pixel weights if requested."""
        super().__init__(problem, engine)
        self.pixel_weighted = pixel_weighted
        self._weights: FloatArray | None = None
        self._ray_obs = problem.obs
        if problem.rig is not None:
            self._ray_obs = rig.camera_observations(problem.obs, problem.rig, problem.n_cams)
        if pixel_weighted:
            self.pixel_residuals = True
            v = problem.obs.bearings_c
            jac = problem.obs.pixel_jac
            if jac is None:
                jac = self.engine.projection_jacobian(v, problem.intrinsics, problem.obs.cam_idx)
            self._weights = residuals.pixel_weights(jac, v)

    def bound_to(self, problem: BAProblem) -> ParallaxModel:
        """Return a PMBA model with this one's weighting and engine, bound to ``problem``."""
        return ParallaxModel(problem, self.pixel_weighted, self.engine)

    def slots(self, feats: ParallaxFeatures) -> IntArray:
        """Return the observer, main and associate pose of each observation."""
        slots = residuals.pose_slots(feats, self._ray_obs)
        slots[:, 0] = self.obs.cam_idx     # a rig camera's observer block is its rig pose's
        return slots

    def _ray_poses(self, R_wc: FloatArray, centers_w: FloatArray,
                   ) -> tuple[FloatArray, FloatArray]:
        """Return the poses the rays are computed from (with the rig's camera poses)."""
        if self.problem.rig is None:
            return R_wc, centers_w
        return rig.camera_poses(R_wc, centers_w, self.problem.rig)

    def evaluate(self, R_wc: FloatArray, centers_w: FloatArray,
                 feats: ParallaxFeatures) -> Evaluation:
        """Return ray errors (K, 3), or pixel-weighted ones (K, 3), and R_i^T xi(N_ji)."""
        R, P = self._ray_poses(R_wc, centers_w)
        geo, rays_c, res = self.engine.rays_and_residuals(R, P, feats, self._ray_obs,
                                                          self._weights)
        return Evaluation(res, rays_c, geo)

    def linearize(self, R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                  evaluation: Evaluation | None = None,
                  ) -> Linearization:
        """Return ray errors and their analytic Jacobians (pmba.md §1.6)."""
        R, P = self._ray_poses(R_wc, centers_w)
        if evaluation is None:
            lin = self.engine.ray_jacobians(R, P, feats, self._ray_obs, self._weights)
        else:
            lin = self.engine.ray_jacobians(R, P, feats, self._ray_obs, self._weights,
                                            evaluation.geometry, evaluation.rays_c)
        if self.problem.rig is not None:
            rig.observer_to_rig(lin.rows, R_wc, self.obs, self.problem.rig)
        return lin

    def retract(self, feats: ParallaxFeatures, delta: FloatArray) -> ParallaxFeatures:
        """Return theta + d theta, Exp(A_n dn) n."""
        return residuals.retract_features(feats, delta, self.engine.sphere_retract)

    def turned_away(self, before: Evaluation, after: Evaluation) -> IntArray:
        """Return the features with a ray that a step turned away from its bearing.

        Away: from within 90 degrees of the measured bearing to beyond it
        (:meth:`halve_turning_steps`). XYZ and IDP features, the baselines', keep the plain
        trust region.
        """
        v = self.obs.bearings_c
        was = np.einsum('ki,ki->k', before.rays_c, v) > 0.0
        now = np.einsum('ki,ki->k', after.rays_c, v) > 0.0
        return np.unique(self.obs.feat_idx[was & ~now])

    def parameter_norm_sq(self, feats: ParallaxFeatures) -> float:
        """Return |theta|^2 + |n|^2."""
        return float(np.sum(feats.theta ** 2) + feats.n.shape[0])


class _PixelErrorModel(Model[F]):
    """A parameterization whose residual is the reprojection error pi(h) - (u, v) itself."""

    pixel_residuals = True

    def bound_to(self, problem: BAProblem) -> Model[F]:
        """Return a model of this parameterization with this one's engine, bound to ``problem``."""
        return type(self)(problem, self.engine)

    @abstractmethod
    def camera_rays(self, R_wc: FloatArray, centers_w: FloatArray, feats: F) -> FloatArray:
        """Return each observation's predicted direction in its camera frame, shape (K, 3)."""

    def evaluate(self, R_wc: FloatArray, centers_w: FloatArray, feats: F) -> Evaluation:
        """Return pixel errors (K, 2) and the camera rays they project."""
        h = self.camera_rays(R_wc, centers_w, feats)
        return Evaluation(baselines.pixel_errors(h, self.obs, self.problem.intrinsics), h)

    def reprojection_errors_px(self, evaluation: Evaluation) -> FloatArray:
        """Return the residual norms: they are the reprojection errors."""
        out: FloatArray = np.linalg.norm(evaluation.residuals, axis=1)
        return out


class XyzModel(_PixelErrorModel[XyzFeatures]):
    """XYZ-BA: Euclidean points, pixel errors."""

    def slots(self, feats: XyzFeatures) -> IntArray:
        """Return slot (i)."""
        return baselines.xyz_slots(self.obs)

    def camera_rays(self, R_wc: FloatArray, centers_w: FloatArray,
                    feats: XyzFeatures) -> FloatArray:
        """Return R_i^T (X - P_i)."""
        return baselines.xyz_camera_rays(R_wc, centers_w, feats, self.obs)

    def linearize(self, R_wc: FloatArray, centers_w: FloatArray, feats: XyzFeatures,
                  evaluation: Evaluation | None = None,
                  ) -> Linearization:
        """Return pixel errors and Jacobians."""
        h = evaluation.rays_c if evaluation is not None else None
        return baselines.xyz_jacobians(R_wc, centers_w, feats, self.obs,
                                       self.problem.intrinsics, h)

    def retract(self, feats: XyzFeatures, delta: FloatArray) -> XyzFeatures:
        """Return X + dX."""
        return XyzFeatures(feats.points_w + delta)

    def parameter_norm_sq(self, feats: XyzFeatures) -> float:
        """Return |X|^2."""
        return float(np.sum(feats.points_w ** 2))


class IdpModel(_PixelErrorModel[IdpFeatures]):
    """IDP-BA: inverse depth from the first observing camera, pixel errors."""

    anchor_cols = baselines.IDP_ANCHOR_COLS

    def slots(self, feats: IdpFeatures) -> IntArray:
        """Return the observer and anchor pose of each observation."""
        return baselines.idp_slots(feats, self.obs)

    def camera_rays(self, R_wc: FloatArray, centers_w: FloatArray,
                    feats: IdpFeatures) -> FloatArray:
        """Return R_i^T (R_h m + rho (P_h - P_i))."""
        return baselines.idp_camera_rays(R_wc, centers_w, feats, self.obs)

    def linearize(self, R_wc: FloatArray, centers_w: FloatArray, feats: IdpFeatures,
                  evaluation: Evaluation | None = None,
                  ) -> Linearization:
        """Return pixel errors and Jacobians."""
        h = evaluation.rays_c if evaluation is not None else None
        return baselines.idp_jacobians(R_wc, centers_w, feats, self.obs,
                                       self.problem.intrinsics, h)

    def retract(self, feats: IdpFeatures, delta: FloatArray) -> IdpFeatures:
        """Return (a, b, rho) + delta."""
        return IdpFeatures(feats.anchor_idx, feats.ab + delta[:, :2], feats.rho + delta[:, 2])

    def parameter_norm_sq(self, feats: IdpFeatures) -> float:
        """Return |(a, b, rho)|^2."""
        return float(np.sum(feats.ab ** 2) + np.sum(feats.rho ** 2))


def make_model(param: Parameterization, problem: BAProblem, *, pixel_weighted: bool = False,
               engine: Engine | None = None) -> ParallaxModel | XyzModel | IdpModel:
    """Return the model of a parameterization bound to a problem and an engine.

    Raises:
        ProblemError: For a multi-camera rig with a parameterization other than PMBA.
    """
    if param is Parameterization.PMBA:
        return ParallaxModel(problem, pixel_weighted, engine)
    if problem.rig is not None:
        msg = f'multi-camera rigs are solved with the pmba parameterization, not {param.value}'
        raise ProblemError(msg)
    if param is Parameterization.XYZ:
        return XyzModel(problem, engine)
    return IdpModel(problem, engine)
