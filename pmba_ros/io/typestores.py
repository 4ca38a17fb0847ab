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
"""The message definitions bags are read with: pinned rosbags typestores, and deserializers."""

from __future__ import annotations

from collections.abc import Callable
import functools
from functools import lru_cache
from typing import Any

__all__ = ['deserializer', 'jazzy_typestore', 'noetic_typestore']


@lru_cache(maxsize=1)
def jazzy_typestore() -> Any:
    """Return the pinned ROS 2 Jazzy rosbags typestore (``Stores.LATEST`` is Kilted)."""
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


@lru_cache(maxsize=1)
def noetic_typestore() -> Any:
    """Return rosbags' ROS 1 Noetic typestore (the standard ROS 1 message definitions)."""
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS1_NOETIC)


EMPTY_STRUCTURE_FIELD = 'structure_needs_at_least_one_member'
"""The one field rosbags gives a type whose definition has none."""


def deserializer(reader: Any, msgtype: str) -> Callable[[bytes | memoryview], Any]:
    """Return ``raw -> message`` for ``msgtype`` of an open reader.

    rosbags builds a reader's typestore from the bag's message definitions at every opening,
    and generates a type's (de)serializers at its first message. A ROS 2 type defined exactly
    as in Jazzy, nested types included, is read with the process' Jazzy typestore instead,
    whose generated code stays (the result bag's writer shares it): the same values, and
    errors raised as the reader raises them.
    """
    jazzy = jazzy_typestore()
    theirs = reader.typestore.fielddefs.get(msgtype)
    # A schema recorded without its text (empty) defines no fields (rosbags gives it the
    # placeholder an empty IDL structure gets): Jazzy's type is meant.
    names = [] if theirs is None else [name for name, _ in theirs[1]]
    undefined = theirs is not None and names in ([], [EMPTY_STRUCTURE_FIELD]) and \
        bool(jazzy.fielddefs.get(msgtype, ((), ()))[1])
    if not reader.is2 or not (undefined or _defined_alike(
            reader.typestore.fielddefs, jazzy.fielddefs, msgtype, set())):
        return functools.partial(reader.deserialize, typ=msgtype)
    from rosbags.highlevel import AnyReaderError
    from rosbags.serde import SerdeError

    def deserialize(raw: bytes | memoryview) -> Any:
        try:
            return jazzy.deserialize_cdr(raw, msgtype)
        except SerdeError as err:   # as AnyReader.deserialize converts it
            raise AnyReaderError(*err.args) from None
    return deserialize


def _defined_alike(defs: dict[str, Any], reference: dict[str, Any], msgtype: str,
                   seen: set[str]) -> bool:
    """Return True if ``msgtype`` and the types it nests have the same fields in both."""
    if msgtype in seen:
        return True
    seen.add(msgtype)
    if msgtype not in defs or defs[msgtype] != reference.get(msgtype):
        return False
    nested: list[Any] = [desc for _, desc in defs[msgtype][1]]
    while nested:
        item = nested.pop()
        if isinstance(item, tuple):
            nested.extend(item)
        elif isinstance(item, str) and item in defs and \
                not _defined_alike(defs, reference, item, seen):
            return False
    return True
