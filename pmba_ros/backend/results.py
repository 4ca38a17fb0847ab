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
"""The back-end's results as files other tools read: TUM trajectories and a PLY map."""

from __future__ import annotations

import logging
import os
from pathlib import Path

from pmba_ros._typing import FloatArray
from pmba_ros.eval.trajectory import Trajectory, write_tum

logger = logging.getLogger(__name__)

SAVED_FILES = ('pmba_keyframes.tum', 'frontend_keyframes.tum', 'pmba_landmarks.ply')
"""What :func:`save_results` writes, in order."""


def save_results(directory: str | os.PathLike[str], optimized: Trajectory, frontend: Trajectory,
                 landmarks: FloatArray) -> list[Path]:
    """Write the trajectories (TUM) and the landmarks (ASCII PLY) into ``directory``.

    Returns:
        The written files, :data:`SAVED_FILES` in ``directory``.

    Raises:
        OSError: If the directory cannot be created.
        pmba_ros.errors.FormatError: If a file cannot be written.
    """
    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    paths = [root / name for name in SAVED_FILES]
    write_tum(paths[0], optimized)
    write_tum(paths[1], frontend)
    header = (f'ply\nformat ascii 1.0\nelement vertex {landmarks.shape[0]}\nproperty float x\n'
              'property float y\nproperty float z\nend_header\n')
    body = ''.join(f'{x:.6g} {y:.6g} {z:.6g}\n' for x, y, z in landmarks.tolist())
    paths[2].write_text(header + body, encoding='utf-8')
    logger.info('saved %s', ', '.join(str(p) for p in paths))
    return paths
