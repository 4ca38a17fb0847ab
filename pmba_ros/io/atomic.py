"""Atomic file output: a reader sees the old file or the complete new one, never a part.

Each file is written to a hidden temporary file beside it, flushed to disk and renamed over
the target. A failure (disk full, interrupt) removes the temporary file and re-raises, so the
target keeps its earlier content and the real cause is what the caller sees.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
import os
from pathlib import Path
from typing import IO


def temp_path(path: Path) -> Path:
    """Return the hidden temporary name used while writing ``path``."""
    return path.with_name(f'.{path.name}.{os.getpid()}.tmp')


@contextmanager
def atomic_open(path: Path | str, mode: str = 'w') -> Iterator[IO]:
    """Open a temporary file for writing that replaces ``path`` when the block succeeds.

    Args:
        path: Final file.
        mode: 'w' (text, UTF-8) or 'wb'.

    Yields:
        The open temporary file.

    Raises:
        OSError: If writing, syncing or renaming fails (the temporary file is removed).
    """
    path = Path(path)
    tmp = temp_path(path)
    try:
        encoding = None if 'b' in mode else 'utf-8'
        with open(tmp, mode, encoding=encoding) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: Path | str, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_open(path) as fh:
        fh.write(text)


def write_atomic(path: Path | str, writer: Callable[[Path], object]) -> None:
    """Let ``writer(tmp)`` write a file by name, then rename it to ``path`` atomically.

    For writers that take a path (numpy, the TUM and PLY writers).

    Raises:
        OSError: If the rename fails; whatever ``writer`` raises (the temporary file is
            removed in both cases).
    """
    path = Path(path)
    tmp = temp_path(path)
    try:
        writer(tmp)
        with open(tmp, 'rb+') as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
