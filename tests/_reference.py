"""Where the golden traces of the original environments live: ``tests/data/traces/<domain>``.

They are part of the repository (format and provenance: ``docs/traces.md``). Conformance is not
optional, so a missing trace fails the trace tests (``require_traces``) instead of skipping them.
"""

from __future__ import annotations

import glob
import os

TRACES_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "traces")


def trace_dir(domain: str) -> str:
    """``tests/data/traces/<domain>``."""
    return os.path.join(TRACES_DIR, domain)


def trace_files(domain: str, pattern: str) -> list[str]:
    """Sorted trace files of ``domain`` matching ``pattern`` ([] when none; see :func:`require_traces`)."""
    return sorted(glob.glob(os.path.join(trace_dir(domain), pattern)))


def require_traces(domain: str, files: list[str]) -> None:
    """Fail the calling test, saying where it looked, when ``files`` (from :func:`trace_files`) is empty."""
    assert files, f"no {domain} traces in {trace_dir(domain)} (they are committed under tests/data/traces)"
