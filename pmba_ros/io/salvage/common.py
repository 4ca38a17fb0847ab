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
"""What a salvage of a damaged storage file made."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

__all__ = ['Salvaged']


class Salvaged(NamedTuple):
    """A readable copy of a damaged storage file.

    Attributes:
        path: The new, complete storage file.
        messages: Messages copied.
        damage: What was wrong with the original and where reading stopped (the original's
            name is not in it: the copy may be read from another copy); empty for a copy
            of an undamaged file into a format rosbags reads.
    """

    path: Path
    messages: int
    damage: str
