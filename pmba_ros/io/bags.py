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
"""Reading recordings with rosbags (no ROS install needed); writing is :mod:`.bag_writer`.

Reading goes through :class:`rosbags.highlevel.AnyReader` (rosbag2 folders, bare ``.mcap`` /
``.db3`` storage files, or several ROS 1 ``.bag`` files) with the ROS 2 Jazzy typestore as
the default for bags without message definitions. The QoS pitfall of
``ros2_notes.md`` §4.4 is handled:

* **QoS mismatch** (§4.4.6): when the QoS profiles in a folder's ``metadata.yaml`` differ
  from those stored in the storage file, opening the *folder* yields zero messages although
  ``message_count`` is right. :func:`iter_messages` notices a folder that promised messages
  and yielded none, and reads the storage files directly.

Every failure is raised as :class:`~pmba_ros.errors.BagError` naming the bag and the problem.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator, Sequence
from contextlib import closing, contextmanager, ExitStack, nullcontext
from dataclasses import dataclass, field
import logging
from pathlib import Path
import struct
from typing import Any, NamedTuple

from pmba_ros.errors import BagError
from pmba_ros.io import cloud_decode
from pmba_ros.io.mcap_layout import check_mcap_lengths, zstd_module
from pmba_ros.io.typestores import deserializer, jazzy_typestore, noetic_typestore

logger = logging.getLogger(__name__)

STORAGE_SUFFIXES = ('.mcap', '.db3')
"""Suffixes of rosbag2 storage files that can be opened without their folder."""


class BagMessage(NamedTuple):
    """One deserialized message of a recording.

    Attributes:
        topic: Topic name as recorded.
        msgtype: Message type, e.g. 'nav_msgs/msg/Odometry'.
        log_time_ns: Receive (log) time of the message, ns.
        msg: The message (a rosbags typestore dataclass).
    """

    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a recording.

    Attributes:
        topic: Topic name.
        msgtype: Message type.
        count: Number of messages the bag reports for it.
    """

    topic: str
    msgtype: str
    count: int


RESUME_STEP_NS = 1_000_000
"""First step past a corrupt part of a recording when looking for readable data again."""


@dataclass
class ReadStats:
    """Damage met while reading, when the reader is asked to read past it.

    Attributes:
        undecodable: Messages skipped because they do not deserialize.
        first_undecodable: Description of the first of them.
        damaged_parts: Corrupt stretches of storage (e.g. MCAP chunks) skipped.
        first_damage: Description of the first of them.
    """

    undecodable: int = 0
    first_undecodable: str | None = None
    damaged_parts: int = 0
    first_damage: str | None = None
    _pending: str | None = field(default=None, init=False, repr=False)
    _span: tuple[int, int] = field(default=(0, 0), init=False, repr=False)


def reader_errors() -> tuple[type[BaseException], ...]:
    """Return the exception types the rosbags readers raise on bad input.

    rosbags passes on what apsw, its SQLite binding, raises on a page found damaged while it
    reads the messages (``apsw.CorruptError``).
    """
    import apsw
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    return (AnyReaderError, Reader1Error, Reader2Error, struct.error, EOFError, ValueError,
            KeyError, IndexError, UnicodeDecodeError, AssertionError, OSError, ArithmeticError,
            MemoryError, TypeError, RuntimeError, apsw.Error, *_zstd_errors())


def _zstd_errors() -> tuple[type[BaseException], ...]:
    """Return the error type of the zstd module rosbags decompresses MCAP chunks with."""
    return (zstd_module().ZstdError,)


def _describe(paths: Sequence[Path]) -> str:
    """Return a short name for a list of bags."""
    return ', '.join(str(p) for p in paths)


def _check_paths(paths: Sequence[Path]) -> list[Path]:
    """Validate bag paths and return them as a list.

    Raises:
        BagError: If no path is given, a path is missing or is a folder without a bag, or
            ROS 1 and ROS 2 bags are mixed.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        msg = 'no bag given'
        raise BagError(msg)
    for path in paths:
        if not path.exists():
            msg = f'{path}: no such bag'
            raise BagError(msg)
    expanded: list[Path] = []
    for path in paths:
        if path.is_dir() and not (path / 'metadata.yaml').exists():
            files = storage_files(path)
            if not files:
                msg = f'{path}: not a bag (no metadata.yaml and no .mcap or .db3 file in it)'
                raise BagError(msg)
            logger.info('%s has no metadata.yaml; reading %s', path, _describe(files))
            expanded.extend(files)
        else:
            expanded.append(path)
    paths = expanded
    kinds = {is_ros1(p) for p in paths}
    if len(kinds) > 1:
        msg = f'cannot mix ROS 1 (.bag) and ROS 2 recordings: {_describe(paths)}'
        raise BagError(msg)
    return paths


def is_ros1(path: Path) -> bool:
    """Return True for a ROS 1 bag (``.bag``, or ``.bag.active``: ``rosbag record`` writing)."""
    return path.suffix == '.bag' or path.name.endswith('.bag.active')


def storage_files(path: Path) -> list[Path]:
    """Return the storage files inside a rosbag2 folder (sorted), or [] for a file."""
    if not path.is_dir():
        return []
    return sorted(p for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)


@contextmanager
def any_reader(paths: Sequence[Path]) -> Iterator[Any]:
    """Open an AnyReader over ``paths`` with the Jazzy default typestore.

    Raises:
        BagError: If a bag cannot be opened (not a bag, truncated, unknown format).
    """
    from rosbags.highlevel import AnyReader
    errors = reader_errors()
    check_mcap_lengths(f for p in paths for f in (storage_files(p) or [p]))
    try:
        reader = AnyReader(list(paths), default_typestore=jazzy_typestore())
        reader.open()
    except FileNotFoundError as err:
        msg = f'{_describe(paths)}: {err}'
        raise BagError(msg) from err
    except errors as err:
        msg = (f'{_describe(paths)}: cannot open bag (not a bag, truncated or corrupt?): '
               f'{error_text(err)}')
        raise BagError(msg) from err
    try:
        yield reader
    finally:
        try:
            reader.close()
        except errors as err:  # pragma: no cover - closing a read-only file rarely fails
            logger.debug('closing %s failed: %s', _describe(paths), err)


def error_text(err: BaseException) -> str:
    """Return a one-line description of a reader exception."""
    text = ' '.join(str(a) for a in err.args) if err.args else ''
    text = text.strip() or type(err).__name__
    if isinstance(err, (KeyError, IndexError)):   # a lookup inside the reader: say which
        text = f'{type(err).__name__}: {text}'
    line = text.splitlines()[0] if text else type(err).__name__
    # A reader's message may quote the damaged bytes themselves (a ROS 1 header: megabytes).
    return line if len(line) <= MAX_ERROR_TEXT else f'{line[:MAX_ERROR_TEXT]} ...'


MAX_ERROR_TEXT = 300
"""Longest reader message kept in a damage line (a report, a warning)."""


def list_topics(paths: Sequence[Path | str]) -> dict[str, TopicInfo]:
    """Return the topics of one or more recordings.

    Args:
        paths: rosbag2 folders or storage files, or ROS 1 ``.bag`` files.

    Returns:
        Topic name -> :class:`TopicInfo` (message counts summed over the bags).

    Raises:
        BagError: If a bag is missing or cannot be opened.
    """
    with open_bags(paths) as bags:
        return bags.topics


def ros2_type_name(msgtype: str) -> str:
    """Return a message type's ROS 2 name: ``package/msg/Type`` for ``package/Type``.

    Some tools record ROS 2 messages under their ROS 1 type names (an MCAP schema named
    ``sensor_msgs/PointCloud``); the types are the same, and the name the rest of the
    package compares is the ROS 2 one.
    """
    package, sep, name = msgtype.partition('/')
    return f'{package}/msg/{name}' if sep and package and name and '/' not in name else msgtype


def _topics_of(reader: Any) -> dict[str, TopicInfo]:
    """Return the topics of an open reader (counts summed over its bags)."""
    topics: dict[str, TopicInfo] = {}
    for conn in reader.connections:
        old = topics.get(conn.topic)
        count = int(conn.msgcount) + (old.count if old else 0)
        topics[conn.topic] = TopicInfo(conn.topic, ros2_type_name(conn.msgtype), count)
    return topics


class OpenBags(NamedTuple):
    """Recordings opened once for their topics and then their messages (see :func:`open_bags`).

    Attributes:
        paths: The checked bag paths (a damaged MCAP file's readable copy in its place).
        reader: The open rosbags reader.
        topics: Topic name -> :class:`TopicInfo`, as :func:`list_topics` returns them.
        damage: What could not be opened, and what was read instead (see :func:`open_bags`).
    """

    paths: list[Path]
    reader: Any
    topics: dict[str, TopicInfo]
    damage: tuple[str, ...] = ()


@contextmanager
def open_bags(paths: Sequence[Path | str]) -> Iterator[OpenBags]:
    """Open recordings once: their topics now, their messages by :func:`iter_messages` later.

    Opening parses the bags' metadata and message definitions; a replay that lists the topics
    and then reads the messages needs it only once.

    Recordings that cannot be opened whole, or that a recorder did not close, are read file by
    file (:func:`~pmba_ros.io.salvage.readable_parts`): a damaged storage file by its readable
    messages (an MCAP or ROS 1 bag without its index up to the damage; the readable rows of a
    SQLite file cut short, damaged, with SQLite's journal beside it or an index missing rows),
    a rosbag2 folder without ``metadata.yaml``, or whose ``metadata.yaml`` lists a missing file,
    by the files there are; a folder whose ``metadata.yaml`` its files contradict (a topic's
    type, their compression) or rosbags refuses, by its files alone. ``damage`` then says what
    was lost or wrong.

    Raises:
        BagError: If a bag is missing or cannot be opened, not even in part.
    """
    from pmba_ros.io import salvage  # it builds on this module
    given = [Path(p) for p in paths]
    checked = _check_paths(given)
    with ExitStack() as stack:
        damage: tuple[str, ...] = ()
        error: BagError | None = None
        reader = None
        said: list[str] = []
        if not salvage.suspect(given):
            reader, error, said = salvage.opened_whole(checked, stack)
        if reader is None:
            checked, damage = salvage.readable_parts(given, error, stack, said)
            try:
                reader = stack.enter_context(any_reader(checked))
            except BagError as err:   # it names the salvaged copies, in a temporary folder
                msg = (f'{_describe(given)}: cannot open bag, not even the parts salvaged '
                       f'({"; ".join(damage)}): {error_text(err.__cause__ or err)}')
                raise BagError(msg) from err
        yield OpenBags(checked, reader, _topics_of(reader), damage)


def require_topics(topics: dict[str, TopicInfo], wanted: dict[str, Sequence[str]],
                   bags: Sequence[Path | str]) -> None:
    """Check that every wanted topic is recorded with one of the accepted types.

    Args:
        topics: Result of :func:`list_topics`.
        wanted: Topic -> accepted message types (empty: any type).
        bags: The bags (for the error message).

    Raises:
        BagError: If a topic is missing or has an unexpected type.
    """
    names = _describe([Path(b) for b in bags])
    for topic, types in wanted.items():
        info = topics.get(topic)
        if info is None:
            have = ', '.join(f'{t} [{i.msgtype}]' for t, i in sorted(topics.items())) or 'none'
            msg = f'{names}: topic {topic!r} is not in the bag (topics: {have})'
            raise BagError(msg)
        if types and info.msgtype not in types:
            msg = (f'{names}: topic {topic!r} has type {info.msgtype}, expected '
                   f'{" or ".join(types)}')
            raise BagError(msg)


def iter_messages(paths: Sequence[Path | str] | OpenBags,
                  topics: Sequence[str] | None = None, *,
                  damage: ReadStats | None = None,
                  points_as_arrays: bool = False) -> Iterator[BagMessage]:
    """Yield the messages of one or more recordings in log-time order, deserialized.

    A rosbag2 folder that reports messages on the selected topics but yields none (the
    metadata/storage QoS mismatch of ``ros2_notes.md`` §4.4.6) is read again through its
    storage files.

    Args:
        paths: rosbag2 folders or storage files, or ROS 1 ``.bag`` files; or bags opened by
            :func:`open_bags`, whose reader then reads them (once: reading on after damage,
            and the QoS fallback, open the bags again).
        topics: Topics to read; None reads all.
        damage: If given, read past damage instead of raising: a message that does not
            deserialize is skipped, and after a corrupt part of the storage reading resumes
            at the next readable data (found by stepping forward in time from the last good
            message, 1 ms at first and doubling); both are counted here.
        points_as_arrays: Decode the points of standard ``sensor_msgs/PointCloud`` messages
            as one ``(N, 3)`` float32 array (:mod:`.cloud_decode`), without a Python object
            per point; such messages are for reading, not for serializing again.

    Yields:
        :class:`BagMessage` tuples, merged over all bags in log-time order.

    Raises:
        BagError: If a bag is missing or cannot be opened; without ``damage`` also if it is
            corrupt or truncated (raised when the damaged part is reached; the messages
            before it have been yielded).
    """
    if isinstance(paths, OpenBags):
        checked, reader, recorded = paths.paths, paths.reader, paths.topics
    else:
        checked, reader, recorded = _check_paths([Path(p) for p in paths]), None, None
    expected, produced = 0, 0
    for message in _iter_all(checked, topics, damage, points_as_arrays, reader):
        produced += 1
        yield message
    if produced or (damage is not None and damage.damaged_parts):
        return
    recorded = list_topics(checked) if recorded is None else recorded
    expected = sum(info.count for name, info in recorded.items()
                   if topics is None or name in topics)
    folders = [p for p in checked if storage_files(p)]
    if expected == 0 or not folders:
        return
    files = [f for p in checked for f in (storage_files(p) or [p])]
    logger.warning('%s: the bag folder reports %d messages but yields none (metadata.yaml '
                   'QoS differs from the storage file); reading %s directly', _describe(checked),
                   expected, _describe(files))
    yield from _iter_all(files, topics, damage, points_as_arrays)


def _iter_all(paths: Sequence[Path], topics: Sequence[str] | None,
              damage: ReadStats | None, points_as_arrays: bool = False, reader: Any = None,
              ) -> Iterator[BagMessage]:
    """Yield the messages of ``paths``, resuming after corrupt parts if ``damage`` is given.

    An open ``reader`` of ``paths`` serves the first pass; reading on after damage opens the
    bags afresh.
    """
    if damage is None:
        yield from _iter_once(paths, topics, None, points_as_arrays=points_as_arrays,
                              reader=reader)
        return
    start: int | None = None
    copied = False
    while True:
        last: int | None = None
        for message in _iter_once(paths, topics, damage, start, points_as_arrays, reader):
            last = message.log_time_ns
            yield message
        error, damage._pending = damage._pending, None
        if error is None:
            return
        if last is not None or start is None:
            damage.damaged_parts += 1
            damage.first_damage = damage.first_damage or error
            logger.warning('%s; looking for readable data after it', error)
        reader = None
        if not copied:   # MCAP chunks read up to their damage, once
            copied = True
            from pmba_ros.io import salvage  # it builds on this module
            with salvage.mcap_copies(paths) as (copies, said):
                if copies:
                    damage.first_damage = '; '.join(filter(None, [damage.first_damage, said]))
                    after = last if last is not None else start
                    yield from _iter_once(copies, topics, damage,
                                          None if after is None else after + 1, points_as_arrays)
                    # The copies hold every readable message: reading the originals on
                    # would give some twice.
                    if damage._pending is not None:
                        damage.damaged_parts += 1
                        damage._pending = None
                    return
        failed = last + 1 if last is not None else (damage._span[0] if start is None else start)
        start = _next_readable(paths, topics, failed, damage._span[1])
        if start is None:
            return


def _next_readable(paths: Sequence[Path], topics: Sequence[str] | None, failed: int,
                   end: int) -> int | None:
    """Return the earliest start time after ``failed`` (ns) that reads without an error.

    Steps forward from ``failed`` by 1 ms, doubling, then bisects back to 1 ms; None if
    nothing up to ``end`` is readable.
    """
    lo, step = failed, RESUME_STEP_NS
    while True:
        hi = min(lo + step, end)
        if _readable_from(paths, topics, hi):
            break
        if hi >= end:
            return None
        lo, step = hi, 2 * step
    while hi - lo > RESUME_STEP_NS:
        mid = (lo + hi) // 2
        if _readable_from(paths, topics, mid):
            hi = mid
        else:
            lo = mid
    return hi


def _readable_from(paths: Sequence[Path], topics: Sequence[str] | None, start: int) -> bool:
    """Return True if reading from ``start`` (ns) gets a message, or the end, without error."""
    probe = ReadStats()
    with closing(_iter_once(paths, topics, probe, start)) as stream:
        next(stream, None)
    return probe._pending is None


def _iter_once(paths: Sequence[Path], topics: Sequence[str] | None,
               damage: ReadStats | None, start: int | None = None,
               points_as_arrays: bool = False, reader: Any = None,
               ) -> Generator[BagMessage, None, None]:
    """Yield the messages of ``paths`` from ``start`` (ns) once (see :func:`iter_messages`).

    ``reader``: an open reader of ``paths`` to use (left open); None opens one.
    """
    errors = reader_errors()
    with nullcontext(reader) if reader is not None else any_reader(paths) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if not conns:
            return
        if damage is not None:
            damage._span = (int(reader.start_time), int(reader.end_time))
        # rosbags defines the types by their ROS 2 names, whatever name a schema gave.
        name = {c.msgtype: ros2_type_name(c.msgtype) for c in conns}
        fast = {}
        if points_as_arrays:
            reference = jazzy_typestore() if reader.is2 else noetic_typestore()
            fast = {t: cloud_decode.fast_decoder(reader.typestore, t, reference,
                                                 ros1=not reader.is2) for t in name.values()}
        deserialize = {t: deserializer(reader, t) for t in name.values()}
        try:
            for conn, t_ns, raw in _raw_messages(reader, conns, paths, start):
                msgtype = name[conn.msgtype]
                decode = fast.get(msgtype)
                msg_obj = decode(raw) if decode is not None else None
                try:
                    if msg_obj is None:
                        msg_obj = deserialize[msgtype](raw)
                except errors as err:
                    msg = (f'{_describe(paths)}: cannot deserialize a {msgtype} message '
                           f'on {conn.topic} at {t_ns} ns: {error_text(err)}')
                    if damage is None:
                        raise BagError(msg) from err
                    logger.debug('%s; skipped', msg)
                    damage.undecodable += 1
                    damage.first_undecodable = damage.first_undecodable or msg
                    continue
                yield BagMessage(conn.topic, msgtype, t_ns, msg_obj)
        except _CorruptStorage as err:
            if damage is None:
                raise
            damage._pending = str(err)


class _CorruptStorage(BagError):
    """The storage itself could not be read on (as opposed to one undecodable message)."""


ZSTD_MAGIC = b'\x28\xb5\x2f\xfd'
"""A zstd frame's first bytes; a CDR message starts with its encapsulation header instead."""


def _raw_messages(reader: Any, conns: list[Any], paths: Sequence[Path],
                  start: int | None = None) -> Iterator[tuple[Any, int, bytes]]:
    """Yield ``(connection, log_time_ns, raw bytes)`` of an open reader in log-time order.

    A ROS 2 message still zstd-compressed (rosbag2's per-message compression, read from a
    storage file without the ``metadata.yaml`` that says so: given alone, or salvaged) is
    decompressed.

    Raises:
        _CorruptStorage: If the storage is corrupt or truncated.
    """
    errors = reader_errors()
    stream = reader.messages(connections=conns, start=start)
    while True:
        try:
            conn, t_ns, raw = next(stream)
        except StopIteration:
            return
        except errors as err:
            msg = f'{_describe(paths)}: bag is corrupt or truncated: {error_text(err)}'
            raise _CorruptStorage(msg) from err
        if reader.is2 and raw[:4] == ZSTD_MAGIC:
            raw = _decompressed(raw)
        yield conn, int(t_ns), raw


def _decompressed(raw: bytes) -> bytes:
    """Return a zstd frame's content, or ``raw`` if it does not decompress (then undecodable)."""
    broken: tuple[type[BaseException], ...] = (*_zstd_errors(), ValueError)
    try:
        return bytes(zstd_module().decompress(raw))
    except broken:
        return raw


__all__ = ['STORAGE_SUFFIXES', 'BagMessage', 'OpenBags', 'ReadStats', 'TopicInfo', 'any_reader',
           'error_text', 'is_ros1', 'iter_messages', 'iter_serialized', 'jazzy_typestore',
           'list_topics', 'open_bags', 'reader_errors', 'require_topics',
           'serialized_messages', 'storage_files']


def iter_serialized(paths: Sequence[Path | str], topics: Sequence[str] | None = None,
                    ) -> Iterator[tuple[str, int, bytes]]:
    """Yield ``(topic, log_time_ns, CDR bytes)`` of rosbag2 recordings in log-time order.

    The bytes are the stored serialization, ready for an rclpy publisher (``pmba play``).
    A damaged recording is read in the parts that can be, as :func:`open_bags` reads it (and
    warns).

    Args:
        paths: rosbag2 folders or storage files.
        topics: Topics to read; None reads all.

    Raises:
        BagError: If a bag is missing, cannot be opened or is corrupt, or is a ROS 1 bag
            (whose serialization ROS 2 publishers cannot send).
    """
    with open_bags(paths) as bags:
        yield from serialized_messages(bags, topics)


def serialized_messages(bags: OpenBags, topics: Sequence[str] | None = None,
                        ) -> Iterator[tuple[str, int, bytes]]:
    """Yield :func:`iter_serialized`'s messages of opened recordings, each call from the start."""
    ros1 = [p for p in bags.paths if is_ros1(p)]
    if ros1:
        msg = (f'{_describe(ros1)}: a ROS 1 bag cannot be played into ROS 2 as it is; '
               'convert it first: rosbags-convert --src BAG --dst FOLDER')
        raise BagError(msg)
    reader = bags.reader
    conns = [c for c in reader.connections if topics is None or c.topic in topics]
    for conn, t_ns, raw in _raw_messages(reader, conns, bags.paths) if conns else ():
        yield conn.topic, t_ns, bytes(raw)
