"""Shared helpers of the text-file readers."""

from __future__ import annotations

from pathlib import Path

from pmba_ros.errors import FormatError


def nonblank_lines(path: Path) -> tuple[list[str], list[int]]:
    """Return the non-blank lines of ``path`` and their 1-based line numbers.

    Raises:
        FormatError: If the file is not UTF-8 text.
    """
    try:
        text = path.read_text(encoding='utf-8')
    except UnicodeDecodeError as err:
        msg = f'{path}: not a text file ({err})'
        raise FormatError(msg) from err
    lines = text.splitlines()
    numbers = [i for i, s in enumerate(lines, start=1) if s.strip()]
    return [lines[i - 1] for i in numbers], numbers
