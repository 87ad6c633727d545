"""Conformance harness: replays the original environments' golden traces against ours.

``python -m envs_jax.conformance FILE.npz [FILE …]`` prints one summary line per file, then
``N/N transitions match``, and exits non-zero on any mismatch, naming file, episode, step,
field and both values. ``check_file(path)`` does the same for one file from Python.
"""

from __future__ import annotations

import numpy as np

from envs_jax.conformance import boxpushing as _boxpushing  # noqa: F401  (registers its adapter)
from envs_jax.conformance import overcooked as _overcooked  # noqa: F401
from envs_jax.conformance import warehouse as _warehouse  # noqa: F401
from envs_jax.conformance.common import ADAPTERS, FileReport, Mismatch, TraceAdapter, register_adapter

__all__ = ["check_file", "FileReport", "Mismatch", "TraceAdapter", "register_adapter", "ADAPTERS"]


def check_file(path: str) -> FileReport:
    """Replay one trace file; raises ``ValueError`` if its format is not recognised."""
    with np.load(path, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    for adapter in ADAPTERS:
        if adapter.detects(data):
            return adapter.check(path, data)
    raise ValueError(f"{path}: not a recognised trace format; known formats: {[a.name for a in ADAPTERS]}")
