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
"""Argument types of the ``pmba`` verbs: range checks become usage errors (exit 2)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
import math


def _number(text: str, kind: type[int] | type[float]) -> float:
    try:
        value = kind(text)
    except ValueError:
        msg = f'expected {"an integer" if kind is int else "a number"}, got {text!r}'
        raise argparse.ArgumentTypeError(msg) from None
    if not math.isfinite(value):
        msg = f'expected a finite number, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative_int(text: str) -> int:
    """Parse an integer >= 0."""
    value = int(_number(text, int))
    if value < 0:
        msg = f'must be >= 0, got {value}'
        raise argparse.ArgumentTypeError(msg)
    return value


def positive_int(text: str) -> int:
    """Parse an integer >= 1."""
    value = int(_number(text, int))
    if value < 1:
        msg = f'must be >= 1, got {value}'
        raise argparse.ArgumentTypeError(msg)
    return value


def int_at_least(minimum: int) -> Callable[[str], int]:
    """Return a parser of an integer >= ``minimum``."""
    def parse(text: str) -> int:
        value = int(_number(text, int))
        if value < minimum:
            msg = f'must be >= {minimum}, got {value}'
            raise argparse.ArgumentTypeError(msg)
        return value
    return parse


def positive_float(text: str) -> float:
    """Parse a finite number > 0."""
    value = _number(text, float)
    if value <= 0:
        msg = f'must be > 0, got {text}'
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative_float(text: str) -> float:
    """Parse a finite number >= 0."""
    value = _number(text, float)
    if value < 0:
        msg = f'must be >= 0, got {text}'
        raise argparse.ArgumentTypeError(msg)
    return value


def finite_float(text: str) -> float:
    """Parse a finite number."""
    return _number(text, float)
