"""Suite-wide compilation settings: the suite's time is mostly XLA compiling tiny programs, not running them.

- One compilation per program for the whole session. Every run a test trains builds fresh jitted closures, so
  JAX's in-memory cache (keyed by function) misses when two tests train the same configuration; the persistent
  compilation cache is keyed by the program itself. It points at a folder fresh for each pytest session, so no
  program of an earlier session (or of the user's ~/.cache) can leak into this one.
- LLVM's backend optimisation level 0 (set before JAX starts its backend; subprocesses inherit it). XLA's own HLO
  passes still run, so every program computes what it computes at the default level; only the machine code is
  less tuned, which costs the tiny runs of the tests far less than the optimisation would (about half the
  compile time of a ToMacVF chunk measured here). The pinned-metrics test passes at both levels.
"""

import os

LLVM_LEVEL_FLAG = "--xla_backend_optimization_level=0"
if LLVM_LEVEL_FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {LLVM_LEVEL_FLAG}".strip()

import jax  # noqa: E402  (after XLA_FLAGS)
import pytest  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _one_compilation_per_program(tmp_path_factory):
    jax.config.update("jax_compilation_cache_dir", str(tmp_path_factory.mktemp("xla_cache")))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    yield
