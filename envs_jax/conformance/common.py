"""Shared pieces of the conformance harness: reports, field comparison, adapter registry.

A *trace adapter* knows one trace format (``docs/traces.md``): it says
whether an opened ``.npz`` is in its format and replays it against our env, one-step from
every recorded pre-state and as whole episodes from the recorded start state.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Mapping

import numpy as np


@dataclasses.dataclass(frozen=True)
class Mismatch:
    episode: int
    step: int
    field: str
    expected: str
    got: str
    mode: str  # "one-step" or "rollout"

    def describe(self, path: str) -> str:
        return (
            f"{path}: episode {self.episode}, step {self.step} ({self.mode}): field {self.field!r} "
            f"expected {self.expected}, got {self.got}"
        )


@dataclasses.dataclass(frozen=True)
class FileReport:
    path: str
    format: str
    episodes: int
    transitions: int
    matched: int  # transitions matching both one-step and in the episode rollout
    first_mismatch: Mismatch | None

    @property
    def ok(self) -> bool:
        return self.first_mismatch is None and self.matched == self.transitions

    def summary(self) -> str:
        status = "OK" if self.ok else "MISMATCH"
        return (
            f"{status} {self.path} [{self.format}]: {self.episodes} episodes, "
            f"{self.matched}/{self.transitions} transitions match"
        )


def compare_fields(
    expected: Mapping[str, np.ndarray],
    got: Mapping[str, np.ndarray],
    valid: np.ndarray,
    atol: Mapping[str, float] | None = None,
    mode: str = "one-step",
) -> tuple[np.ndarray, Mismatch | None]:
    """Compare per-transition fields laid out ``[E, L, ...]``.

    Integer/bool fields must be equal; fields named in ``atol`` are compared with that
    absolute tolerance. Returns ``ok[E, L]`` (False where any field differs; padding is
    True) and the first mismatch in (episode, step, field order).
    """
    atol = atol or {}
    ok = np.ones(valid.shape, bool)
    first: Mismatch | None = None
    for name, exp in expected.items():
        g = np.asarray(got[name])
        exp = np.asarray(exp)
        if g.shape != exp.shape:
            raise ValueError(f"field {name!r}: shape {g.shape} does not match the trace's {exp.shape}")
        if name in atol:
            close = np.isclose(g.astype(np.float64), exp.astype(np.float64), rtol=0.0, atol=atol[name])
        else:
            close = g == exp
        field_ok = close.reshape(*valid.shape, -1).all(-1) | ~valid
        ok &= field_ok
        bad = np.argwhere(~field_ok)
        if len(bad):
            e, t = (int(v) for v in bad[0])
            cand = Mismatch(e, t, name, _fmt(exp[e, t]), _fmt(g[e, t]), mode)
            if first is None or (e, t) < (first.episode, first.step):
                first = cand
    return ok, first


def _fmt(x: np.ndarray) -> str:
    return np.array2string(np.asarray(x), precision=6, separator=",", max_line_width=10_000)


@dataclasses.dataclass(frozen=True)
class TraceAdapter:
    name: str
    detects: Callable[[Mapping[str, np.ndarray]], bool]
    check: Callable[[str, Mapping[str, np.ndarray]], FileReport]


ADAPTERS: list[TraceAdapter] = []


def register_adapter(adapter: TraceAdapter) -> None:
    ADAPTERS.append(adapter)
