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
"""keep_freed_memory: repeated large temporaries stop page-faulting (glibc)."""

from __future__ import annotations

import platform
import subprocess
import sys

from pmba_ros import _heap
import pytest

_PROBE = """
import resource, sys
import numpy as np
from pmba_ros._heap import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == '1' else False
x = np.ones((40_000, 3, 3)); w = x * 2.0; del x, w  # 2.9 MB each: above the default mmap threshold
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(50):
    y = np.ones((40_000, 3, 3))
    z = y * 2.0
    del y, z
print(int(applied), resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(apply: bool) -> tuple[bool, int]:
    out = subprocess.run([sys.executable, '-c', _PROBE, '1' if apply else '0'], check=True,
                         capture_output=True, text=True).stdout.split()
    return out[0] == '1', int(out[1])


@pytest.mark.skipif(platform.system() != 'Linux' or platform.libc_ver()[0] != 'glibc',
                    reason='mallopt is glibc-specific')
def test_keep_freed_memory_stops_refaulting() -> None:
    """With the setting, 100 allocations of 2.9 MB arrays touch no new page."""
    applied, with_setting = _faults(True)
    assert applied
    _, default = _faults(False)
    # 100 arrays x 700 pages each would be 70,000 faults if every one got fresh pages.
    assert with_setting < 500
    assert default > 10 * with_setting, (default, with_setting)


def test_keep_freed_memory_without_libc(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without a C library exposing mallopt it reports False instead of failing."""
    monkeypatch.setattr(_heap.ctypes.util, 'find_library', lambda _name: 'no-such-libc.so')
    assert _heap.keep_freed_memory() is False
