"""Conformance harness: replays the original environments' golden traces against ours.

``python -m envs_jax.conformance FILE.npz [FILE …]`` prints one summary line per file, then
``N/N transitions match``, and exits non-zero on any mismatch, naming file, episode, step,
field and both values. ``check_file(path)`` does the same for one file from Python.
"""

from __future__ import annotations

import os

import numpy as np

from envs_jax.conformance import boxpushing as _boxpushing  # noqa: F401  (registers its adapter)
from envs_jax.conformance import overcooked as _overcooked  # noqa: F401
from envs_jax.conformance import warehouse as _warehouse  # noqa: F401
from envs_jax.conformance.common import ADAPTERS, FileReport, Mismatch, TraceAdapter, register_adapter

__all__ = ["check_file", "FileReport", "Mismatch", "TraceAdapter", "register_adapter", "ADAPTERS"]


def _load_trace(path: str) -> dict:
    """The arrays of the ``.npz`` trace ``path``; a file that is not one (empty, truncated, text, another format) is a
    one-line ``ValueError`` naming it (never a pickle load: ``allow_pickle=False``)."""
    import zipfile

    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such trace file")
    what = "an empty file" if os.path.getsize(path) == 0 else None
    if what is None and not zipfile.is_zipfile(path):
        what = "not a zip archive (truncated, or another kind of file)"
    if what is None:
        try:
            with np.load(path, allow_pickle=False) as npz:
                return {k: npz[k] for k in npz.files}
        except (EOFError, OSError, ValueError, zipfile.BadZipFile, KeyError) as err:
            what = f"unreadable ({type(err).__name__}: {' '.join(str(err).split())[:160]})"
    raise ValueError(f"{path} is not a readable .npz trace file: {what}; a trace is an .npz of a format of "
                     "docs/traces.md")


def check_file(path: str) -> FileReport:
    """Replay one trace file; raises ``ValueError`` if its format is not recognised."""
    data = _load_trace(path)
    for adapter in ADAPTERS:
        if adapter.detects(data):
            return adapter.check(path, data)
    raise ValueError(f"{path}: not a recognised trace format; known formats: {[a.name for a in ADAPTERS]}")
