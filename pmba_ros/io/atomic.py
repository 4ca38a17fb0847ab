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
"""Atomic file output: a reader sees the old file or the complete new one, never a part.

Each file is written to a hidden temporary file beside it, flushed to disk and renamed over
the target. A failure (disk full, interrupt) removes the temporary file and re-raises, so the
target keeps its earlier content and the real cause is what the caller sees.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
from contextlib import contextmanager
import os
from pathlib import Path
import signal
from typing import Any, IO

from pmba_ros.errors import PmbaError


def temp_path(path: Path) -> Path:
    """Return the hidden temporary name used while writing ``path`` (same suffix)."""
    return path.with_name(f'.{path.stem}.{os.getpid()}.tmp{path.suffix}')


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
    except BaseException as err:
        _cleanup(tmp, path, err)
        raise


def _cleanup(tmp: Path, path: Path, err: BaseException) -> None:
    """Remove the temporary file; make an OSError name the target, not the temporary."""
    with contextlib.suppress(OSError):
        tmp.unlink(missing_ok=True)
    if isinstance(err, OSError) and err.filename == str(tmp):
        err.filename = str(path)


def prepare_output(path: Path, option: str) -> None:
    """Check before the work that ``path`` can be written (named ``option``), making its folder.

    The hidden temporary file :func:`atomic_open` writes is created beside it and removed:
    a folder that takes no new file (``/proc``, read-only) had failed only once the work whose
    result it was to hold was done (its table printed, then exit 1).

    Raises:
        PmbaError: If ``path`` is a folder, or its folder cannot be created or written in.
    """
    if path.is_dir():
        msg = f'{option} {path}: is a folder; give a file name'
        raise PmbaError(msg)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f'{option} {path}: cannot create its folder: {err}'
        raise PmbaError(msg) from err
    tmp = temp_path(path)
    try:
        with open(tmp, 'w', encoding='utf-8'):
            pass
        tmp.unlink()
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        msg = f'{option} {path}: cannot be written: {err.strerror or err}'
        raise PmbaError(msg) from err


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
    except BaseException as err:
        _cleanup(tmp, path, err)
        raise


@contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back until the block ends, then deliver the first one.

    For writing that must not be cut short (finalizing a bag, the output files). If the
    block itself raises, a held-back signal is dropped: the block's error is already on its
    way out. Outside the main thread (no signal handlers there) this does nothing.
    """
    received: list[int] = []

    def hold(signum: int, frame: object) -> None:
        received.append(signum)

    previous: dict[int, Any] = {}
    try:
        for sig in (int(signal.SIGINT), int(signal.SIGTERM)):
            previous[sig] = signal.signal(sig, hold)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if received:
        signal.raise_signal(received[0])
