"""Orbax checkpoints of a run's whole training state: saved atomically, found, restored from the newest one that
restores (and that metrics.csv has the rows of), falling back to older ones, and the stale ones removed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import shutil
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp

from jaxmac.runs.folders import WriteFailed
from jaxmac.runs.metrics_csv import MetricsFile, read_metrics_file
from jaxmac.runs.programs import Programs

def checkpointer(out_dir: str):
    import orbax.checkpoint as ocp

    return ocp.CheckpointManager(
        os.path.abspath(os.path.join(out_dir, "checkpoints")),
        options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True),
    )


def _to_saveable(state):
    return state.replace(key=jax.random.key_data(state.key))


def _from_saved(state):
    return state.replace(key=jax.random.wrap_key_data(state.key))


def _first_line(err: BaseException, limit: int = 200) -> str:
    """``Type: first line`` of the innermost cause of ``err`` (orbax wraps tensorstore's telling message)."""
    seen = {id(err)}
    while err.__cause__ is not None and id(err.__cause__) not in seen:
        err = err.__cause__
        seen.add(id(err))
    text = (str(err).strip().splitlines() or [""])[0]
    return f"{type(err).__name__}: {text[:limit]}" + ("..." if len(text) > limit else "")


@dataclasses.dataclass
class Start:
    """Where a run continues: its state at checkpoint ``chunk`` (a fresh one at 0), the newer checkpoints that
    could not be used (step, why) and metrics.csv as read."""

    state: Any
    chunk: int
    skipped: list[tuple[int, str]]
    metrics: MetricsFile
    steps: list[int]  # every checkpoint step found


def checkpoint_steps(out_dir: str) -> list[int]:
    """The chunk counts of the checkpoints ``out_dir`` keeps, newest first."""
    folder = os.path.join(out_dir, "checkpoints")
    if not os.path.isdir(folder):
        return []
    return sorted((int(n) for n in os.listdir(folder) if n.isdigit() and os.path.isdir(os.path.join(folder, n))),
                  reverse=True)


def start_point(out_dir: str, programs: Programs, meta: dict, need_rows: bool) -> Start:
    """The newest checkpoint of ``out_dir`` that restores (and, with ``need_rows``, whose rounds metrics.csv holds a
    row of for every seed), falling back to older ones; a fresh state at chunk 0 if none. Reads only."""
    seed_ids = list(range(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    keys = jax.vmap(jax.random.key)(jnp.arange(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    state = programs.init(keys)
    metrics = read_metrics_file(os.path.join(out_dir, "metrics.csv"))
    steps = checkpoint_steps(out_dir)
    skipped: list[tuple[int, str]] = []
    if not steps:
        return Start(state, 0, skipped, metrics, steps)
    import orbax.checkpoint as ocp

    rounds_per_chunk = programs.trainer.rounds_per_chunk
    complete = metrics.complete_rounds(seed_ids)
    # restored onto the devices of a fresh state here (one device), whatever devices the run was saved from: a run
    # trained with its seeds sharded over 2 devices resumes on 1 and back (the caller places it, ``placed``)
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _to_saveable(state))
    with _quiet_orbax() as failed:
        mngr = ocp.CheckpointManager(os.path.abspath(os.path.join(out_dir, "checkpoints")),
                                     options=ocp.CheckpointManagerOptions(create=False, read_only=True))
        try:
            for step in steps:
                if need_rows and step * rounds_per_chunk > complete:
                    skipped.append((step, f"is not matched by metrics.csv, which has rows of every seed for rounds "
                                          f"0..{complete - 1} only (it needs rounds 0..{step * rounds_per_chunk - 1})"))
                    continue
                try:
                    restored = mngr.restore(step, args=ocp.args.StandardRestore(abstract))
                except Exception as err:  # a truncated or missing file: orbax and tensorstore raise many kinds
                    failed.append(step)
                    skipped.append((step, f"cannot be restored ({_first_line(err)})"))
                    continue
                return Start(_from_saved(restored), step, skipped, metrics, steps)
        finally:
            mngr.close()
    return Start(state, 0, skipped, metrics, steps)


@contextlib.contextmanager
def _quiet_orbax():
    """Silence orbax while it opens and restores checkpoints: its read-only notices and, when a damaged checkpoint
    fails to restore, the pages its abandoned asynchronous reads print (tasks never awaited, a closed event loop)
    — the failure itself is reported in one line by the caller. Yields a list the caller appends failed steps to;
    after a failure the abandoned reads are left a moment to end while still silenced."""
    import gc
    import logging
    import warnings

    loggers = [logging.getLogger(name) for name in ("asyncio", "absl")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: None
    failed: list[int] = []
    saved = None
    try:
        sys.stderr.flush()
        saved = os.dup(2)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no file descriptor 2 to silence: leave it
        saved = None
    try:
        yield failed
    finally:
        if failed:
            with warnings.catch_warnings():  # "coroutine ... was never awaited"
                warnings.simplefilter("ignore")
                for _ in range(3):
                    gc.collect()
                    time.sleep(0.1)
        try:
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
        sys.unraisablehook = hook
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


def say_skipped(out_dir: str, start: Start, doing: str) -> None:
    for step, why in start.skipped:
        print(f"jaxmac: {out_dir}: checkpoint {step} {why}", file=sys.stderr)
    if start.skipped:
        where = f"checkpoint {start.chunk}" if start.chunk else "no checkpoint (the start)"
        print(f"jaxmac: {out_dir}: {doing} {where}", file=sys.stderr)


def skipped_text(start: Start) -> str:
    return "".join(f"; checkpoint {step} {why}" for step, why in start.skipped)


def drop_checkpoints_after(out_dir: str, start: Start) -> None:
    """Before training on from checkpoint ``start.chunk``: remove the newer checkpoints it fell back from (damaged,
    or ahead of metrics.csv; training on re-creates them, and orbax would not save a step below its newest) and the
    temporary folders of saves a crash interrupted."""
    folder = os.path.join(out_dir, "checkpoints")
    if not os.path.isdir(folder):
        return
    for name in os.listdir(folder):
        stale = ".orbax-checkpoint-tmp" in name or (name.isdigit() and int(name) > start.chunk)
        if stale:
            shutil.rmtree(os.path.join(folder, name), ignore_errors=True)


def save_checkpoint(mngr, chunk: int, state, out_dir: str, advice: str) -> None:
    import orbax.checkpoint as ocp

    where = os.path.join(out_dir, "checkpoints", str(chunk))
    try:
        mngr.save(chunk, args=ocp.args.StandardSave(_to_saveable(state)))
        mngr.wait_until_finished()
    except OSError as err:
        raise WriteFailed(where, err, advice) from err
    except Exception as err:  # orbax and tensorstore report a full disk in their own exception types
        raise WriteFailed(where, OSError(errno.EIO, _first_line(err)), advice) from err
