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
"""An MCAP file of ROS 1 messages, read as the ROS 1 bag it was made from.

``mcap convert demo.bag demo.mcap`` (the mcap CLI, and Foxglove's way to open ROS 1
recordings) writes the ``ros1`` profile: ``ros1msg`` schemas, ``ros1`` message encoding,
each message's ROS 1 serialization unchanged. rosbags reads MCAP of ROS 2 messages only and
refuses such a file whole ("Profile is not ros2"). Its messages are copied as they are into
a ROS 1 bag, which rosbags reads as any other (the definitions recorded, ROS 1 decoding).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pmba_ros.errors import BagError

__all__ = ['ROS1_ENCODING', 'ROS1_SCHEMA_ENCODING', 'is_ros1_channel', 'write_ros1_bag']

ROS1_ENCODING = 'ros1'
"""The message encoding of the MCAP ``ros1`` profile."""

ROS1_SCHEMA_ENCODING = 'ros1msg'
"""The schema encoding of the MCAP ``ros1`` profile: a ROS 1 connection's full definition."""


def is_ros1_channel(channel: Any, schemas: dict[int, Any]) -> bool:
    """Return True if an MCAP channel carries ROS 1 messages defined by a ``ros1msg`` schema."""
    schema = schemas.get(channel.schema_id)
    return (channel.message_encoding == ROS1_ENCODING and schema is not None
            and schema.encoding == ROS1_SCHEMA_ENCODING)


def _md5sum(msgtype: str, definition: str) -> str:
    """Return the ROS 1 MD5 sum of a type from its full definition.

    The ``ros1`` profile does not record it (rosbags' ROS 1 writer needs one for each
    connection); it is computed as ROS 1 does, from the definition the file carries.
    """
    from rosbags.typesys import get_types_from_msg, get_typestore, Stores

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(definition, msgtype))
    return str(store.generate_msgdef(msgtype)[1])


def write_ros1_bag(dest: Path, channels: dict[int, Any], schemas: dict[int, Any],
                   messages: Iterable[Any]) -> int:
    """Write the messages of ROS 1 MCAP channels into a ROS 1 bag; return how many.

    Args:
        dest: The ``.bag`` file to write.
        channels: Channel id -> MCAP channel record (each a ``ros1`` one, see
            :func:`is_ros1_channel`).
        schemas: Schema id -> MCAP schema record.
        messages: MCAP message records, in file order; those of other channels are left out.

    Raises:
        BagError: If a schema's definition does not parse.
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import TypesysError
    from rosbags.typesys.msg import normalize_msgtype

    count = 0
    with Writer(dest) as writer:
        connections: dict[int, Any] = {}
        alike: dict[tuple[Any, ...], Any] = {}   # a bag holds each connection once
        for cid, channel in channels.items():
            schema = schemas[channel.schema_id]
            msgtype = normalize_msgtype(schema.name)
            latching = channel.metadata.get('latching')
            try:
                definition = schema.data.decode()
                md5sum = channel.metadata.get('md5sum') or _md5sum(msgtype, definition)
            except (TypesysError, UnicodeDecodeError) as err:
                msg = f'the ROS 1 definition of {schema.name} does not parse: {err}'
                raise BagError(msg) from err
            args = (channel.topic, msgtype, definition, md5sum, channel.metadata.get('callerid'),
                    None if latching is None else int(latching in ('1', 'true')))
            if args not in alike:
                alike[args] = writer.add_connection(
                    args[0], args[1], msgdef=args[2], md5sum=args[3], callerid=args[4],
                    latching=args[5])
            connections[cid] = alike[args]
        for record in messages:
            if record.channel_id in connections:
                writer.write(connections[record.channel_id], record.log_time, record.data)
                count += 1
    return count
