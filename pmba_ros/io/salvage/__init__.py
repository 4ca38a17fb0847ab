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
"""Recordings that cannot be opened whole, read in the parts that can.

Each kind of storage file has its own salvage, which copies the readable messages of a
damaged file into a new, complete one and says what was lost: MCAP (:mod:`.mcap_file`).
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from tempfile import TemporaryDirectory

from pmba_ros.errors import BagError
from pmba_ros.io.bags import any_reader, error_text, storage_files
from pmba_ros.io.salvage.common import Salvaged
from pmba_ros.io.salvage.mcap_file import salvage_mcap

__all__ = ['Salvaged', 'readable_parts', 'salvage_mcap']


def readable_parts(paths: list[Path], error: BagError,
                   stack: ExitStack) -> tuple[list[Path], tuple[str, ...]]:
    """Return the storage files of ``paths`` that open, damaged MCAP files' readable copies.

    The copies go to a temporary folder that ``stack`` removes.

    Raises:
        BagError: ``error`` again if that leaves nothing to read, or a file that is not
            MCAP (a ROS 1 bag, SQLite) does not open.
    """
    files = [f for p in paths for f in (storage_files(p) or [p])]
    if not any(f.suffix == '.mcap' for f in files) and files == paths:
        raise error
    readable: list[Path] = []
    damage: list[str] = []
    tmp: Path | None = None
    for file in files:
        try:
            with any_reader([file]):
                readable.append(file)
                continue
        except BagError as err:
            if file.suffix != '.mcap':
                raise error from err
            reason = error_text(err.__cause__ or err)
        if tmp is None:
            tmp = Path(stack.enter_context(TemporaryDirectory(prefix='pmba_salvage_')))
        saved = salvage_mcap(file, tmp / f'{len(readable)}_{file.name}', reason)
        if saved is None:
            damage.append(f'{file}: cannot be opened ({reason}); no message in it is readable')
            continue
        readable.append(saved.path)
        damage.append(saved.damage)
    if not readable:
        raise error
    if not damage:   # every file opens: the folder's metadata.yaml is what is wrong
        damage = [f'{p}: {error_text(error.__cause__ or error)}; its storage files were '
                  'read one by one' for p in paths if p.is_dir()]
    return readable, tuple(damage)
