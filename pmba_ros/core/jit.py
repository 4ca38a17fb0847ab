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
"""numba for the compiled loops of :mod:`pmba_ros.core.compiled`: the switch and the cache.

``PMBA_NUMBA=0`` is read before numba is imported: the loops then stay plain Python (the
numpy engine runs) and numba is never loaded. numba compiles a loop once and keeps the machine
code on disk; by default next to the source (``pmba_ros/core/compiled/__pycache__``). An
install that the user cannot write to (a system install run by another user) gets a per-user
folder instead, named once in a warning (:class:`CacheWarning`) when it is created:
``$XDG_CACHE_HOME/pmba_ros/numba`` (``~/.cache/...``), else a private folder in the temporary
directory. ``NUMBA_CACHE_DIR``, if set, is numba's own choice and is left alone. With no
writable place at all the loops are compiled in memory, in every process.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import importlib
import os
from pathlib import Path
import stat
import tempfile
import threading
from typing import Any
import warnings

#: The loops' source folder; numba's default cache is its ``__pycache__``.
SOURCE_DIR = Path(__file__).resolve().parent / 'compiled'


class CacheWarning(UserWarning):
    """The compiled loops are cached outside the package, or not at all."""


def wanted() -> bool:
    """Return False when the user turned the compiled loops off (``PMBA_NUMBA=0``)."""
    return os.environ.get('PMBA_NUMBA', '1') != '0'


def _import_numba() -> Any:
    """Return the numba module, or None where it is turned off or not installed (an extra)."""
    if not wanted():
        return None
    try:
        return importlib.import_module('numba')
    except ImportError:
        return None


def _private_dir(path: Path) -> bool:
    """Create ``path`` if needed; return whether this user owns it, alone, and can write it.

    A folder another user could write to could hand us machine code to load, so it is
    refused.
    """
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        info = path.stat()
        if info.st_uid != os.getuid() or info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return False
        with tempfile.TemporaryFile(dir=path):
            return True
    except OSError:
        return False


def _writable(path: Path) -> bool:
    """Return whether files can be created in ``path`` (created if missing)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            return True
    except OSError:
        return False


def user_cache_dirs() -> Iterator[Path]:
    """Yield the per-user cache folders to try, in order."""
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    yield Path(base) / 'pmba_ros' / 'numba'
    yield Path(tempfile.gettempdir()) / f'pmba_ros-numba-{os.getuid()}'


def choose_cache(numba: Any) -> bool:
    """Point numba's cache where this user can write; return whether loops can be cached.

    Sets ``numba.config.CACHE_DIR`` only when the source folder is not writable.
    """
    if os.environ.get('NUMBA_CACHE_DIR') or _writable(SOURCE_DIR / '__pycache__'):
        return True
    for folder in user_cache_dirs():
        existed = folder.is_dir()
        if _private_dir(folder):
            numba.config.CACHE_DIR = str(folder)
            if not existed:
                warnings.warn(f'{SOURCE_DIR} is not writable: compiled solver loops are '
                              f'cached in {folder}', CacheWarning, stacklevel=2)
            return True
    tried = ', '.join(str(f) for f in [SOURCE_DIR, *user_cache_dirs()])
    warnings.warn(f'no writable cache folder for the compiled solver loops ({tried}): they '
                  'are compiled again in every process', CacheWarning, stacklevel=2)
    return False


NUMBA = _import_numba()
#: Whether compiled loops are kept on disk between processes.
CACHING = choose_cache(NUMBA) if NUMBA is not None else False
#: Set while the loops are being compiled beside the process's work, or that failed
#: (:func:`pmba_ros.core.warmup.warm_up_in_background`): the 'auto' engine is the numpy one
#: meanwhile, as a call into a loop not compiled yet would compile it there and then.
NOT_READY = threading.Event()


def cache_folder() -> Path | None:
    """Return the folder numba caches the loops in (None: not cached, or no numba)."""
    if NUMBA is None or not CACHING:
        return None
    chosen = NUMBA.config.CACHE_DIR
    return Path(chosen) if chosen else SOURCE_DIR / '__pycache__'


def numba_version() -> str:
    """Return the version of the numba in use ('' without numba)."""
    return str(getattr(NUMBA, '__version__', ''))


def jit(fn: Callable[..., Any]) -> Any:
    """Compile ``fn`` lazily (cached on disk where possible) when numba is there, else keep it."""
    if NUMBA is None:
        return fn
    return NUMBA.njit(cache=CACHING, nogil=True, inline='always')(fn)
