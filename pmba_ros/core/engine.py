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
"""The engine switch: the numpy reference code or the compiled loops, chosen once.

``SolveOptions(engine=...)`` names an engine; :func:`resolve` turns the name into an
:class:`Engine` once per solve, and the solver hands that object down to the model, the
Schur structure and the anchor search. ``'auto'`` is the compiled engine when numba imports
(the ``fast`` extra) and is not turned off with ``PMBA_NUMBA=0`` (:mod:`pmba_ros.core.jit`),
else the numpy engine; ``'numpy'`` and ``'compiled'`` ask for one.

Both engines give the same numbers to rounding (the tests run both). The numpy engine forms
everything from batched products: the reference, and the faster one on large problems where
a few dozen numpy calls per step are amortised; the compiled loops (:mod:`pmba_ros.core.compiled`)
visit each observation once, which wins on sliding windows of a few thousand observations.
"""

from __future__ import annotations

from enum import Enum
from typing import Protocol

import numpy as np
from pmba_ros._typing import BoolArray, FloatArray, IntArray
from pmba_ros.core import anchor_search, camera, jit, normal_equations, residuals, sphere
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.compiled import anchor_search as compiled_anchor_search
from pmba_ros.core.compiled import assembly as compiled_assembly
from pmba_ros.core.compiled import camera as compiled_camera
from pmba_ros.core.compiled import loss as compiled_loss
from pmba_ros.core.compiled import residuals as compiled_residuals
from pmba_ros.core.compiled.plan import CompiledSchurPlan
from pmba_ros.core.jacobian import Linearization
from pmba_ros.core.loss import Loss, robust_cost, robust_weights
from pmba_ros.core.normal_equations import (
    NormalEquations,
    ScaledSystem,
    SchurLayout,
    SchurPlan,
    SchurStructure,
)
from pmba_ros.core.numpy_schur import NumpySchurPlan
from pmba_ros.core.problem import Observations, ParallaxFeatures
from pmba_ros.core.residuals import RayGeometry
from pmba_ros.errors import SolverError


class EngineName(str, Enum):
    """Names of the engines (``SolveOptions.engine``, ``pmba solve --engine``)."""

    AUTO = 'auto'
    NUMPY = 'numpy'
    COMPILED = 'compiled'


class Engine(Protocol):
    """The numerical kernels a solve needs, from numpy or from compiled loops.

    Arguments and results are those of the numpy references named in each docstring.
    """

    name: EngineName

    def rays_and_residuals(self, R_wc: FloatArray, centers_w: FloatArray,
                           feats: ParallaxFeatures, obs: Observations,
                           weights: FloatArray | None,
                           ) -> tuple[RayGeometry, FloatArray, FloatArray]:
        """Return :func:`pmba_ros.core.residuals.rays_and_residuals`."""

    def ray_jacobians(self, R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                      obs: Observations, weights: FloatArray | None,
                      geo: RayGeometry | None = None, rays_c: FloatArray | None = None,
                      ) -> Linearization:
        """Return :func:`pmba_ros.core.residuals.ray_jacobians`."""

    def sphere_retract(self, n: FloatArray, delta: FloatArray) -> FloatArray:
        """Return :func:`pmba_ros.core.sphere.retract`."""

    def reprojection_errors(self, rays_c: FloatArray, intr: Intrinsics, cam_idx: IntArray,
                            pixels: FloatArray) -> FloatArray:
        """Return |camera.project(rays_c) - pixels| per observation, shape (K,)."""

    def projection_jacobian(self, h_c: FloatArray, intr: Intrinsics,
                            cam_idx: IntArray) -> FloatArray:
        """Return the Jacobian of :func:`pmba_ros.core.camera.projection_jacobian`."""

    def robust_cost(self, res: FloatArray, loss: Loss, scale: float) -> float:
        """Return :func:`pmba_ros.core.loss.robust_cost`, inf if a residual is not finite."""

    def robust_rows(self, lin: Linearization, loss: Loss, scale: float) -> Linearization:
        """Return rows scaled by :func:`pmba_ros.core.loss.robust_weights` (may reuse lin's)."""

    def widest_pairs(self, rays: FloatArray, cam_idx: IntArray, starts: IntArray,
                     allowed: BoolArray | None, close: IntArray, n_cams: int,
                     ) -> tuple[IntArray, IntArray, BoolArray]:
        """Return :func:`pmba_ros.core.anchor_search.widest_pairs`."""

    def jacobi_scale(self, structure: SchurStructure, eqs: NormalEquations,
                     col_mask: BoolArray, jacobi: bool) -> ScaledSystem:
        """Return :func:`pmba_ros.core.normal_equations.jacobi_scale` (W scaled in place)."""

    def schur_plan(self, layout: SchurLayout) -> SchurPlan:
        """Return this engine's plan of the normal equations of ``layout``."""

    def schur_anchors(self, cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray,
                      starts: IntArray) -> tuple[IntArray, IntArray, BoolArray]:
        """Return :func:`pmba_ros.core.normal_equations.anchors`."""


class NumpyEngine:
    """The numpy reference code (batched products and scatter matrices)."""

    name = EngineName.NUMPY

    def rays_and_residuals(self, R_wc: FloatArray, centers_w: FloatArray,
                           feats: ParallaxFeatures, obs: Observations,
                           weights: FloatArray | None,
                           ) -> tuple[RayGeometry, FloatArray, FloatArray]:
        """Return :func:`pmba_ros.core.residuals.rays_and_residuals`."""
        return residuals.rays_and_residuals(R_wc, centers_w, feats, obs, weights)

    def ray_jacobians(self, R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                      obs: Observations, weights: FloatArray | None,
                      geo: RayGeometry | None = None, rays_c: FloatArray | None = None,
                      ) -> Linearization:
        """Return :func:`pmba_ros.core.residuals.ray_jacobians`."""
        return residuals.ray_jacobians(R_wc, centers_w, feats, obs, weights, geo, rays_c)

    def sphere_retract(self, n: FloatArray, delta: FloatArray) -> FloatArray:
        """Return :func:`pmba_ros.core.sphere.retract`."""
        return sphere.retract(n, delta)

    def reprojection_errors(self, rays_c: FloatArray, intr: Intrinsics, cam_idx: IntArray,
                            pixels: FloatArray) -> FloatArray:
        """Return |camera.project(rays_c) - pixels| per observation, shape (K,)."""
        out: FloatArray = np.linalg.norm(camera.project(rays_c, intr, cam_idx) - pixels, axis=1)
        return out

    def projection_jacobian(self, h_c: FloatArray, intr: Intrinsics,
                            cam_idx: IntArray) -> FloatArray:
        """Return the Jacobian of :func:`pmba_ros.core.camera.projection_jacobian`."""
        return camera.projection_jacobian(h_c, intr, cam_idx)[1]

    def robust_cost(self, res: FloatArray, loss: Loss, scale: float) -> float:
        """Return :func:`pmba_ros.core.loss.robust_cost`, inf if a residual is not finite."""
        if not np.all(np.isfinite(res)):
            return np.inf
        return robust_cost(res, loss, scale)

    def robust_rows(self, lin: Linearization, loss: Loss, scale: float) -> Linearization:
        """Return rows scaled by :func:`pmba_ros.core.loss.robust_weights` (new rows)."""
        return lin.scaled(robust_weights(lin.residuals, loss, scale))

    def widest_pairs(self, rays: FloatArray, cam_idx: IntArray, starts: IntArray,
                     allowed: BoolArray | None, close: IntArray, n_cams: int,
                     ) -> tuple[IntArray, IntArray, BoolArray]:
        """Return :func:`pmba_ros.core.anchor_search.widest_pairs`."""
        return anchor_search.widest_pairs(rays, cam_idx, starts, allowed, close, n_cams)

    def jacobi_scale(self, structure: SchurStructure, eqs: NormalEquations,
                     col_mask: BoolArray, jacobi: bool) -> ScaledSystem:
        """Return :func:`pmba_ros.core.normal_equations.jacobi_scale` (W scaled in place)."""
        return normal_equations.jacobi_scale(structure, eqs, col_mask, jacobi)

    def schur_plan(self, layout: SchurLayout) -> SchurPlan:
        """Return the :class:`~pmba_ros.core.numpy_schur.NumpySchurPlan` of ``layout``."""
        return NumpySchurPlan.build(layout)

    def schur_anchors(self, cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray,
                      starts: IntArray) -> tuple[IntArray, IntArray, BoolArray]:
        """Return :func:`pmba_ros.core.normal_equations.anchors`."""
        return normal_equations.anchors(cam_idx, feat_idx, slot_pose, starts)


class CompiledEngine:
    """The compiled loops of :mod:`pmba_ros.core.compiled` (numba)."""

    name = EngineName.COMPILED

    def rays_and_residuals(self, R_wc: FloatArray, centers_w: FloatArray,
                           feats: ParallaxFeatures, obs: Observations,
                           weights: FloatArray | None,
                           ) -> tuple[RayGeometry, FloatArray, FloatArray]:
        """Return :func:`pmba_ros.core.residuals.rays_and_residuals`, in one pass."""
        return compiled_residuals.pmba_rays(R_wc, centers_w, feats, obs, weights)

    def ray_jacobians(self, R_wc: FloatArray, centers_w: FloatArray, feats: ParallaxFeatures,
                      obs: Observations, weights: FloatArray | None,
                      geo: RayGeometry | None = None, rays_c: FloatArray | None = None,
                      ) -> Linearization:
        """Return :func:`pmba_ros.core.residuals.ray_jacobians`."""
        if geo is None:
            geo = self.rays_and_residuals(R_wc, centers_w, feats, obs, None)[0]
        if weights is not None and rays_c is None:
            rays_c = residuals.camera_rays_from(geo, R_wc, obs)
        lin = Linearization.empty(obs.cam_idx.shape[0], 3, residuals.ANCHOR_COLS)
        compiled_residuals.pmba_rows(obs, feats, R_wc, geo, weights, rays_c, lin.rows)
        return lin

    def sphere_retract(self, n: FloatArray, delta: FloatArray) -> FloatArray:
        """Return :func:`pmba_ros.core.sphere.retract`."""
        return compiled_residuals.sphere_retract(n, delta)

    def reprojection_errors(self, rays_c: FloatArray, intr: Intrinsics, cam_idx: IntArray,
                            pixels: FloatArray) -> FloatArray:
        """Return |camera.project(rays_c) - pixels| per observation, shape (K,)."""
        return compiled_camera.reprojection_errors(rays_c, intr, cam_idx, pixels)

    def projection_jacobian(self, h_c: FloatArray, intr: Intrinsics,
                            cam_idx: IntArray) -> FloatArray:
        """Return the Jacobian of :func:`pmba_ros.core.camera.projection_jacobian`."""
        return compiled_camera.projection_jacobian(h_c, intr, cam_idx)

    def robust_cost(self, res: FloatArray, loss: Loss, scale: float) -> float:
        """Return :func:`pmba_ros.core.loss.robust_cost`, inf if a residual is not finite."""
        return compiled_loss.robust_cost(res, loss.value, scale)

    def robust_rows(self, lin: Linearization, loss: Loss, scale: float) -> Linearization:
        """Return ``lin`` with its rows scaled in place by the robust weights."""
        compiled_loss.robust_scale_rows(lin.rows, loss.value, scale)
        return lin

    def widest_pairs(self, rays: FloatArray, cam_idx: IntArray, starts: IntArray,
                     allowed: BoolArray | None, close: IntArray, n_cams: int,
                     ) -> tuple[IntArray, IntArray, BoolArray]:
        """Return :func:`pmba_ros.core.anchor_search.widest_pairs`."""
        return compiled_anchor_search.widest_pairs(rays, cam_idx, starts, allowed, close,
                                                   n_cams)

    def jacobi_scale(self, structure: SchurStructure, eqs: NormalEquations,
                     col_mask: BoolArray, jacobi: bool) -> ScaledSystem:
        """Return :func:`pmba_ros.core.normal_equations.jacobi_scale`, U, V and g in one pass."""
        U, V, g_pose, g_feat, c_pose, c_feat, *rest = compiled_assembly.jacobi_scale(
            eqs.U, eqs.V, eqs.g_pose, eqs.g_feat, structure.pair_rows, structure.pair_cols,
            col_mask, jacobi)
        structure.plan.scale_w(eqs.W, c_pose, c_feat)   # the plan's W layout and arithmetic
        return ScaledSystem(NormalEquations(U, eqs.W, V, g_pose, g_feat), c_pose, c_feat,
                            *rest)

    def schur_plan(self, layout: SchurLayout) -> SchurPlan:
        """Return the compiled plan, or numpy's above the pair index's size limit.

        The compiled plan's (n, n) pair index grows with the square of the free poses.
        """
        if layout.n_blocks > compiled_assembly.MAX_BLOCKS:
            return NumpySchurPlan.build(layout)
        return CompiledSchurPlan.build(layout)

    def schur_anchors(self, cam_idx: IntArray, feat_idx: IntArray, slot_pose: IntArray,
                      starts: IntArray) -> tuple[IntArray, IntArray, BoolArray]:
        """Return :func:`pmba_ros.core.normal_equations.anchors`, one pass per slot."""
        return compiled_assembly.anchors(cam_idx, slot_pose, starts)


NUMPY = NumpyEngine()
COMPILED = CompiledEngine()


def compiled_available() -> bool:
    """Return whether the compiled engine can run (numba imported, not ``PMBA_NUMBA=0``)."""
    return jit.NUMBA is not None


def compiled_ready() -> bool:
    """Return whether ``'auto'`` runs the compiled loops now (not compiling in the background)."""
    return compiled_available() and not jit.NOT_READY.is_set()


def resolve(name: EngineName | str = EngineName.AUTO) -> Engine:
    """Return the engine of a name; ``'auto'`` is the compiled one where it is ready.

    Raises:
        ValueError: If the name is not an engine's.
        SolverError: If ``'compiled'`` is asked for without numba (or with ``PMBA_NUMBA=0``).
    """
    kind = EngineName(name)
    if kind is EngineName.NUMPY:
        return NUMPY
    if compiled_ready() or (kind is EngineName.COMPILED and compiled_available()):
        return COMPILED
    if kind is EngineName.AUTO:
        return NUMPY
    msg = ("engine 'compiled' needs numba (pip install numba, the `fast` extra), and "
           'PMBA_NUMBA not set to 0')
    raise SolverError(msg)


def default_engine() -> Engine:
    """Return the ``'auto'`` engine, for callers that were not handed one."""
    return resolve(EngineName.AUTO)
