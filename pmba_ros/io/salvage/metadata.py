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
"""A rosbag2 folder whose ``metadata.yaml`` its storage files contradict, or rosbags refuses.

rosbags reads a folder by what its ``metadata.yaml`` says: the topics' types, the messages'
compression, the files. Where that is wrong the storage files, whose own topic tables are the
truth for their messages, are read alone instead (:func:`~pmba_ros.io.salvage.readable_parts`),
and what was wrong is said in ``metadata.yaml``'s name, not as damage to the files.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import closing, ExitStack
from pathlib import Path
from typing import Any

from pmba_ros.errors import BagError
from pmba_ros.io.bags import (
    any_reader,
    error_text,
    reader_errors,
    ros2_type_name,
    storage_files,
    ZSTD_MAGIC,
)
from pmba_ros.io.mcap_layout import zstd_module

__all__ = ['contradictions', 'metadata_refusal', 'newer_version', 'opened_whole', 'unlisted']

KNOWN_VERSION = 9
"""The newest rosbag2 metadata version rosbags' folder reader reads (it refuses the others)."""


def _information(folder: Path) -> dict[str, Any] | None:
    """Return the ``rosbag2_bagfile_information`` of a folder's metadata.yaml, if it reads."""
    import yaml

    if not (folder / 'metadata.yaml').is_file():
        return None
    try:
        info = yaml.safe_load((folder / 'metadata.yaml').read_text(encoding='utf-8'))
        found = info['rosbag2_bagfile_information']
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return None
    return found if isinstance(found, dict) else None


def unlisted(folder: Path) -> list[Path]:
    """Return the storage files in a rosbag2 folder that its ``metadata.yaml`` does not list.

    A split the recorder began after it last wrote the metadata, or a file copied in: rosbags
    reads the listed files only. A file, a folder without metadata and an unreadable metadata
    file list nothing here (opening the folder names what is wrong with it).
    """
    info = _information(folder)
    try:
        listed = {Path(str(name)).name for name in info['relative_file_paths']} if info else None
    except (KeyError, TypeError):
        listed = None
    return [] if listed is None else [f for f in storage_files(folder) if f.name not in listed]


def newer_version(folder: Path) -> str | None:
    """Return what is wrong if a folder's metadata.yaml is of a version rosbags refuses."""
    version = (_information(folder) or {}).get('version')
    if not isinstance(version, int) or version <= KNOWN_VERSION:
        return None
    return (f'metadata.yaml is of rosbag2 metadata version {version}, newer than the reader '
            f'knows (up to {KNOWN_VERSION}); its storage files were read as they are')


def metadata_refusal(folder: Path, error: BagError) -> str:
    """Return why rosbags refused a folder whose storage files each open alone.

    ``error`` is rosbags' refusal; a claim of whole-file compression that the files belie
    (they open as they are) is named as such, not as the zstd error it gave.
    """
    mode = str((_information(folder) or {}).get('compression_mode', '')).lower()
    if mode == 'file' and isinstance(error.__cause__, zstd_module().ZstdError):
        return ('metadata.yaml says its storage files are compressed (compression_mode: file), '
                'but they open as they are; they were read so')
    return f'{error_text(error.__cause__ or error)}; its storage files were read one by one'


def opened_whole(paths: Sequence[Path], stack: ExitStack,
                 ) -> tuple[Any, BagError | None, list[str]]:
    """Open recordings together, unless a folder's metadata.yaml contradicts its storage files.

    Returns:
        The reader (left open by ``stack``), or None with why rosbags did not open the
        recordings, or with the :func:`contradictions` found (then reading the storage files
        alone reads them right).
    """
    with ExitStack() as attempt:
        try:
            reader = attempt.enter_context(any_reader(paths))
        except BagError as err:
            return None, err, []
        try:
            said = contradictions(reader)
        except reader_errors():   # damage in a first message: met again when reading on
            said = []
        if said:
            return None, None, said
        stack.enter_context(attempt.pop_all())
        return reader, None, []


def contradictions(reader: Any) -> list[str]:
    """Return what the metadata.yaml of an open reader's folders says that their files belie.

    A topic's type (rosbags then matches none of the file's messages to the topic, and the
    topic keeps the wrong type), and per-message compression of messages stored plain
    (rosbags fails on the first). One line each, naming the folder. A folder of compressed
    files (compression_mode: file) is not checked: its files would not open alone.
    """
    from rosbags.rosbag2.reader import DirectoryReader

    said: list[str] = []
    folders = [r.storage for r in reader.readers] if reader.is2 else []
    for folder in (f for f in folders if isinstance(f, DirectoryReader)):
        if folder.metadata.compression_mode == 'file':
            continue
        recorded: dict[str, dict[str, list[str]]] = {}
        for storage in folder.storages:
            for conn in storage.connections:
                files = recorded.setdefault(conn.topic, {}).setdefault(
                    ros2_type_name(conn.msgtype), [])
                files.append(_name(storage))
        for conn in folder.connections:
            types = recorded.get(conn.topic, {})
            if types and ros2_type_name(conn.msgtype) not in types:
                where = '; '.join(f'{", ".join(names)} records {t}' for t, names in types.items())
                said.append(f'{folder.path}: metadata.yaml gives topic {conn.topic!r} the type '
                            f'{conn.msgtype}, but {where}; read as the storage files say')
        if folder.metadata.compression_mode == 'message':
            plain = [_name(s) for s in folder.storages if _stored_plain(s)]
            if plain:
                said.append(f'{folder.path}: metadata.yaml says its messages are compressed '
                            f'(compression_mode: message), but those of {", ".join(plain)} are '
                            'not; read as they are')
    return said


def _name(storage: Any) -> str:
    """Return the file name of one of a folder reader's storage readers.

    rosbags' storage readers (MCAP, SQLite) keep their path; their protocol does not say so.
    """
    return Path(storage.path).name


def _stored_plain(storage: Any) -> bool:
    """Return True if a storage file's first message is not a zstd frame (it is plain CDR)."""
    if not storage.connections:
        return False
    with closing(storage.messages(storage.connections)) as stream:
        first = next(stream, None)
    return first is not None and bytes(first[2][:4]) != ZSTD_MAGIC
