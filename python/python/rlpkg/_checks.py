"""Argument checks shared by the package's entry points: a wrong type is a TypeError, a value out
of range a ValueError, both naming the argument, what it expects and what it got."""

from __future__ import annotations

import numbers
from typing import Any, Callable

import numpy as np


def describe(value: Any) -> str:
    """``value`` for an error message: its repr and its type, e.g. ``True (a bool)``."""
    text = repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    kind = type(value).__name__
    return f"{text} ({'an' if kind[0] in 'aeiou' else 'a'} {kind})"


def fail(name: str, value: Any, expected: str, error: type[Exception] = ValueError) -> Exception:
    """The error for argument ``name``: ``name: expected <expected>, got <value> (a <type>)``."""
    return error(f"{name}: expected {expected}, got {describe(value)}")


def whole(name: str, value: Any, expected: str, low: int, high: int | None = None) -> int:
    """``value`` as an int in ``[low, high]``: a Python or NumPy integer, not a bool (True is not a
    count), else a TypeError; out of range a ValueError."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise fail(name, value, expected, TypeError)
    if value < low or (high is not None and value > high):
        raise fail(name, value, expected)
    return int(value)


def real(name: str, value: Any, expected: str, ok: Callable[[float], bool] | None = None) -> float:
    """``value`` as a float: a Python or NumPy real number, not a bool or a string, else a
    TypeError; a ValueError when ``ok`` refuses it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise fail(name, value, expected, TypeError)
    number = float(value)
    if ok is not None and not ok(number):
        raise fail(name, value, expected)
    return number
