"""``envs_jax.make(name, **overrides)``: the environment registry.

Each domain registers a *family*: a name pattern, the list of valid names (for error
messages) and a builder ``build(match, overrides) -> MacroEnv``. Configurations are frozen
dataclasses; ``apply_overrides`` validates names and types of the overrides up front.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from typing import Any, Callable

from envs_jax.core import MacroEnv
from envs_jax.validation import has_type, type_name


@dataclasses.dataclass(frozen=True)
class Family:
    pattern: re.Pattern
    valid_names: str  # human-readable description of the valid names
    build: Callable[[re.Match, dict[str, Any]], MacroEnv]


_FAMILIES: dict[str, Family] = {}


def register(prefix: str, pattern: str, valid_names: str, build: Callable[[re.Match, dict], MacroEnv]):
    """Register a family of env names ``prefix-…`` matched by the regex ``pattern``."""
    _FAMILIES[prefix] = Family(re.compile(pattern), valid_names, build)


def registered_names() -> str:
    """Human-readable list of every valid env name."""
    return "; ".join(f.valid_names for f in _FAMILIES.values())


def make(name: str, **overrides: Any) -> MacroEnv:
    """Build an environment by name, e.g. ``make("boxpushing-6x6", horizon=50)``.

    Raises ``ValueError`` naming the bad value and the valid choices for an unknown name,
    an out-of-range size, or an unknown / ill-typed override.
    """
    if not isinstance(name, str):
        raise ValueError(f"env name must be a string, got {name!r}; valid names: {registered_names()}")
    for family in _FAMILIES.values():
        match = family.pattern.fullmatch(name)
        if match:
            return family.build(match, overrides)
    raise ValueError(f"unknown env name {name!r}; valid names: {registered_names()}")


def apply_overrides(config: Any, overrides: dict[str, Any], env_name: str) -> Any:
    """Return ``config`` (a frozen dataclass) with ``overrides`` applied, checking each
    key is a field and each value has the field's type (ints are accepted for floats)."""
    fields = {f.name: f for f in dataclasses.fields(config)}
    hints = typing.get_type_hints(type(config))
    for key, value in overrides.items():
        if key not in fields or not fields[key].init:
            raise ValueError(
                f"{env_name}: unknown override {key!r}; valid overrides: {sorted(k for k, f in fields.items() if f.init)}"
            )
        if hints[key] in (int, float, bool, str) and not has_type(value, hints[key]):
            raise ValueError(f"{env_name}: override {key}={value!r} must be of type {type_name(hints[key])}")
    return dataclasses.replace(config, **overrides)
