"""Suite-wide compilation settings: the suite's time is mostly XLA compiling tiny programs, not running them.

- One compilation per program for the whole session. Every run a test trains builds fresh jitted closures, so
  JAX's in-memory cache (keyed by function) misses when two tests train the same configuration; the persistent
  compilation cache is keyed by the program itself. It points at a folder fresh for each pytest session, shared by
  the session's xdist workers and by the processes its tests start (the CLI and ``--workers`` read it from
  ``JAXMAC_CACHE``), so no program of an earlier session (or of the user's ~/.cache) can leak into this one.
- The suite runs in xdist workers (``addopts`` in pyproject.toml), a test file per worker at a time, so a
  module's fixtures are built once.
- LLVM's backend optimisation level 0 (set before JAX starts its backend; subprocesses inherit it). XLA's own HLO
  passes still run, so every program computes what it computes at the default level; only the machine code is
  less tuned, which costs the tiny runs of the tests far less than the optimisation would (about half the
  compile time of a ToMacVF chunk measured here). The pinned-metrics test passes at both levels.
"""

import os

LLVM_LEVEL_FLAG = "--xla_backend_optimization_level=0"
if LLVM_LEVEL_FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {LLVM_LEVEL_FLAG}".strip()

import pytest  # noqa: E402

from jaxmac.runs import enable_compilation_cache  # noqa: E402  (imports jax: after XLA_FLAGS)


@pytest.fixture(scope="session", autouse=True)
def _one_compilation_per_program(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    # an xdist worker's base is a subfolder of the session's; the cache is shared one level up
    session_root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    cache = session_root / "xla_cache"
    cache.mkdir(exist_ok=True)
    os.environ["JAXMAC_CACHE"] = str(cache)  # for the CLI inside tests and the processes tests start
    enable_compilation_cache(str(cache))
    yield
