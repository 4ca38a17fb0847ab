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
"""Message backends: who builds a message object, rclpy's classes or rosbags' dataclasses.

Message construction differs between rclpy and rosbags (``ros2_notes.md`` §3.2): rosbags
classes need every field and numpy arrays for primitive sequences, rclpy classes want
``array.array`` for unbounded sequences, Python ``float``/``int`` scalars and ``bytes``
byte constants. A :class:`MsgBackend` hides the difference from the builders of
:mod:`pmba_ros.backend.outputs` and :mod:`pmba_ros.sim.inputs`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
import array
from collections.abc import Callable
from dataclasses import dataclass
import importlib
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pmba_ros._typing import FloatArray
from pmba_ros.errors import MessageError


class MsgBackend(ABC):
    """Creates message objects and the container types their sequence fields need."""

    @abstractmethod
    def msg_class(self, type_name: str) -> Any:
        """Return the message class of ``type_name`` ('pkg/msg/Name').

        Raises:
            MessageError: If the type is unknown.
        """

    def new(self, type_name: str, **fields: Any) -> Any:
        """Return a new ``type_name`` message built from keyword fields.

        Args:
            type_name: Message type, e.g. 'nav_msgs/msg/Path'.
            **fields: Every field of the message.

        Returns:
            The message.

        Raises:
            MessageError: If the type is unknown.
        """
        return self.msg_class(type_name)(**fields)

    def constant(self, type_name: str, name: str) -> Any:
        """Return the class constant ``name`` of ``type_name`` (byte constants differ).

        Raises:
            MessageError: If the type or constant is unknown.
        """
        try:
            return getattr(self.msg_class(type_name), name)
        except AttributeError as err:
            msg = f'{type_name} has no constant {name!r}'
            raise MessageError(msg) from err

    @staticmethod
    def fixed_f64(values: ArrayLike) -> FloatArray:
        """Return a fixed-size ``float64[N]`` field value (numpy in both backends)."""
        return np.array(values, dtype=np.float64).reshape(-1)

    @abstractmethod
    def seq_f32(self, values: ArrayLike) -> Any:
        """Return an unbounded ``float32[]`` field value."""

    @abstractmethod
    def seq_f64(self, values: ArrayLike) -> Any:
        """Return an unbounded ``float64[]`` field value."""

    @abstractmethod
    def seq_u8(self, data: bytes | np.ndarray) -> Any:
        """Return an unbounded ``uint8[]`` field value from raw bytes."""


class RosbagsBackend(MsgBackend):
    """Messages as rosbags typestore dataclasses (default: the pinned ROS 2 Jazzy store).

    Args:
        typestore: A rosbags ``Typestore``; ``None`` loads
            ``get_typestore(Stores.ROS2_JAZZY)`` (rosbags is imported only then).
    """

    def __init__(self, typestore: Any = None) -> None:
        """Store the typestore, loading the Jazzy one if none is given."""
        if typestore is None:
            from rosbags.typesys import get_typestore, Stores
            typestore = get_typestore(Stores.ROS2_JAZZY)
        self.typestore = typestore

    def msg_class(self, type_name: str) -> Any:
        """Return the typestore class of ``type_name``.

        Raises:
            MessageError: If the typestore does not know the type.
        """
        try:
            return self.typestore.types[type_name]
        except KeyError as err:
            msg = f'type {type_name!r} is not in the rosbags typestore'
            raise MessageError(msg) from err

    def seq_f32(self, values: ArrayLike) -> np.ndarray:
        """Return a float32 numpy array (``serialize_cdr`` rejects lists)."""
        return np.array(values, dtype=np.float32).reshape(-1)

    def seq_f64(self, values: ArrayLike) -> np.ndarray:
        """Return a float64 numpy array."""
        return np.array(values, dtype=np.float64).reshape(-1)

    def seq_u8(self, data: bytes | np.ndarray) -> np.ndarray:
        """Return a uint8 numpy array (a copy)."""
        return np.frombuffer(data, dtype=np.uint8).copy()

    def serialize(self, msg: Any) -> bytes:
        """Serialize a message of this typestore to CDR.

        Raises:
            MessageError: If the message does not serialize.
        """
        try:
            return bytes(self.typestore.serialize_cdr(msg, msg.__msgtype__))
        except Exception as err:
            msg_ = f'cannot serialize {getattr(msg, "__msgtype__", type(msg).__name__)}: {err}'
            raise MessageError(msg_) from err


class RclpyBackend(MsgBackend):
    """Messages as rclpy (rosidl-generated) classes, imported lazily by type name.

    It never imports rclpy, only message modules such as ``nav_msgs.msg``. Unbounded
    sequences are ``array.array`` (rosidl setters take the fast path for them; ``bytes``
    for ``uint8[]`` is also accepted, but then checked element by element under
    ``__debug__``).

    Args:
        module_loader: Imports a module by dotted name (default
            :func:`importlib.import_module`); tests may inject fake message modules.
    """

    def __init__(self, module_loader: Callable[[str], ModuleType] | None = None) -> None:
        """Store the loader and an empty class cache."""
        self._loader = module_loader or importlib.import_module
        self._cache: dict[str, Any] = {}

    def msg_class(self, type_name: str) -> Any:
        """Return the class of 'pkg/msg/Name' (or 'pkg/Name') from module ``pkg.msg``.

        Raises:
            MessageError: If the module or class cannot be loaded.
        """
        cls = self._cache.get(type_name)
        if cls is None:
            parts = type_name.split('/')
            if len(parts) == 2:
                parts.insert(1, 'msg')
            if len(parts) != 3 or not all(parts):
                msg = f'bad message type name {type_name!r} (want pkg/msg/Name)'
                raise MessageError(msg)
            try:
                cls = getattr(self._loader(f'{parts[0]}.{parts[1]}'), parts[2])
            except (ImportError, AttributeError) as err:
                msg = f'cannot load message type {type_name!r}: {err}'
                raise MessageError(msg) from err
            self._cache[type_name] = cls
        return cls

    def seq_f32(self, values: ArrayLike) -> array.array[float]:
        """Return ``array.array('f')`` (rclpy rejects numpy arrays for float32[])."""
        out = array.array('f')
        out.frombytes(np.asarray(values, dtype=np.float32).reshape(-1).tobytes())
        return out

    def seq_f64(self, values: ArrayLike) -> array.array[float]:
        """Return ``array.array('d')``."""
        out = array.array('d')
        out.frombytes(np.asarray(values, dtype=np.float64).reshape(-1).tobytes())
        return out

    def seq_u8(self, data: bytes | np.ndarray) -> array.array[int]:
        """Return ``array.array('B')`` holding ``data``."""
        out = array.array('B')
        out.frombytes(np.frombuffer(data, dtype=np.uint8).tobytes())
        return out


@dataclass
class TransformsStandIn:
    """Stand-in for tf2_msgs/TFMessage where tf2_msgs is missing (never published as such)."""

    transforms: list[Any]


class NodeMsgBackend(RclpyBackend):
    """rclpy messages; a TFMessage stand-in where tf2_msgs is not importable."""

    def msg_class(self, type_name: str) -> Any:
        """Return the rclpy class of ``type_name`` (:class:`TransformsStandIn` for TFMessage)."""
        try:
            return super().msg_class(type_name)
        except MessageError:
            if type_name == 'tf2_msgs/msg/TFMessage':
                return TransformsStandIn
            raise


__all__ = ['MsgBackend', 'NodeMsgBackend', 'RclpyBackend', 'RosbagsBackend',
           'TransformsStandIn']
