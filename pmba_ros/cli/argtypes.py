"""Argument types of the ``pmba`` verbs: range checks become usage errors (exit 2)."""

from __future__ import annotations

import argparse
import math


def _number(text: str, kind: type[int] | type[float]) -> float:
    try:
        value = kind(text)
    except ValueError:
        msg = f'expected {"an integer" if kind is int else "a number"}, got {text!r}'
        raise argparse.ArgumentTypeError(msg) from None
    if not math.isfinite(value):
        msg = f'expected a finite number, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative_int(text: str) -> int:
    """Parse an integer >= 0."""
    value = int(_number(text, int))
    if value < 0:
        msg = f'must be >= 0, got {value}'
        raise argparse.ArgumentTypeError(msg)
    return value


def positive_int(text: str) -> int:
    """Parse an integer >= 1."""
    value = int(_number(text, int))
    if value < 1:
        msg = f'must be >= 1, got {value}'
        raise argparse.ArgumentTypeError(msg)
    return value


def positive_float(text: str) -> float:
    """Parse a finite number > 0."""
    value = _number(text, float)
    if value <= 0:
        msg = f'must be > 0, got {text}'
        raise argparse.ArgumentTypeError(msg)
    return value


def non_negative_float(text: str) -> float:
    """Parse a finite number >= 0."""
    value = _number(text, float)
    if value < 0:
        msg = f'must be >= 0, got {text}'
        raise argparse.ArgumentTypeError(msg)
    return value


def finite_float(text: str) -> float:
    """Parse a finite number."""
    return _number(text, float)
