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
"""An output folder owned by one writer: its lock, and the removal of an earlier run's files."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
import os
from pathlib import Path
import shutil

from pmba_ros.errors import BagError

LOCK_FILE = '.pmba_replay.lock'


@contextmanager
def output_lock(out: Path) -> Iterator[None]:
    """Hold ``out/.pmba_replay.lock`` while replaying into ``out``.

    Raises:
        BagError: If another process holds it (a replay into the same folder).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no advisory locks on this platform
        yield
        return
    path = out / LOCK_FILE
    try:
        fh = open(path, 'a+', encoding='utf-8')
    except OSError as err:
        msg = f'{out}: cannot create the lock file: {err}'
        raise BagError(msg) from err
    with fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            fh.seek(0)
            owner = fh.read().strip() or 'unknown'
            msg = (f'{out}: another replay (process {owner}) is writing into this folder; '
                   'wait for it to finish or choose another --out')
            raise BagError(msg) from err
        fh.seek(0)
        fh.truncate()
        fh.write(f'{os.getpid()}\n')
        fh.flush()
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def remove_outputs(out: Path, names: Sequence[str]) -> None:
    """Remove an earlier run's outputs (report.json first) so none survives this run.

    Raises:
        BagError: If one cannot be removed.
    """
    for name in names:
        path = out / name
        try:
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink(missing_ok=True)
        except OSError as err:
            msg = f'{path}: cannot replace the earlier output: {err}'
            raise BagError(msg) from err
