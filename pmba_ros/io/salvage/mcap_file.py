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
"""The readable part of an MCAP file that cannot be opened (a recorder killed mid-run).

``ros2 bag record`` writes an MCAP file's index (summary and footer) when it closes it; a
recorder that is killed, or a disk that fills up, leaves a file without one, and rosbags
refuses the whole file ("File end magic is invalid"): every keyframe before the damage was
lost. :func:`salvage_mcap` copies the complete chunks at the start of such a file into a
new, indexed file, as ``mcap recover`` does, and says what was lost.
"""

from __future__ import annotations

from pathlib import Path
import struct

from pmba_ros.io.salvage.common import Salvaged

__all__ = ['salvage_mcap']


def _stream_errors() -> tuple[type[BaseException], ...]:
    """Return what the mcap stream reader raises on a truncated or corrupt file."""
    from mcap.exceptions import McapError
    # A damaged length asks a buffer for more than it can hold: OverflowError, MemoryError.
    errors: list[type[BaseException]] = [McapError, EOFError, ValueError, KeyError,
                                         struct.error, OSError, ArithmeticError, MemoryError]
    try:
        import zstandard
        errors.append(zstandard.ZstdError)
    except ImportError:   # the mcap reader then cannot read zstd chunks at all
        pass
    return tuple(errors)


def salvage_mcap(path: Path, dest: Path, reason: str) -> Salvaged | None:
    """Copy the readable messages of the MCAP file ``path`` into ``dest``.

    Records are read from the start up to the first that is incomplete or corrupt (a chunk
    cut short, a CRC mismatch); the schemas, channels and messages before it are written
    into ``dest`` with a summary, so rosbags reads it like any recording.

    Args:
        path: The damaged MCAP file.
        dest: The file to write.
        reason: Why ``path`` is read this way, the damage description's start.

    Returns:
        What was copied, or None if not a single message could be (``dest`` removed).
    """
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Header, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    errors = _stream_errors()
    size = path.stat().st_size
    messages, stopped = 0, 'at its end (no index)'
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    with path.open('rb') as src, dest.open('wb') as out:
        writer = Writer(out)
        started = False
        try:
            for record in StreamReader(src, skip_magic=False, validate_crcs=True).records:
                if isinstance(record, Header) and not started:
                    writer.start(profile=record.profile, library=record.library)
                    started = True
                elif not started:
                    continue
                elif isinstance(record, Schema) and record.id not in schemas:
                    schemas[record.id] = writer.register_schema(record.name, record.encoding,
                                                                record.data)
                elif isinstance(record, Channel) and record.id not in channels:
                    channels[record.id] = writer.register_channel(
                        record.topic, record.message_encoding,
                        schemas.get(record.schema_id, 0), record.metadata)
                elif isinstance(record, Message) and record.channel_id in channels:
                    writer.add_message(channels[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    messages += 1
        except EndOfFile:
            stopped = f'where the file ends, at byte {size}, in the middle of a record'
        except errors as err:
            stopped = f'at byte {src.tell()} of {size} ({type(err).__name__}: {err})'
        if started:
            writer.finish()
    if not messages:
        dest.unlink(missing_ok=True)
        return None
    damage = (f'{reason}; {messages} messages read up to the '
              f'damage {stopped}, the rest of the file is lost')
    return Salvaged(dest, messages, damage)
