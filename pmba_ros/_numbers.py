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
"""Numbers in text files as the formats' own tools read them (C's strtod), not as Python does."""

from __future__ import annotations

__all__ = ['is_number', 'python_only']


def python_only(text: str) -> bool:
    """Return True if ``text`` may hold a number that only Python reads.

    Python's float() and int(), and numpy's conversion of strings that calls them, also read
    digits grouped by underscores ('1_000') and the digits of other scripts; numpy's
    loadtxt and the formats' own tools refuse them. A reader whose fast path converts with
    numpy checks its numbers' text with this (one scan, no copy) and names the first such
    token with :func:`is_number`, as any other non-numeric one.
    """
    return '_' in text or not text.isascii()


def is_number(token: str) -> bool:
    """Return True if ``token`` is a number as C's strtod reads it (not '1_000', not '\uff11')."""
    if python_only(token):
        return False
    try:
        float(token)
    except ValueError:
        return False
    return True
