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
"""``pmba solve`` on COLMAP models with rigs and frames: each rig held rigid.

A model whose frames' rigs have more than one camera is solved with one pose per frame
(:mod:`pmba_ros.io.colmap_rig_problem`): ``--init file`` from the frames' poses; ``--init
global`` runs the global initialization over the images as independent poses, takes each
frame's pose from its initialized images (the rig's scale fitted to its baselines) and then
solves the rig problem. The refined frames are written to ``frames``, the images' poses
through their rig (``cam_from_world = sensor_from_rig * rig_from_world``) and the rigs as read.

A model whose rigs have one camera each is solved as independent images, as one without
rigs; its frames are written from the refined images. A model whose rigs cannot be held (a
camera without ``sensor_from_rig``; or ``--param xyz`` / ``idp`` / ``--compare``, which solve
no rigs) is solved as independent images and written without rigs and frames, with a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TYPE_CHECKING

import numpy as np
from pmba_ros.io import colmap, colmap_rigs
from pmba_ros.io import colmap_rig_problem as rp
from pmba_ros.io.colmap_poses import poses_from_colmap
from pmba_ros.io.solution_frame import finite_points, in_model_frame

if TYPE_CHECKING:
    from pmba_ros._typing import IntArray
    from pmba_ros.core.problem import BAProblem
    from pmba_ros.core.solve import SolveOptions, SolveResult
    from pmba_ros.init.options import InitResult

__all__ = ['RigInit', 'RigModel', 'global_rig_init', 'load_rig_model', 'write_frames_of_images',
           'write_rig_model']


@dataclass(frozen=True, eq=False)
class RigModel:
    """A COLMAP model with rigs and frames, and the problem ``pmba solve`` solves.

    Attributes:
        model: The model's cameras, images and points.
        rigs: Its rigs and frames.
        images: Its independent-image problem (:func:`~pmba_ros.io.colmap.to_problem`).
        layout: Its images' poses and rig cameras.
        problem: The problem solved: the rig problem from the frames' poses if ``held``,
            else ``images``.
        held: The rigs are held rigid (a rig with several cameras, PMBA).
        written: Rigs and frames are written with the refined model.
        warnings: What the user should know about how the rigs were treated.
    """

    model: colmap.ColmapModel
    rigs: colmap_rigs.ColmapRigs
    images: BAProblem
    layout: rp.RigLayout | None
    problem: BAProblem
    held: bool
    written: bool
    warnings: list[str] = field(default_factory=list)


def load_rig_model(path: Path, rigid: bool) -> RigModel | None:
    """Read a COLMAP model's rigs and frames; None for a model without them.

    Args:
        path: The model's directory.
        rigid: The solve can hold rigs (PMBA, one method).

    Raises:
        FormatError: If the model, rigs or frames are malformed or inconsistent.
    """
    if not any((path / f'{name}{ext}').is_file() for name in ('rigs', 'frames')
               for ext in ('.bin', '.txt')):
        return None
    model = colmap.read_colmap(path)
    rigs = colmap_rigs.read_rigs(path, model.images)
    if rigs is None:
        return None
    images, image_ids = colmap.to_problem(model)
    multi = rigs.has_multi_camera_rig()
    missing = rp.unknown_offsets(rigs)
    if missing or (multi and not rigid):
        why = (f'{", ".join(missing)} without sensor_from_rig' if missing
               else 'only --param pmba without --compare holds rigs')
        text = (f'{rigs.rigs_path}: rigs not held rigid ({why}): the images are solved as '
                'independent poses and the refined model is written without rigs and frames')
        return RigModel(model, rigs, images, None, images, False, False, [text])
    layout = rp.rig_layout(model, rigs, image_ids)
    problem = images
    if multi:
        assert images.points_w is not None   # a COLMAP model stores its points
        problem, _ = rp.to_rig_problem(images, layout, layout.R_wc, layout.centers_w,
                                       images.points_w)
    return RigModel(model, rigs, images, layout, problem, multi, True)


@dataclass(frozen=True, eq=False)
class RigInit:
    """A global initialization over the images, then the rig problem solved from it.

    Attributes:
        init: The initialization over the images.
        solve: The rig problem's solve.
        camera_index: The layout pose of each solved pose, shape (P,).
        scale: Scale applied to the initialization to fit the rigs' baselines.
    """

    init: InitResult
    solve: SolveResult
    camera_index: IntArray
    scale: float
    ba_invocations: int = 2

    def to_report(self) -> dict[str, Any]:
        """Return the initialization's report, with the rig stage."""
        report = self.init.to_report()
        report['rigs'] = {'frames_initialized': int(self.camera_index.shape[0]),
                          'scale_to_rig_baselines': self.scale}
        return report


def global_rig_init(rm: RigModel, options: SolveOptions, callback: Any = None,
                    progress: Any = None) -> RigInit:
    """Run the global initialization over the images, then solve the rig problem from it.

    Raises:
        FormatError: If the rig problem cannot be built; InitError from the initialization.
    """
    from pmba_ros.core.solve import solve
    from pmba_ros.init.pipeline import global_init, InitOptions

    assert rm.layout is not None
    init = global_init(rm.images, InitOptions(solve_options=options), progress=progress)
    res = init.solve
    poses, R_wr, C_r, scale = rp.frames_from_images(rm.layout, init.camera_index, res.R_wc,
                                                    res.centers_w)
    M = rm.layout.frame_ids.shape[0]
    R_all, C_all = np.tile(np.eye(3), (M, 1, 1)), np.zeros((M, 3))
    R_all[poses], C_all[poses] = R_wr, C_r
    points = np.full((rm.images.n_feats, 3), np.nan)
    # Points at infinity start far along their rays (the rig problem starts from points).
    points[init.feature_index] = scale * finite_points(res)
    problem, poses = rp.to_rig_problem(rm.images, rm.layout, R_all, C_all, points, poses)
    return RigInit(init, solve(problem, options, callback=callback), poses, scale)


def write_rig_model(out: Path, source: Path, rm: RigModel, result: SolveResult,
                    camera_index: IntArray | None) -> None:
    """Write a rig problem's refined model: frames, images through their rigs, points.

    Args:
        out: The output directory.
        source: The input model's directory (its form, text or binary, is kept).
        rm: The model.
        result: The rig problem's solve.
        camera_index: The layout pose of each solved pose (None: all, in order).
    """
    assert rm.layout is not None and rm.images.points_w is not None
    layout = rm.layout
    poses = np.arange(layout.frame_ids.shape[0]) if camera_index is None else camera_index
    point_ids = result.problem.feature_ids
    order = np.argsort(rm.images.feature_ids)
    rows = order[np.searchsorted(rm.images.feature_ids[order], point_ids)]
    R_wr, C_r, points = in_model_frame(result, layout.R_wc[poses], layout.centers_w[poses],
                                       rm.images.points_w[rows], with_scale=not layout.metric)
    index, R_wc, centers = rp.image_poses(layout, poses, R_wr, C_r)
    refined = colmap.updated(rm.model, layout.image_ids[index], R_wc, centers, point_ids, points)
    binary = (source / 'cameras.bin').is_file()
    colmap.write_colmap(out, refined, binary=binary)
    colmap_rigs.write_rigs(out, rp.updated_frames(rm.rigs, layout, poses, R_wr, C_r), binary)


def write_frames_of_images(out: Path, source: Path, rm: RigModel) -> None:
    """Write the frames of a model of one-camera rigs from its refined images in ``out``."""
    assert rm.layout is not None
    model = colmap.read_colmap(out)
    image_ids = np.array(sorted(model.images), dtype=np.int64)   # the layout's order
    q = np.array([model.images[int(i)].qvec for i in image_ids])
    t = np.array([model.images[int(i)].tvec for i in image_ids])
    R_wc, centers = poses_from_colmap(q, t)
    poses, R_wr, C_r, _ = rp.frames_from_images(rm.layout, np.arange(image_ids.shape[0]),
                                                R_wc, centers, fit_scale=False)
    colmap_rigs.write_rigs(out, rp.updated_frames(rm.rigs, rm.layout, poses, R_wr, C_r),
                           binary=(source / 'cameras.bin').is_file())
