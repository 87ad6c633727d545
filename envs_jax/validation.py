"""Checks of user-given settings shared by the envs and the trainer (the bottom layer of the project).

``bool`` is a subclass of ``int`` in Python, so ``True`` would pass a plain ``isinstance(x, int)``; these helpers
refuse it wherever a count or a width is asked for.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def is_integer(value: Any) -> bool:
    """An int (Python or NumPy), not a bool."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def is_positive_integer(value: Any) -> bool:
    return is_integer(value) and value >= 1


def has_type(value: Any, hint: Any) -> bool:
    """Whether ``value`` fits a settings field typed ``hint``: int (not bool), float (ints accepted), bool, str,
    ``tuple[int, ...]``; other hints are not checked."""
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return is_integer(value)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if getattr(hint, "__origin__", None) is tuple:
        return isinstance(value, tuple) and all(is_integer(v) for v in value)
    return True


def type_name(hint: Any) -> str:
    return getattr(hint, "__name__", None) or str(hint)


def check_choice(owner: str, name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{owner}: {name}={value!r} is not valid; choices: {list(choices)}")


def check_positive(owner: str, obj: Any, names: tuple[str, ...]) -> None:
    """Each field of ``obj`` named in ``names`` is >= 1 (a tuple: non-empty, every entry >= 1)."""
    for name in names:
        value = getattr(obj, name)
        if isinstance(value, tuple):
            if not value or any(v < 1 for v in value):
                raise ValueError(f"{owner}: {name}={value!r} must be a non-empty list of positive integers")
        elif value < 1:
            raise ValueError(f"{owner}: {name}={value!r} must be >= 1")


def check_fraction(owner: str, name: str, value: float, low_open: bool = True) -> None:
    """``value`` in (0, 1] (``low_open``) or [0, 1]."""
    ok = (0.0 < value <= 1.0) if low_open else (0.0 <= value <= 1.0)
    if not ok:
        raise ValueError(f"{owner}: {name}={value!r} must be in {'(0' if low_open else '[0'}, 1]")


def parse_value(key: str, raw: str, kind: Any) -> Any:
    """A ``key=value`` string's value as the field's type (``tuple[int, ...]``: "64,64" or "64 64")."""
    try:
        if kind is bool:
            if raw.lower() in ("true", "1", "yes"):
                return True
            if raw.lower() in ("false", "0", "no"):
                return False
            raise ValueError
        if kind is int:
            return int(raw.replace("_", ""))
        if kind is float:
            return float(raw)
        if kind is str:
            return raw
        return tuple(int(v.replace("_", "")) for v in raw.replace(",", " ").split())  # tuple[int, ...]
    except ValueError:
        raise ValueError(f"config {key}={raw!r} is not a valid {type_name(kind)}") from None
