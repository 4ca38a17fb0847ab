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
