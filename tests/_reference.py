"""Where the golden traces of the original environments live.

They are in ``shared/reference/<domain>/traces`` next to the checkout (``../shared`` from the
repository root, as in CI). A checkout elsewhere points ``JAXMAC_SHARED`` at that ``shared``
folder. Conformance is not optional, so a missing folder fails the trace tests (``require_traces``)
instead of skipping them.
"""

from __future__ import annotations

import glob
import os

SHARED_DIR = os.environ.get("JAXMAC_SHARED",
                            os.path.join(os.path.dirname(__file__), "..", "..", "shared"))


def trace_dir(domain: str) -> str:
    """``shared/reference/<domain>/traces`` (need not exist; see :func:`trace_files`)."""
    return os.path.join(SHARED_DIR, "reference", domain, "traces")


def trace_files(domain: str, pattern: str) -> list[str]:
    """Sorted trace files of ``domain`` matching ``pattern``; [] when the folder is missing."""
    return sorted(glob.glob(os.path.join(trace_dir(domain), pattern)))


def require_traces(domain: str, files: list[str]) -> None:
    """Fail the calling test, saying where it looked, when ``files`` (from :func:`trace_files`) is empty."""
    assert files, (f"no {domain} traces in {os.path.abspath(trace_dir(domain))}: run the tests from a checkout "
                   f"next to shared/, or set JAXMAC_SHARED to the shared folder")
