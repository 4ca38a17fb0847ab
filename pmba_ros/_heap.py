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
"""Process-level heap tuning for the executables (``pmba``, ``pmba_node``, the benchmarks).

A solve allocates the same temporaries (100 kB to a few MB each) at every iteration. With
glibc's default settings freed memory at the top of the heap is given back to the kernel, and
arrays above the mmap threshold get fresh pages: every new array is then page-faulted in again.
Run back to back, small window solves then spend a noticeable share of their time in minor
page faults. Only the programs that own the process call :func:`keep_freed_memory`;
importing the library changes nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

logger = logging.getLogger(__name__)

#: mallopt(3) parameters (glibc malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: Arrays below this come from the heap (glibc's own dynamic limit on 64-bit systems).
MMAP_THRESHOLD_BYTES = 32 << 20
#: Free memory kept at the top of the heap before any is returned to the kernel.
TRIM_THRESHOLD_BYTES = 64 << 20


def keep_freed_memory() -> bool:
    """Keep freed heap memory in the process (glibc only); return whether it was applied."""
    name = ctypes.util.find_library('c')
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        logger.debug('no glibc mallopt: heap left at its defaults')
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = (mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
          and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1)
    if not ok:
        logger.debug('mallopt refused the heap settings')
    return ok
