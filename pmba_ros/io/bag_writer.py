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
"""Writing recordings with rosbags: rosbag2 MCAP, as ``ros2 bag record`` writes them.

The rosbags writer refuses an existing path (``ros2_notes.md`` §4.4.2): :func:`open_writer`
writes into a fresh temporary folder and moves the storage file into place when it closes,
also when the writing code raises (the MCAP summary is always written, so an interrupted run
leaves a readable file). Every failure is raised as :class:`~pmba_ros.errors.BagError`.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import logging
from pathlib import Path
import shutil
from typing import Any

from pmba_ros.errors import BagError
from pmba_ros.io import cdr
from pmba_ros.io.atomic import deferred_interrupts
from pmba_ros.io.bags import jazzy_typestore

logger = logging.getLogger(__name__)


class BagWriter:
    """Writes serialized messages to one rosbag2 MCAP recording (Jazzy typestore).

    Use :func:`open_writer` to create one; connections are added on first use of a topic.
    """

    def __init__(self, writer: Any, typestore: Any) -> None:
        """Wrap an open rosbags writer."""
        self._writer = writer
        self._typestore = typestore
        self._connections: dict[str, Any] = {}
        self._encoders: dict[str, cdr.Encoder] = {}
        self.count = 0

    def write(self, topic: str, msg: Any, log_time_ns: int, *, msgtype: str | None = None,
              ) -> None:
        """Serialize and write one message.

        Args:
            topic: Absolute topic name.
            msg: A message of the Jazzy typestore.
            log_time_ns: Log time, ns.
            msgtype: Message type; default ``msg.__msgtype__``.

        Raises:
            BagError: If the message does not serialize or the topic changes type.
        """
        msgtype = str(msgtype or getattr(msg, '__msgtype__', ''))
        conn = self._connections.get(topic)
        if conn is None:
            try:
                conn = self._writer.add_connection(topic, msgtype, typestore=self._typestore)
            except Exception as err:
                msg_ = f'cannot add topic {topic!r} of type {msgtype!r}: {err}'
                raise BagError(msg_) from err
            self._connections[topic] = conn
            self._encoders[topic] = cdr.Encoder()
        elif conn.msgtype != msgtype:
            msg_ = f'topic {topic!r} has type {conn.msgtype}, cannot write a {msgtype}'
            raise BagError(msg_)
        try:
            raw = self._encoders[topic].encode(msg, msgtype)
            if raw is None:
                raw = self._typestore.serialize_cdr(msg, msgtype)
        except Exception as err:
            msg_ = f'cannot serialize a {msgtype} message for {topic!r}: {err}'
            raise BagError(msg_) from err
        self._writer.write(conn, int(log_time_ns), raw)
        self.count += 1


@contextmanager
def open_writer(path: Path | str, *, overwrite: bool = False,
                keep_on_error: bool = True) -> Iterator[BagWriter]:
    """Open a rosbag2 MCAP recording for writing (rosbag2 metadata version 9).

    Chunks are zstd-compressed, as ``ros2 bag record``'s ``zstd_fast`` preset does: the
    node's growing outputs (path, keyframes, landmarks) repeat from message to message, so a
    long replay's result bag shrinks several-fold.

    ``path`` ending in ``.mcap`` gives a bare storage file (readable by rosbags, mcap and
    ``ros2 bag``); any other path gives a rosbag2 folder ``path/`` with ``metadata.yaml``
    and ``path/<name>.mcap``. The recording is written into a temporary folder beside
    ``path`` and moved into place when the block ends, normally or by an exception, so the
    MCAP summary is always written; with ``keep_on_error=False`` an exception discards it
    instead (a partly written input recording must not pass for a whole one).

    Args:
        path: Output file (``*.mcap``) or folder.
        overwrite: Replace an existing output; otherwise an existing path is an error.
        keep_on_error: Whether to keep what was written when the block raises.

    Yields:
        The :class:`BagWriter`.

    Raises:
        BagError: If ``path`` exists (and ``overwrite`` is False) or cannot be written.
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    path = Path(path)
    bare = path.suffix == '.mcap'
    if path.exists() and not overwrite:
        msg = f'{path}: exists already (choose a new path or overwrite it)'
        raise BagError(msg)
    tmp = path.with_name(f'.{path.name}.partial')
    if tmp.exists():
        shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.parent.mkdir(parents=True, exist_ok=True)
        writer = Writer(tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
    except Exception as err:
        msg = f'{path}: cannot create bag: {err}'
        raise BagError(msg) from err
    try:
        yield BagWriter(writer, jazzy_typestore())
    except BaseException:
        # The block's error is the cause to report; a failing close (a full disk fails
        # both) must not replace it.
        with deferred_interrupts():
            try:
                if keep_on_error:
                    _finalize(writer, tmp, path, bare)
                else:
                    _discard(writer, tmp)
            except Exception as err:
                logger.warning('%s: cannot finalize the bag after an error: %s', path, err)
        raise
    with deferred_interrupts():
        _finalize(writer, tmp, path, bare)


def _finalize(writer: Any, tmp: Path, path: Path, bare: bool) -> None:
    """Close the writer (MCAP summary) and move the recording into place."""
    writer.close()
    _move_into_place(tmp, path, bare)


def _discard(writer: Any, tmp: Path) -> None:
    """Close the writer and remove the temporary recording."""
    try:
        writer.close()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _move_into_place(tmp: Path, path: Path, bare: bool) -> None:
    """Move a finished temporary rosbag2 folder to ``path`` (file or folder)."""
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
    if bare:
        (tmp / f'{tmp.name}.mcap').replace(path)
        shutil.rmtree(tmp)
        return
    storage = tmp / f'{tmp.name}.mcap'
    final_storage = tmp / f'{path.name}.mcap'
    storage.replace(final_storage)
    meta = tmp / 'metadata.yaml'
    text = meta.read_text(encoding='utf-8').replace(f'{tmp.name}.mcap', f'{path.name}.mcap')
    meta.write_text(text, encoding='utf-8')
    tmp.replace(path)
