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
"""Start-up tuning of the processes the package owns (``pmba``, ``pmba_node``, the benchmarks).

One call, :func:`tune_process`, at the start of an executable: the heap keeps freed memory
(:mod:`pmba_ros._heap`) and BLAS runs on one thread except where more pay
(:mod:`pmba_ros._threads`). Importing the library changes neither.
"""

from __future__ import annotations

from pmba_ros._heap import keep_freed_memory
from pmba_ros._threads import limit_blas_threads


def tune_process() -> None:
    """Apply the heap and thread-pool settings of the package's executables."""
    keep_freed_memory()
    limit_blas_threads()
