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
"""Reports as strict JSON: numpy values made plain, non-finite numbers made ``null``."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def to_jsonable(value: Any) -> Any:
    """Return ``value`` with numpy scalars and arrays (also nested) turned into plain Python."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def finite_or_null(value: Any, where: str = '', nulled: list[str] | None = None) -> Any:
    """Return ``value`` (made plain) with every non-finite float replaced by None.

    Args:
        value: A report (dicts, lists, numbers, numpy values).
        where: Key path of ``value`` (for ``nulled``).
        nulled: Receives the key path of every replaced number.
    """
    value = to_jsonable(value)
    if isinstance(value, float) and not math.isfinite(value):
        if nulled is not None:
            nulled.append(where or '.')
        return None
    if isinstance(value, dict):
        return {k: finite_or_null(v, f'{where}.{k}' if where else k, nulled)
                for k, v in value.items()}
    if isinstance(value, list):
        # One entry per list: a cost history of many inf values is one finding.
        found: list[str] = []
        items = [finite_or_null(v, f'{where}[]', found) for v in value]
        if found and nulled is not None:
            nulled.append(f'{where}[]')
        return items
    return value


def dumps_report(report: dict[str, Any], warnings_key: str | None = 'warnings', *,
                 sort_keys: bool = True) -> str:
    """Return ``report`` as strict JSON (indented, newline-terminated).

    Non-finite numbers (JSON has no NaN or Infinity) become ``null``; their key paths are
    appended as one warning to ``report[warnings_key]`` (created if missing) unless
    ``warnings_key`` is None.
    """
    nulled: list[str] = []
    clean = finite_or_null(report, nulled=nulled)
    if nulled and warnings_key is not None:
        warnings = list(clean.get(warnings_key) or [])
        warnings.append(f'non-finite values written as null: {", ".join(nulled)}')
        clean[warnings_key] = warnings
    return json.dumps(clean, indent=2, sort_keys=sort_keys, allow_nan=False) + '\n'
