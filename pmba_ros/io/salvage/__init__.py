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
"""Recordings that cannot be opened whole, or that a recorder did not close, read in parts.

A recorder that is killed, or a disk that fills up, leaves a recording that rosbags refuses
whole or reads silently short. :func:`readable_parts` reads such recordings file by file and
says what was damaged. Each kind of storage file has its own salvage, which copies the
readable messages of a damaged file into a new, complete one in a temporary folder (never in
the recording's folder): MCAP without its index (:mod:`.mcap_file`), SQLite cut short or with
damaged pages and SQLite's journal left beside a file (:mod:`.sqlite_file`), and a ROS 1 bag
without its index (:mod:`.ros1_file`). A rosbag2 folder without ``metadata.yaml``, or whose
``metadata.yaml`` is wrong (:mod:`.metadata`), is read by its storage files, which rosbags
opens alone. An MCAP file of ROS 1 messages, which rosbags refuses too, is read by its copy
as a ROS 1 bag (:mod:`.ros1_mcap`), damage or not.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, ExitStack
import logging
from pathlib import Path
from tempfile import TemporaryDirectory

from pmba_ros.errors import BagError
from pmba_ros.io.bags import any_reader, error_text, is_ros1, storage_files
from pmba_ros.io.salvage.common import Salvaged
from pmba_ros.io.salvage.mcap_file import salvage_mcap
from pmba_ros.io.salvage.metadata import metadata_refusal, newer_version, opened_whole, unlisted
from pmba_ros.io.salvage.ros1_file import ACTIVE_SUFFIX, salvage_ros1
from pmba_ros.io.salvage.sqlite_file import index_damage, journal_of, recover_journal, salvage_db3

logger = logging.getLogger(__name__)

__all__ = ['Salvaged', 'mcap_copies', 'opened_whole', 'readable_parts', 'suspect']

Salvage = Callable[[Path, Path, str], Salvaged | None]
"""``(damaged file, copy to write, what is wrong with it) -> what was copied``."""


def _salvage_of(path: Path) -> Salvage | None:
    """Return the salvage for the kind of storage file ``path`` is, if there is one."""
    if is_ros1(path):
        return salvage_ros1
    return {'.mcap': salvage_mcap, '.db3': salvage_db3}.get(path.suffix)


def _active(path: Path) -> bool:
    """Return True for a ROS 1 bag that ``rosbag record`` had not closed (``NAME.bag.active``)."""
    return is_ros1(path) and path.suffix == ACTIVE_SUFFIX


def _open_error(path: Path) -> BagError | None:
    """Return why rosbags does not open ``path`` alone, or None if it does."""
    try:
        with any_reader([path]):
            return None
    except BagError as err:
        return err


def _files(paths: Sequence[Path]) -> list[Path]:
    """Return the storage files of ``paths`` (a folder's, or the file itself)."""
    return [f for p in paths for f in (storage_files(p) or [p])]


def _without_metadata(paths: Sequence[Path]) -> list[Path]:
    """Return the folders among ``paths`` that have no ``metadata.yaml``."""
    return [p for p in paths if p.is_dir() and not (p / 'metadata.yaml').exists()]


def suspect(paths: Sequence[Path]) -> bool:
    """Return True if recordings may open and still read short: then read them file by file.

    A rosbag2 folder without ``metadata.yaml`` (written last, when the recorder closes the
    recording), with storage files it does not list or of a metadata version rosbags refuses,
    a ROS 1 ``.bag.active`` file, a ``.db3`` file with SQLite's journal beside it (which
    rosbags does not read), or given alone (not in a closed recording's folder) with a
    timestamp index that disagrees with its rows (:func:`.sqlite_file.index_damage`).
    """
    return bool(_without_metadata(paths)) or any(
        unlisted(p) or newer_version(p) for p in paths) or any(
        _active(f) or (f.suffix == '.db3' and (journal_of(f) is not None or (
            f in paths and index_damage(f) is not None))) for f in _files(paths))


class _Scratch:
    """Names for copies in a temporary folder made at the first copy, removed by ``stack``."""

    def __init__(self, stack: ExitStack) -> None:
        self._stack = stack
        self._dir: Path | None = None
        self._count = 0

    def path(self, name: str) -> Path:
        """Return a new path in the folder ending in ``name``."""
        if self._dir is None:
            self._dir = Path(self._stack.enter_context(TemporaryDirectory(prefix='pmba_salvage_')))
        self._count += 1
        return self._dir / f'{self._count}_{name}'


def readable_parts(paths: Sequence[Path], error: BagError | None, stack: ExitStack,
                   said: Sequence[str] = ()) -> tuple[list[Path], tuple[str, ...]]:
    """Return storage files to read for ``paths``: those that open, readable copies of the rest.

    Args:
        paths: The recordings as given (folders and files).
        error: Why they did not open together, or None if they were not tried (:func:`suspect`)
            or a folder's metadata.yaml was found wrong (``said``).
        stack: Removes the copies' temporary folder when it closes.
        said: What the folders' metadata.yaml says that their files belie
            (:func:`.metadata.contradictions`), one line each.

    Returns:
        The files to read, and what was damaged in ``paths`` (one line each, the files' first).

    Raises:
        BagError: If that leaves nothing to read (``error`` again, if given), or a file of no
            kind that can be salvaged does not open.
    """
    damage: list[str] = []
    readable: list[Path] = []
    scratch = _Scratch(stack)
    for file in _files(paths):
        source = file
        journal = journal_of(file) if file.suffix == '.db3' else None
        if journal is not None:
            source = scratch.path(file.name)
            damage.append(f'{file}: {recover_journal(file, journal, source)}')
        salvage: Salvage
        if _active(file):   # rosbags takes it for an unknown ROS 2 storage format
            salvage = salvage_ros1
            reason = f'not closed by its recorder (no index, still named {ACTIVE_SUFFIX})'
        elif (failed := _open_error(source)) is not None:
            found = _salvage_of(file)
            if found is None:
                raise (error or failed) from failed
            reason = f'cannot be opened ({error_text(failed.__cause__ or failed)})'
            salvage = found
        elif file.suffix == '.db3' and (short := index_damage(source)) is not None:
            salvage, reason = salvage_db3, short
        else:
            readable.append(source)
            continue
        saved = salvage(source, scratch.path(file.name.removesuffix(ACTIVE_SUFFIX)), reason)
        if saved is None:
            damage.append(f'{file}: {reason}; no message in it is readable')
            continue
        readable.append(saved.path)
        if saved.damage:
            damage.append(f'{file}: {saved.damage}')
        else:   # a whole file copied into a format rosbags reads (ROS 1 messages in MCAP)
            logger.info('%s: read through a copy (%s)', file, saved.path.name)
    if not readable:
        raise error or BagError('; '.join(damage))
    damage += [f'{p}: no metadata.yaml, the recorder did not close the recording; its storage '
               'files were read as they are' for p in _without_metadata(paths)]
    damage += [f'{p}: {", ".join(f.name for f in files)} not listed in its metadata.yaml; '
               'every storage file there was read' for p in paths if (files := unlisted(p))]
    damage += [f'{p}: {newer}' for p in paths if (newer := newer_version(p))]
    damage += said
    if error is not None and not damage:   # every file opens: the folder's metadata.yaml is wrong
        damage = [f'{p}: {metadata_refusal(p, error)}' for p in paths if p.is_dir()]
    for line in damage:
        logger.warning('%s', line)
    return readable, tuple(damage)


@contextmanager
def mcap_copies(paths: Sequence[Path]) -> Iterator[tuple[list[Path], str]]:
    """Copy the MCAP files of recordings record by record (damage read around), for a while.

    For a recording that opened but fails inside a chunk: reading on by time steps over the
    whole chunk, while its records before the damage are readable
    (:func:`~.mcap_file.salvage_mcap`).

    Yields:
        The copies, in a temporary folder, and what they say of the damage; no copies unless
        every storage file is an MCAP file with a message to copy.
    """
    files = [f for p in paths for f in (storage_files(p) or [p])]
    with TemporaryDirectory(prefix='pmba_salvage_') as folder:
        copies: list[Path] = []
        said: list[str] = []
        if files and all(f.suffix == '.mcap' for f in files):
            for i, f in enumerate(files):
                saved = salvage_mcap(f, Path(folder) / f'{i}_{f.name}', 'read record by record')
                if saved is not None:
                    copies.append(saved.path)
                    said.append(saved.damage)
        yield copies, '; '.join(filter(None, said))
