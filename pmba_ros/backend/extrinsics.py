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
"""Body -> camera extrinsics: rigid transforms, parameters and a small TF tree (no ROS imports).

Front-ends such as VINS and OpenVINS publish keyframe poses of the body (IMU) frame; the
problem is solved over camera poses. :class:`Rigid` is one transform ``T_ab`` (rotation
``R_ab`` and translation ``t_ab``: ``x_a = R_ab x_b + t_ab``), :func:`extrinsics_from_params`
reads the ``camera_extrinsics`` parameter and :class:`TransformTree` collects ``/tf`` and
``/tf_static`` edges so the body -> camera chain can be looked up between any two frames of
one tree.

With the body pose ``T_wb`` and the extrinsic ``T_bc`` the camera pose is
``T_wc = T_wb T_bc``: ``R_wc = R_wb R_bc`` and camera centre ``C_wc = C_wb + R_wb t_bc``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import so3
from pmba_ros.errors import MessageError

EXTRINSIC_VALUES = 7
"""Values per camera in ``camera_extrinsics``: x, y, z, qx, qy, qz, qw (body -> camera)."""


@dataclass(frozen=True, eq=False)
class Rigid:
    """A rigid transform T_ab: ``x_a = rotation @ x_b + translation``.

    Attributes:
        rotation: R_ab, shape (3, 3).
        translation: t_ab (origin of b in a), shape (3,), m.
    """

    rotation: FloatArray
    translation: FloatArray

    @classmethod
    def identity(cls) -> Rigid:
        """Return the identity."""
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_xyz_quat(cls, xyz: Sequence[float] | FloatArray, quat_xyzw: Sequence[float] |
                      FloatArray, what: str = 'transform') -> Rigid:
        """Build a transform from a translation and a unit quaternion (x, y, z, w).

        Raises:
            MessageError: On non-finite values or a zero-norm quaternion.
        """
        t = np.asarray(xyz, dtype=np.float64).reshape(-1)
        q = np.asarray(quat_xyzw, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or q.shape != (4,) or not np.all(np.isfinite(np.r_[t, q])):
            msg = f'{what}: need 3 finite translation and 4 finite quaternion values'
            raise MessageError(msg)
        norm = float(np.linalg.norm(q))
        if norm < 1e-9:
            msg = f'{what}: zero-norm quaternion'
            raise MessageError(msg)
        return cls(so3.from_quat_xyzw(q / norm), t)

    @property
    def is_identity(self) -> bool:
        """Return True for the identity (to 1e-12)."""
        return bool(np.allclose(self.rotation, np.eye(3), atol=1e-12)
                    and np.allclose(self.translation, 0.0, atol=1e-12))

    def inverse(self) -> Rigid:
        """Return T_ba."""
        return Rigid(self.rotation.T, -self.rotation.T @ self.translation)

    def __matmul__(self, other: Rigid) -> Rigid:
        """Return the composition ``self * other`` (T_ab * T_bc = T_ac)."""
        return Rigid(self.rotation @ other.rotation,
                     self.rotation @ other.translation + self.translation)

    def apply_to_poses(self, R_w: FloatArray, C_w: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Right-compose poses (R_wa (..., 3, 3), centres (..., 3)) with T_ab: return T_wb."""
        return R_w @ self.rotation, C_w + R_w @ self.translation

    def to_flat(self) -> list[float]:
        """Return x, y, z, qx, qy, qz, qw."""
        return [*self.translation.tolist(), *so3.to_quat_xyzw(self.rotation).tolist()]


def extrinsics_from_params(values: Sequence[float], num_cams: int) -> list[Rigid] | None:
    """Read ``camera_extrinsics``: 7 values (x, y, z, qx, qy, qz, qw) per camera id.

    Args:
        values: The flat parameter (empty: not given).
        num_cams: Camera count; the list must hold ``7 * num_cams`` values.

    Returns:
        One body -> camera transform per camera id, or None if ``values`` is empty.

    Raises:
        ValueError: On a wrong length or invalid values, naming the parameter.
    """
    flat = [float(v) for v in values]
    if not flat:
        return None
    if len(flat) != EXTRINSIC_VALUES * num_cams:
        cameras, rest = divmod(len(flat), EXTRINSIC_VALUES)
        fix = (f'set num_cams: {cameras}, or give {EXTRINSIC_VALUES * num_cams} values'
               if not rest else f'{len(flat)} is not a multiple of {EXTRINSIC_VALUES}')
        msg = (f'parameter camera_extrinsics: expected {EXTRINSIC_VALUES} values (x, y, z, qx, '
               f'qy, qz, qw) per camera for num_cams={num_cams}, got {len(flat)}: {fix}')
        raise ValueError(msg)
    out = []
    for cam in range(num_cams):
        chunk = flat[EXTRINSIC_VALUES * cam:EXTRINSIC_VALUES * (cam + 1)]
        try:
            out.append(Rigid.from_xyz_quat(chunk[:3], chunk[3:], f'camera_extrinsics[{cam}]'))
        except MessageError as err:
            msg = f'parameter {err}'
            raise ValueError(msg) from err
    return out


class TransformTree:
    """Latest transform of every ``/tf`` and ``/tf_static`` edge, with chain lookup.

    A frame has one parent (as in tf2); a later transform of the same edge replaces the
    earlier one. Lookups compose the edges through the closest common ancestor.
    """

    def __init__(self) -> None:
        """Create an empty tree."""
        self._parent: dict[str, tuple[str, Rigid]] = {}

    def __len__(self) -> int:
        """Return the number of edges."""
        return len(self._parent)

    def add(self, parent: str, child: str, transform: Rigid) -> None:
        """Set the edge parent -> child (T_parent_child)."""
        parent, child = parent.lstrip('/'), child.lstrip('/')
        if parent and child and parent != child:
            self._parent[child] = (parent, transform)

    def add_message(self, msg: Any) -> int:
        """Add every transform of a ``tf2_msgs/TFMessage`` (any backend).

        Returns:
            The number of transforms added.

        Raises:
            MessageError: If the message is not a TFMessage or a transform is invalid.
        """
        try:
            items = list(msg.transforms)
        except (AttributeError, TypeError) as err:
            msg_ = f'expected tf2_msgs/msg/TFMessage, got {type(msg).__name__}'
            raise MessageError(msg_) from err
        for item in items:
            tr = item.transform
            rigid = Rigid.from_xyz_quat(
                [tr.translation.x, tr.translation.y, tr.translation.z],
                [tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w],
                f'transform {item.header.frame_id} -> {item.child_frame_id}')
            self.add(str(item.header.frame_id), str(item.child_frame_id), rigid)
        return len(items)

    def _to_root(self, frame: str) -> dict[str, Rigid]:
        """Return {ancestor: T_root_ancestor} for frame and each ancestor (root = topmost)."""
        names = [frame]
        edges: list[Rigid] = []  # edges[k] = T_{names[k+1], names[k]}
        while names[-1] in self._parent:
            parent, edge = self._parent[names[-1]]
            if parent in names:  # a cycle: stop (tf2 rejects those too)
                break
            names.append(parent)
            edges.append(edge)
        out = {names[-1]: Rigid.identity()}
        for k in range(len(edges) - 1, -1, -1):
            out[names[k]] = out[names[k + 1]] @ edges[k]
        return out

    def lookup(self, parent: str, child: str) -> Rigid | None:
        """Return T_parent_child through the tree, or None if the frames are not connected."""
        parent, child = parent.lstrip('/'), child.lstrip('/')
        if not parent or not child:
            return None
        if parent == child:
            return Rigid.identity()
        up_p = self._to_root(parent)
        up_c = self._to_root(child)
        if not any(name in up_p for name in up_c):
            return None
        # One parent per frame: connected frames share the topmost ancestor (the root).
        return up_p[parent].inverse() @ up_c[child]
