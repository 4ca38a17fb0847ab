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
"""rosbag2 folders whose metadata.yaml is wrong about their storage files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pmba_ros.io.bags import iter_messages, jazzy_typestore, open_bags, ReadStats
import pytest
import yaml

N = 6


def write_folder(folder: Path, storage: str = 'sqlite3', compressed: bool = False) -> None:
    """Write ``N`` std_msgs/String messages on ``/s`` and ``N`` Int32 on ``/i``."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    typestore = jazzy_typestore()
    string, int32 = typestore.types['std_msgs/msg/String'], typestore.types['std_msgs/msg/Int32']
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    writer = Writer(folder, version=9, storage_plugin=plugin)
    if compressed:
        writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        text = writer.add_connection('/s', 'std_msgs/msg/String', typestore=typestore)
        number = writer.add_connection('/i', 'std_msgs/msg/Int32', typestore=typestore)
        for i in range(N):
            writer.write(text, (2 * i + 1) * 10**7, typestore.serialize_cdr(
                string(data=f'message {i}'), 'std_msgs/msg/String'))
            writer.write(number, (2 * i + 2) * 10**7, typestore.serialize_cdr(
                int32(data=i), 'std_msgs/msg/Int32'))


def edit_metadata(folder: Path, **changes: Any) -> None:
    """Set fields of a folder's ``rosbag2_bagfile_information``."""
    meta = folder / 'metadata.yaml'
    info = yaml.safe_load(meta.read_text())
    info['rosbag2_bagfile_information'].update(changes)
    meta.write_text(yaml.safe_dump(info))


def read(folder: Path) -> tuple[dict[str, str], list[Any], tuple[str, ...], ReadStats]:
    """Return a folder's topic types, messages, what was wrong with it and the damage met."""
    stats = ReadStats()
    with open_bags([folder]) as bags:
        types = {name: info.msgtype for name, info in bags.topics.items()}
        messages = [m.msg.data for m in iter_messages(bags, damage=stats)]
    return types, messages, bags.damage, stats


def expected() -> list[Any]:
    """Return the messages :func:`write_folder` writes, in log-time order."""
    return [x for i in range(N) for x in (f'message {i}', i)]


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_a_topic_type_the_storage_file_contradicts_is_read_as_the_file_says(
        tmp_path: Path, storage: str) -> None:
    """metadata.yaml naming another type than the storage file's: the file's type, named.

    rosbags matched none of the topic's messages to the metadata's type: the topic read as
    empty with the wrong type, then the storage file alone, and a replay refused the layout
    or counted the messages missing ("damaged or truncated"). The storage file alone reads.
    """
    folder = tmp_path / 'rec'
    write_folder(folder, storage)
    meta = folder / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('type: std_msgs/msg/Int32',
                                             'type: std_msgs/msg/Int64'))
    types, messages, said, stats = read(folder)
    assert types == {'/s': 'std_msgs/msg/String', '/i': 'std_msgs/msg/Int32'}
    assert messages == expected() and stats.damaged_parts == 0 and stats.undecodable == 0
    (line,) = said
    assert line.startswith(f"{folder}: metadata.yaml gives topic '/i' the type "
                           'std_msgs/msg/Int64, but rec')
    assert 'records std_msgs/msg/Int32' in line and 'truncated' not in line


def test_a_false_claim_of_per_message_compression_is_named(tmp_path: Path) -> None:
    """``compression_mode: message`` over plain messages: read as they are, metadata.yaml named.

    rosbags failed to decompress the first message, and the whole recording was refused as
    corrupt. A recording compressed so is read as before, with nothing said.
    """
    folder = tmp_path / 'rec'
    write_folder(folder)
    edit_metadata(folder, compression_format='zstd', compression_mode='message')
    _, messages, said, stats = read(folder)
    assert messages == expected() and stats.damaged_parts == 0
    (line,) = said
    assert line == (f'{folder}: metadata.yaml says its messages are compressed '
                    '(compression_mode: message), but those of rec.db3 are not; read as they are')
    compressed = tmp_path / 'compressed'
    write_folder(compressed, compressed=True)
    _, messages, said, stats = read(compressed)
    assert messages == expected() and not said and stats.damaged_parts == 0


def test_a_false_claim_of_file_compression_is_named(tmp_path: Path) -> None:
    """``compression_mode: file`` over plain files: named as metadata.yaml's, not as zstd's."""
    folder = tmp_path / 'rec'
    write_folder(folder)
    edit_metadata(folder, compression_format='zstd', compression_mode='file')
    _, messages, said, _ = read(folder)
    assert messages == expected()
    (line,) = said
    assert line == (f'{folder}: metadata.yaml says its storage files are compressed '
                    '(compression_mode: file), but they open as they are; they were read so')


def test_a_metadata_version_newer_than_the_reader_knows_is_said_so(tmp_path: Path) -> None:
    """``version: 99``: the storage files read, the version named (not rosbags' plea to report)."""
    folder = tmp_path / 'rec'
    write_folder(folder)
    edit_metadata(folder, version=99)
    _, messages, said, _ = read(folder)
    assert messages == expected()
    (line,) = said
    assert line == (f'{folder}: metadata.yaml is of rosbag2 metadata version 99, newer than the '
                    'reader knows (up to 9); its storage files were read as they are')
