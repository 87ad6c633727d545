"""The thin host loop around the compiled trainer: seeds, progress, metrics, checkpoints, plots.

``train_run(config, seeds, out_dir)`` vmaps the trainer over ``seeds`` seeds and calls its
compiled chunk repeatedly; between chunks it appends the per-round metrics to
``metrics.csv``, saves an orbax checkpoint (atomic: written aside, then renamed) and updates
the progress bar. ``resume_run(out_dir)`` continues a killed run from its newest checkpoint
and ends with the same result as an uninterrupted run. A run folder holds::

    config.json     resolved TrainConfig + seeds + chunking (the resume source of truth)
    metrics.csv     one row per seed and round
    curve.png       learning curve: greedy discounted return, mean ± s.e. over seeds
    summary.json    final greedy evaluation per seed (discounted and undiscounted)
    checkpoints/    orbax checkpoints of the whole training state
    run.lock        while a process trains, resumes or finishes the run: its owner (an OS lock, ``lock_run_folder``)

A run folder has one owner: ``train_run``, ``resume_run`` and ``finish_run`` hold an OS-level lock on it
(``fcntl.flock``, released by the OS when the process ends, however it ends) and a second process is refused,
naming the holder. Its files survive a crash: the metrics rows of the chunks a checkpoint covers are appended and
fsynced just before that checkpoint is saved; a resume cuts metrics.csv back to exactly the rows of the checkpoint
it resumes from (a partial last line included), falls back to an older checkpoint when the newest cannot be restored
(or metrics.csv lacks its rows), and never starts a run with a record over.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import errno
import fnmatch
import functools
import json
import os
import shutil
import socket
import sys
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.seeds import SEED_AXIS
from jaxmac.config import TrainConfig
from jaxmac.scenarios import OPTIMAL_DISC_RETURN

# The first columns of metrics.csv; every other metric the trainer and the algorithm report follows, by name.
METRIC_COLUMNS = ("seed", "round", "episodes", "epsilon", "train_return", "train_disc_return", "train_length",
                  "eval_disc_return", "eval_return", "loss")
# Metrics that must stay finite in every round with a gradient step (and param_norm in every round).
WATCHED = ("loss", "grad_norm", "param_norm")
# The value learners' mean value estimates, each a (mixed or per-agent) estimate of a discounted team return: they
# must stay inside the env's value bounds (``value_bounds``); the divergence guard watches them.
VALUE_METRICS = ("q_tot_mean", "cen_q_mean", "dec_q_mean")
OUT_OF_BOUNDS_COLUMN = "value_out_of_bounds"



# --- one owner per run folder ------------------------------------------------------------------------------------

LOCK_FILE = "run.lock"
# The files that make a folder a run's (``train_run`` refuses a folder holding any of them).
RUN_FILES = ("config.json", "metrics.csv", "summary.json", "progress.json", "diverged.json", "diverged.previous.json",
             "curve.png", "checkpoints")
RUN_FILE_PATTERNS = ("summary.stopped-at-*.json",)


class RunFolderBusy(ValueError):
    """The run folder is owned by another live process (its lock is held)."""


class WriteFailed(OSError):
    """A file of a run could not be written (full disk, permissions): the message names it and what to do."""

    def __init__(self, path: str, err: BaseException, advice: str = "", verb: str = "write"):
        super().__init__(getattr(err, "errno", None) or errno.EIO, getattr(err, "strerror", None) or str(err))
        self.filename = path
        self.message = f"cannot {verb} {path}: {self.strerror}" + (f"; {advice}" if advice else "")

    def __str__(self) -> str:
        return self.message


# folder (real path) -> [open lock file descriptor, how many times this process took it]
_HELD: dict[str, list] = {}


@dataclasses.dataclass
class FolderLock:
    """This process's hold on a run folder (``lock_run_folder``); ``release()`` or a ``with`` block ends it."""

    folder: str
    _key: str | None

    def release(self) -> None:
        key, self._key = self._key, None
        if key is None or key not in _HELD:
            return
        held = _HELD[key]
        held[1] -= 1
        if held[1] > 0:
            return
        del _HELD[key]
        fd, path = held[0], held[2]
        try:  # remove the lock file while still holding it (a process that opened it meanwhile sees it is gone)
            if os.stat(path).st_ino == os.fstat(fd).st_ino:
                os.unlink(path)
        except OSError:
            pass
        os.close(fd)  # releases the flock

    def __enter__(self) -> "FolderLock":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def __bool__(self) -> bool:
        return self._key is not None


def lock_holder(out_dir: str) -> dict | None:
    """What the lock file of ``out_dir`` says about its (last) holder: pid, host, command, since; None if unreadable."""
    try:
        with open(os.path.join(out_dir, LOCK_FILE)) as f:
            holder = json.load(f)
        return holder if isinstance(holder, dict) else None
    except (OSError, ValueError):
        return None


def _describe_holder(holder: dict | None) -> str:
    if not holder:
        return "a process that has not written its name yet"
    return (f"{holder.get('command', 'a jaxmac process')} (pid {holder.get('pid', '?')} on host "
            f"{holder.get('host', '?')}, since {holder.get('since', '?')})")


def try_lock_run_folder(out_dir: str, command: str = "train") -> FolderLock | None:
    """Take ``out_dir`` (created if needed) for this process, or None if another live process holds it.

    The lock is an ``fcntl.flock`` on ``out_dir/run.lock``: the OS releases it when its process ends, however it ends,
    so the lock of a killed process is taken over without a human, and a stale file (of a dead process, or naming a
    reused PID) never blocks. The file holds the holder's pid, host, command and start time, for messages. A process
    may take a folder it already holds again (a sweep's cell, then the run inside it)."""
    import fcntl

    _make_folder(out_dir)
    key = os.path.realpath(out_dir)
    if key in _HELD:
        _HELD[key][1] += 1
        return FolderLock(out_dir, key)
    path = os.path.join(out_dir, LOCK_FILE)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise WriteFailed(path, err, "a run folder must be writable to train in it") from err
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        try:  # the holder before us may have removed the file between our open and our flock: lock the new one
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": f"jaxmac {command}",
              "since": time.strftime("%Y-%m-%d %H:%M:%S")}
    try:  # for other processes' messages only: the lock holds without it (e.g. on a full disk)
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(holder).encode(), 0)
    except OSError:
        pass
    _HELD[key] = [fd, 1, path]
    return FolderLock(out_dir, key)


def lock_run_folder(out_dir: str, command: str = "train") -> FolderLock:
    """``try_lock_run_folder``, raising ``RunFolderBusy`` (naming the holder) if another process holds ``out_dir``."""
    lock = try_lock_run_folder(out_dir, command)
    if lock is None:
        raise RunFolderBusy(f"{out_dir} is in use by {_describe_holder(lock_holder(out_dir))}: a run folder has one "
                            "owner; wait for that process to end (or stop it), then try again")
    return lock


def _make_folder(out_dir: str) -> None:
    """Create the run folder ``out_dir``; an unusable path is a one-line error naming it."""
    if os.path.isdir(out_dir):
        return
    if os.path.exists(out_dir):
        raise ValueError(f"{out_dir} is an existing file, not a run folder: choose another --out")
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as err:
        raise WriteFailed(out_dir, err, "choose a writable --out", verb="create") from err


def run_files(out_dir: str) -> list[str]:
    """The files of a run (``RUN_FILES``, ``RUN_FILE_PATTERNS``) that ``out_dir`` holds."""
    try:
        names = sorted(os.listdir(out_dir))
    except OSError:
        return []
    return [n for n in names if n in RUN_FILES or any(fnmatch.fnmatch(n, p) for p in RUN_FILE_PATTERNS)]


def refuse_run_files(out_dir: str) -> None:
    """A new run may only start in a folder that holds no file of a run (it would mix with them)."""
    found = run_files(out_dir)
    if "config.json" in found:
        raise ValueError(f"{out_dir} already holds a run; use resume (jaxmac train --resume {out_dir}) "
                         "or choose another --out")
    if found:
        raise ValueError(f"{out_dir} holds files of a run ({', '.join(found)}) but no config.json, so it is no run "
                         "jaxmac can resume: a new run would mix with them. Move them away or choose another --out")


def read_meta(out_dir: str, trainable: bool = False) -> dict[str, Any]:
    """The run's ``config.json`` (settings, seeds, chunking), checked: a missing, unreadable or broken file is a
    one-line ``ValueError`` naming it. ``trainable``: it must also say how the run is chunked (to load or train it)."""
    path = os.path.join(out_dir, "config.json")
    if not os.path.exists(path):
        raise ValueError(f"{out_dir} holds no run (no config.json)")
    fix = "restore it from a copy, or move the folder away and start a new run"
    try:
        with open(path) as f:
            meta = json.load(f)
    except OSError as err:
        raise ValueError(f"cannot read {path}: {err.strerror}") from err
    except ValueError as err:
        raise ValueError(f"{path} is broken (not valid JSON: {err}); {fix}") from err
    if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
        raise ValueError(f"{path} is not a jaxmac run's config (no 'config' settings); {fix}")
    needed = ("seeds", "seed_offset") + (("rounds_per_chunk",) if trainable and "workers" not in meta else ())
    missing = [k for k in needed if not isinstance(meta.get(k), int) or isinstance(meta.get(k), bool)]
    if missing:
        raise ValueError(f"{path} is broken: it lacks {', '.join(missing)} (an integer each); {fix}")
    try:
        TrainConfig.from_dict(meta["config"])
    except (ValueError, TypeError, KeyError) as err:
        raise ValueError(f"{path} holds invalid settings ({err}); {fix}") from err
    return meta


def _fsync_dir(path: str) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _append_text(path: str, text: str, advice: str = "") -> None:
    """Append ``text`` to ``path`` and fsync it (on disk before the checkpoint that covers it is saved). A failed
    append (a full disk) is cut off again, so that the file never holds rows no checkpoint covers."""
    size = _size_of(path)
    try:
        with open(path, "a", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
    except OSError as err:
        _cut_back(path, size)
        raise WriteFailed(path, err, advice) from err


def _size_of(path: str) -> int | None:
    return os.path.getsize(path) if os.path.exists(path) else None


def _cut_back(path: str, size: int | None) -> None:
    """Return ``path`` to the ``size`` it had (None: it did not exist), best effort: rows a failed checkpoint would
    have covered go (a partial line left behind is dropped by the next resume)."""
    try:
        if size is None:
            os.remove(path)
        else:
            os.truncate(path, size)
    except OSError:
        pass


# --- metrics.csv as a checkpoint covers it --------------------------------------------------------------------------

@dataclasses.dataclass
class _MetricsFile:
    """metrics.csv read leniently: its header line and its complete, well-formed rows (raw lines, in file order);
    a partial last line (a crash or a full disk mid-write) and malformed lines are left out."""

    header: bytes | None  # the header line with its line end, None if absent or broken
    rows: list[tuple[int, int, bytes]]  # (seed, round, raw line with its end)
    dropped: int  # lines left out

    def complete_rounds(self, seed_ids: list[int]) -> int:
        """The number of leading rounds every seed has a row of."""
        have = {s: set() for s in seed_ids}
        for s, r, _ in self.rows:
            if s in have:
                have[s].add(r)
        k = 0
        while have and all(k in rounds for rounds in have.values()):
            k += 1
        return k

    def duplicate(self, below: int) -> tuple[int, int] | None:
        seen = set()
        for s, r, _ in self.rows:
            if r < below:
                if (s, r) in seen:
                    return s, r
                seen.add((s, r))
        return None


def _read_metrics_file(path: str) -> _MetricsFile:
    if not os.path.exists(path):
        return _MetricsFile(None, [], 0)
    with open(path, "rb") as f:
        data = f.read()
    lines = data.split(b"\n")
    lines = [line + b"\n" for line in lines[:-1]] + ([lines[-1]] if lines[-1] else [])
    if not lines or not lines[0].endswith(b"\n"):
        return _MetricsFile(None, [], len(lines))
    header = next(csv.reader([lines[0].decode("utf-8", "replace")]), [])
    if header[:2] != ["seed", "round"]:
        return _MetricsFile(None, [], len(lines))
    rows, dropped = [], 0
    for line in lines[1:]:
        fields = None
        if line.endswith(b"\n"):
            try:
                fields = next(csv.reader([line.decode("utf-8")]), None)
            except (UnicodeDecodeError, csv.Error):
                fields = None
        try:
            if fields is None or len(fields) != len(header):
                raise ValueError
            rows.append((int(fields[0]), int(fields[1]), line))
        except ValueError:
            dropped += 1
    return _MetricsFile(lines[0], rows, dropped)


def _cut_metrics(path: str, metrics: _MetricsFile, rounds_done: int) -> None:
    """Rewrite metrics.csv (atomically) as exactly its rows of rounds ``< rounds_done`` (none: no file)."""
    if metrics.header is None:  # nothing usable (no rows can be kept): the next rows start a new file
        if os.path.exists(path):
            os.remove(path)
        return
    text = metrics.header + b"".join(line for _, r, line in metrics.rows if r < rounds_done)
    with open(path, "rb") as f:
        if f.read() == text:
            return
    tmp = path + ".tmp"
    try:
        with open(tmp, "wb") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        raise WriteFailed(path, err, "free space, then resume again") from err
    _fsync_dir(os.path.dirname(os.path.abspath(path)))


def enable_compilation_cache(path: str | None = None) -> None:
    """JAX's persistent compilation cache: a re-run skips most compilation."""
    path = path or os.environ.get("JAXMAC_CACHE", os.path.expanduser("~/.cache/jaxmac/xla"))
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def use_host_devices(count: int) -> None:
    """Let a CPU-only JAX split into ``count`` host devices (one per core) so that seeds can be sharded over them.
    Must run before JAX starts its backend (the first computation); on an accelerator it changes nothing."""
    if count > 1:
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={count}".strip()


def seed_sharding(seeds: int, devices: int):
    """The ``NamedSharding`` that splits a state's leading seed axis over the first ``devices`` devices (a mesh
    axis named ``SEED_AXIS``), or None for one device. One jitted program then runs every device's seeds (the same
    command on one GPU, several GPUs, or ``jax.distributed`` hosts)."""
    if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
        raise ValueError(f"devices={devices!r} must be a positive integer")
    if devices == 1:
        return None
    available = jax.devices()
    if devices > len(available):
        raise ValueError(f"devices={devices}: JAX sees {len(available)} device(s) ({available[0].platform}); on a CPU "
                         f"use `jaxmac train --devices N` (it splits the host into N devices before JAX starts)")
    if seeds % devices:
        raise ValueError(f"seeds={seeds} cannot be split evenly over devices={devices}: use a number of seeds that "
                         f"is a multiple of the devices, or fewer devices")
    mesh = jax.sharding.Mesh(np.array(available[:devices]), (SEED_AXIS,))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(SEED_AXIS))


@dataclasses.dataclass(frozen=True)
class _Programs:
    """A trainer and the jitted programs the host loop runs, seeds vmapped (state leaves ``[seeds, ...]``)."""
    trainer: Any  # jaxmac.trainer.Trainer
    init: Callable  # keys [seeds] -> TrainState
    chunk: Callable  # TrainState -> (TrainState, metrics [seeds, rounds]); donates the state it is given
    # (params, keys [seeds]) -> (discounted, undiscounted) mean final-evaluation returns [seeds]
    greedy_returns: Callable  # the greedy policy: the value learners' own, the actor-critics' greedy_act
    sampled_returns: Callable  # the policy ``evaluate`` runs (the actor-critics' sampled one)


@functools.lru_cache(maxsize=4)
def _programs(config: TrainConfig, rounds_per_chunk: int | None) -> _Programs:
    """Built once per setting in a process: a resumed, extended or finished run, or a test that trains the same
    configuration several times, reuses the traced and compiled programs instead of tracing them again."""
    from jaxmac.algos import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.trainer import make_train

    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env), rounds_per_chunk)

    def final_returns(evaluate):
        run = jax.jit(jax.vmap(lambda p, k: evaluate(p, k, config.eval_episodes), axis_name=SEED_AXIS))

        def returns(params, keys):
            stats = run(params, keys)
            return np.asarray(stats["disc_return"]).mean(-1), np.asarray(stats["return"]).mean(-1)

        return returns

    sampled = final_returns(trainer.evaluate)
    return _Programs(trainer, jax.jit(jax.vmap(trainer.init)), jax.jit(trainer.seeds_chunk, donate_argnums=0),
                     final_returns(trainer.evaluate_greedy) if trainer.evaluate_greedy else sampled, sampled)


def _checkpointer(out_dir: str):
    import orbax.checkpoint as ocp

    return ocp.CheckpointManager(
        os.path.abspath(os.path.join(out_dir, "checkpoints")),
        options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True),
    )


def _to_saveable(state):
    return state.replace(key=jax.random.key_data(state.key))


def _from_saved(state):
    return state.replace(key=jax.random.wrap_key_data(state.key))


def metric_columns(metrics: dict[str, Any]) -> list[str]:
    """``METRIC_COLUMNS`` then every other reported metric in name order."""
    return list(METRIC_COLUMNS) + sorted(k for k in metrics if k not in METRIC_COLUMNS)


def _metrics_columns_of(path: str, metrics: dict[str, np.ndarray]) -> tuple[list[str], bool]:
    """The columns rows appended to ``path`` have (its header's, or the metrics' own for a new file) and whether
    the file is new (the rows must be headed)."""
    if not os.path.exists(path):
        return metric_columns(metrics), True
    with open(path, newline="") as f:
        return next(csv.reader(f)), False


def _metrics_text(columns: list[str], metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int,
                  header: bool = False) -> str:
    """The CSV text of one row per seed and round for metrics with leaves [seeds, rounds], in ``columns``."""
    import io

    seeds, rounds = np.shape(metrics["episodes"])
    out = io.StringIO()
    w = csv.writer(out)
    if header:
        w.writerow(columns)
    for s in range(seeds):
        for r in range(rounds):
            row = [seed_ids[s], first_round + r, int(metrics["episodes"][s, r])]
            for k in columns[3:]:
                value = metrics[k][s, r] if k in metrics else float("nan")
                row.append(int(value) if np.issubdtype(np.asarray(value).dtype, np.integer) else float(value))
            w.writerow(row)
    return out.getvalue()


def _append_chunks(path: str, chunks: list[tuple[dict[str, np.ndarray], int]], seed_ids: list[int],
                   advice: str = "") -> None:
    """Append the rows of several chunks' metrics ((metrics, first round) each) in one write, then fsync."""
    if not chunks:
        return
    columns, new = _metrics_columns_of(path, chunks[0][0])
    text = "".join(_metrics_text(columns, m, seed_ids, first, header=new and k == 0)
                   for k, (m, first) in enumerate(chunks))
    _append_text(path, text, advice)


def check_finite(metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int) -> str | None:
    """A message naming the first seed, round and metric that went non-finite (None if all are finite).

    Loss and gradient norm count only in rounds where gradient steps ran (they are NaN by design otherwise);
    the parameter norm counts in every round."""
    stepped = np.asarray(metrics["round_updates"]) > 0
    for r in range(stepped.shape[1]):
        for s in range(stepped.shape[0]):
            for k in WATCHED:
                if k not in metrics:
                    continue
                value = float(metrics[k][s, r])
                if (k == "param_norm" or stepped[s, r]) and not np.isfinite(value):
                    return f"seed {seed_ids[s]}, round {first_round + r}: {k} = {value}"
    return None


def value_bounds_of(config: TrainConfig, env) -> tuple[float, float]:
    """The interval the guard holds value estimates to: the env's bounds on a discounted return from any state
    (``envs_jax.core.value_bounds``, with the learning discount) widened by ``divergence_margin`` of each bound's
    own size."""
    from envs_jax.core import value_bounds

    low, high = value_bounds(env.reward_bounds(), env.spec.discount, env.spec.horizon)
    margin = config.divergence_margin
    return low - margin * abs(low), high + margin * abs(high)


def flag_out_of_bounds(metrics: dict[str, np.ndarray], bounds: tuple[float, float]) -> np.ndarray | None:
    """f32[seeds, rounds]: 1 where a watched value metric (``VALUE_METRICS``) left ``bounds`` in that round, else 0
    (None if the learner reports none of them). NaN values (rounds without a gradient step) are not flagged."""
    names = [k for k in VALUE_METRICS if k in metrics]
    if not names:
        return None
    low, high = bounds
    values = np.stack([np.asarray(metrics[k], np.float64) for k in names])
    with np.errstate(invalid="ignore"):
        out = ((values < low) | (values > high)).any(0)
    return out.astype(np.float32)


def out_of_bounds_message(metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int,
                          bounds: tuple[float, float]) -> str | None:
    """The first seed and round (in round order) whose watched value metric left ``bounds``, or None."""
    flags = metrics.get(OUT_OF_BOUNDS_COLUMN)
    if flags is None or not np.any(flags):
        return None
    seed, rnd = min(zip(*np.nonzero(flags)), key=lambda sr: (sr[1], sr[0]))
    name, value = next((k, float(metrics[k][seed, rnd])) for k in VALUE_METRICS
                       if k in metrics and not bounds[0] <= float(metrics[k][seed, rnd]) <= bounds[1])
    return (f"seed {seed_ids[seed]}, round {first_round + rnd} (episode {int(metrics['episodes'][seed, rnd])}): "
            f"{name} = {value:.6g} is outside the value bounds [{bounds[0]:.6g}, {bounds[1]:.6g}] that every return "
            f"of this env lies in (widened by divergence_margin)")


def write_json_atomic(path: str, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` through a temporary file, an fsync and a rename (never half-written)."""
    tmp = path + ".tmp"
    try:
        with open(tmp, "w") as f:
            json.dump(obj, f, indent=2)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise WriteFailed(path, err, "free space (or fix the folder's permissions) and run the command again") \
            from err


# --- sizes checked before anything compiles -------------------------------------------------------------------------

def check_budget(config: TrainConfig) -> None:
    """Every round collects ``num_envs`` episodes per seed: a budget smaller than one round would be overrun."""
    if config.num_envs > config.episodes:
        raise ValueError(f"episodes={config.episodes} is less than one round of num_envs={config.num_envs} episodes: "
                         f"the run would train {config.num_envs} episodes per seed, "
                         f"{config.num_envs / config.episodes:.4g}x its budget. Lower num_envs to at most "
                         f"{config.episodes}, or raise episodes")


def _nbytes(tree) -> float:
    def itemsize(dtype) -> int:
        try:
            return np.dtype(dtype).itemsize
        except TypeError:  # a PRNG key's extended dtype
            return 8

    return sum(float(np.prod(leaf.shape, dtype=np.float64)) * itemsize(leaf.dtype)
               for leaf in jax.tree_util.tree_leaves(tree))


def _abstract_state(programs: _Programs, seeds: int):
    """The shapes and dtypes of a fresh training state of ``seeds`` seeds (traced, nothing allocated or compiled)."""
    keys = jax.eval_shape(lambda: jax.vmap(jax.random.key)(jnp.arange(seeds)))
    return jax.eval_shape(programs.init, keys)


def memory_estimate(programs: _Programs, seeds: int) -> tuple[float, str]:
    """A rough estimate of the memory a run needs (bytes) and what it is made of: the training state (the replay ring
    of ``buffer_episodes`` episodes per seed above all), a batch of ``batch_size`` episodes gathered for a gradient
    step (counted four times: the gather, its encodings, activations and gradients) and a round's ``num_envs``
    episodes (twice: rollout and write), all per seed."""
    config = programs.trainer.config
    state = _abstract_state(programs, seeds)
    state_bytes = _nbytes(state)
    ring_bytes = _nbytes(state.ring)
    per_episode = ring_bytes / max(1, seeds * config.buffer_episodes)
    batch = 4.0 * seeds * config.batch_size * per_episode
    envs = 2.0 * seeds * (config.num_envs + config.eval_episodes) * per_episode
    gib = 2.0 ** 30
    detail = (f"training state {state_bytes / gib:.3g} GiB (replay ring of buffer_episodes={config.buffer_episodes} "
              f"x {seeds} seed(s): {ring_bytes / gib:.3g} GiB), batches of batch_size={config.batch_size}: "
              f"{batch / gib:.3g} GiB, rounds of num_envs={config.num_envs}: {envs / gib:.3g} GiB")
    return state_bytes + batch + envs, detail


def machine_memory(devices: int = 1) -> tuple[float, str]:
    """The memory a run can use (bytes) and where it is: the accelerators' (``devices`` of them) or this host's RAM."""
    device = jax.devices()[0]
    if device.platform != "cpu":
        try:
            limit = (device.memory_stats() or {}).get("bytes_limit")
        except Exception:  # a backend without memory statistics
            limit = None
        if limit:
            return float(limit) * devices, f"{devices} {device.platform} device(s) of {limit / 2 ** 30:.3g} GiB"
    try:
        ram = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return float("inf"), "unknown"
    return ram, f"this machine's {ram / 2 ** 30:.3g} GiB of RAM"


def check_memory(programs: _Programs, seeds: int, devices: int = 1) -> None:
    """Refuse, before compiling, a run whose sizes (ring, batch, envs) need more memory than the machine has."""
    need, detail = memory_estimate(programs, seeds)
    have, where = machine_memory(devices)
    if need > have:
        raise ValueError(f"this run needs about {need / 2 ** 30:.3g} GiB ({detail}) but has {where}: lower "
                         "buffer_episodes, batch_size, num_envs or the number of seeds")


def check_new_run(config: TrainConfig, seeds: int, devices: int = 1, rounds_per_chunk: int | None = None) -> None:
    """What ``train_run`` checks of a new run before it writes or compiles anything: the budget and the memory."""
    check_budget(config)
    check_memory(_programs(config, rounds_per_chunk), seeds, devices)


# --- training, resuming, finishing ----------------------------------------------------------------------------------

def train_run(
    config: TrainConfig,
    seeds: int,
    out_dir: str,
    seed_offset: int = 0,
    rounds_per_chunk: int | None = None,
    checkpoint_seconds: float = 120.0,
    progress: bool = True,
    stop_after_chunks: int | None = None,
    devices: int = 1,
) -> dict[str, Any] | None:
    """Train ``seeds`` seeds (``seed_offset … seed_offset+seeds-1``) into ``out_dir``, their states sharded over
    ``devices`` devices (``seed_sharding``).

    ``out_dir`` is locked for the call (``lock_run_folder``) and must hold no file of a run. ``stop_after_chunks``
    stops early (as if killed) after that many chunks of this call, checkpointing first — used by tests of resume.
    Returns the summary (None if stopped).
    """
    if seeds < 1:
        raise ValueError(f"seeds={seeds!r} must be >= 1")
    sharding = seed_sharding(seeds, devices)
    check_budget(config)
    created = not os.path.exists(out_dir)
    with lock_run_folder(out_dir, "train"):
        try:
            refuse_run_files(out_dir)
            programs = _programs(config, rounds_per_chunk)
            check_memory(programs, seeds, devices)
            meta = {"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset,
                    "rounds_per_chunk": programs.trainer.rounds_per_chunk, "jax": jax.__version__}
            write_json_atomic(os.path.join(out_dir, "config.json"), meta)
        except BaseException:
            if created:
                _remove_if_empty(out_dir)
            raise
        try:
            keys = jax.vmap(jax.random.key)(jnp.arange(seed_offset, seed_offset + seeds))
            state = programs.init(keys)
            return _loop(programs, state, 0, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, 0.0,
                         sharding)
        except BaseException as err:
            if not isinstance(err, OSError):  # a full disk: the folder stays, for the resume its message suggests
                _forget_unstarted(out_dir, created)
            raise


def _remove_if_empty(out_dir: str) -> None:
    """Remove ``out_dir`` if it holds nothing but (our) lock file."""
    try:
        if not set(os.listdir(out_dir)) - {LOCK_FILE}:
            shutil.rmtree(out_dir, ignore_errors=True)
    except OSError:
        pass


def _forget_unstarted(out_dir: str, created: bool) -> None:
    """After a new run this process started failed before it recorded anything (no checkpoint, no metrics row: e.g.
    out of memory while compiling), remove the config.json it wrote (and the folder if it created it), so that the
    same --out can be used again."""
    found = run_files(out_dir)
    checkpoints = os.path.join(out_dir, "checkpoints")
    if any(f not in ("config.json", "checkpoints") for f in found):
        return
    try:
        if os.path.isdir(checkpoints) and os.listdir(checkpoints):
            return
        if os.path.isdir(checkpoints):
            os.rmdir(checkpoints)
        if "config.json" in found:
            os.remove(os.path.join(out_dir, "config.json"))
    except OSError:
        return
    if created:
        _remove_if_empty(out_dir)


def _first_line(err: BaseException, limit: int = 200) -> str:
    """``Type: first line`` of the innermost cause of ``err`` (orbax wraps tensorstore's telling message)."""
    seen = {id(err)}
    while err.__cause__ is not None and id(err.__cause__) not in seen:
        err = err.__cause__
        seen.add(id(err))
    text = (str(err).strip().splitlines() or [""])[0]
    return f"{type(err).__name__}: {text[:limit]}" + ("..." if len(text) > limit else "")


@dataclasses.dataclass
class _Start:
    """Where a run continues: its state at checkpoint ``chunk`` (a fresh one at 0), the newer checkpoints that
    could not be used (step, why) and metrics.csv as read."""

    state: Any
    chunk: int
    skipped: list[tuple[int, str]]
    metrics: _MetricsFile
    steps: list[int]  # every checkpoint step found


def _checkpoint_steps(out_dir: str) -> list[int]:
    folder = os.path.join(out_dir, "checkpoints")
    if not os.path.isdir(folder):
        return []
    return sorted((int(n) for n in os.listdir(folder) if n.isdigit() and os.path.isdir(os.path.join(folder, n))),
                  reverse=True)


def _start_point(out_dir: str, programs: _Programs, meta: dict, need_rows: bool) -> _Start:
    """The newest checkpoint of ``out_dir`` that restores (and, with ``need_rows``, whose rounds metrics.csv holds a
    row of for every seed), falling back to older ones; a fresh state at chunk 0 if none. Reads only."""
    seed_ids = list(range(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    keys = jax.vmap(jax.random.key)(jnp.arange(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    state = programs.init(keys)
    metrics = _read_metrics_file(os.path.join(out_dir, "metrics.csv"))
    steps = _checkpoint_steps(out_dir)
    skipped: list[tuple[int, str]] = []
    if not steps:
        return _Start(state, 0, skipped, metrics, steps)
    import orbax.checkpoint as ocp

    rounds_per_chunk = programs.trainer.rounds_per_chunk
    complete = metrics.complete_rounds(seed_ids)
    abstract = jax.eval_shape(_to_saveable, state)
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
                return _Start(_from_saved(restored), step, skipped, metrics, steps)
        finally:
            mngr.close()
    return _Start(state, 0, skipped, metrics, steps)


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


def _say_skipped(out_dir: str, start: _Start, doing: str) -> None:
    for step, why in start.skipped:
        print(f"jaxmac: {out_dir}: checkpoint {step} {why}", file=sys.stderr)
    if start.skipped:
        where = f"checkpoint {start.chunk}" if start.chunk else "no checkpoint (the start)"
        print(f"jaxmac: {out_dir}: {doing} {where}", file=sys.stderr)


def load_run(out_dir: str):
    """``(trainer, state, chunks_done, meta)`` of the run in ``out_dir`` at its newest checkpoint that restores
    (an older one, saying so on stderr, if the newest is damaged; a fresh state and 0 chunks if it has none).
    ``state`` leaves are ``[seeds, ...]``. Reads only."""
    programs, state, step, meta = _load(out_dir)
    return programs.trainer, state, step, meta


def _load(out_dir: str):
    """``load_run`` with the run's ``_Programs`` in place of its trainer."""
    meta = read_meta(out_dir, trainable=True)
    programs = _programs(TrainConfig.from_dict(meta["config"]), meta["rounds_per_chunk"])
    start = _start_point(out_dir, programs, meta, need_rows=False)
    _say_skipped(out_dir, start, "using")
    return programs, start.state, start.chunk, meta


def _extended(out_dir: str, meta: dict, episodes: int) -> dict:
    """``meta`` with a budget raised to ``episodes`` per seed (validated; nothing written)."""
    current = meta["config"]["episodes"]
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < current:
        raise ValueError(f"episodes={episodes!r}: a run can only be extended; {out_dir} already has a budget of "
                         f"{current} episodes per seed (give an integer >= {current})")
    return dict(meta, config=TrainConfig.from_dict(meta["config"]).override(episodes=episodes).to_dict())


def extend_budget(out_dir: str, episodes: int) -> None:
    """Raise the training budget of the run in ``out_dir`` to ``episodes`` per seed (its config.json,
    rewritten atomically). Nothing else of the config changes — the ε schedule counts episodes from
    the start — so resuming afterwards ends exactly where a run started with that budget would."""
    with lock_run_folder(out_dir, "train --episodes") if os.path.isdir(out_dir) else _no_lock():
        meta = read_meta(out_dir)
        write_json_atomic(os.path.join(out_dir, "config.json"), _extended(out_dir, meta, episodes))


class _no_lock:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None


def finish_run(out_dir: str) -> dict[str, Any]:
    """End the run in ``out_dir`` where its newest checkpoint stands, without training the rest of its budget (for a
    curve that has been flat for long): the final greedy evaluation, summary.json (with ``stopped_at`` =
    the episodes trained and ``budget``) and the plot, exactly as a run with that budget would end — the ε schedule
    counts episodes from the start, so it does not depend on the budget."""
    with lock_run_folder(out_dir, "train --finish") if os.path.isdir(out_dir) else _no_lock():
        if is_finished(out_dir):
            raise ValueError(f"{out_dir} has already finished (summary.json exists)")
        meta = read_meta(out_dir, trainable=True)
        programs = _programs(TrainConfig.from_dict(meta["config"]), meta["rounds_per_chunk"])
        start = _start_point(out_dir, programs, meta, need_rows=True)
        if start.chunk == 0:
            raise ValueError(f"{out_dir} has no usable checkpoint yet{_skipped_text(start)}: nothing to finish "
                             "(resume it instead)")
        _say_skipped(out_dir, start, "finishing at")
        _drop_checkpoints_after(out_dir, start)
        _cut_metrics(os.path.join(out_dir, "metrics.csv"), start.metrics,
                     start.chunk * programs.trainer.rounds_per_chunk)
        wall = _wall_seconds(out_dir)
        budget = programs.trainer.config.episodes
        summary = _finish(programs, start.state, out_dir, meta, wall)
        summary.update(stopped_at=summary["episodes"], budget=budget)
        write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
        return summary


def _wall_seconds(out_dir: str) -> float:
    try:
        with open(os.path.join(out_dir, "progress.json")) as f:
            return float(json.load(f)["wall_seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


def _skipped_text(start: _Start) -> str:
    return "".join(f"; checkpoint {step} {why}" for step, why in start.skipped)


def _drop_checkpoints_after(out_dir: str, start: _Start) -> None:
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


def _set_aside_early_summary(out_dir: str, training_on: bool) -> None:
    """A finished run trained further (ended early by ``finish_run``, or extended) no longer ends where its summary
    says: keep that summary as ``summary.stopped-at-N.json`` (N its episodes per seed), so that the run counts as
    unfinished until it ends again and ``finish_run`` can end it again."""
    path = os.path.join(out_dir, "summary.json")
    if not (training_on and os.path.exists(path)):
        return
    with open(path) as f:
        episodes = json.load(f)["episodes"]
    os.replace(path, os.path.join(out_dir, f"summary.stopped-at-{episodes}.json"))


def is_finished(out_dir: str) -> bool:
    return os.path.exists(os.path.join(out_dir, "summary.json"))


def _changed_settings(out_dir: str, meta: dict, assignments: list[str]) -> dict:
    """``meta`` with ``assignments`` (``--set`` strings) applied to a diverged run, validated against its checkpoint
    (the training state must keep its shapes); nothing written."""
    if not os.path.exists(os.path.join(out_dir, "diverged.json")):
        raise ValueError(f"{out_dir} did not diverge: --resume continues a run as it was configured "
                         "(--set is only for a diverged run)")
    old = TrainConfig.from_dict(meta["config"])
    new = old.override_strings(assignments)
    before = _abstract_state(_programs(old, meta["rounds_per_chunk"]), meta["seeds"])
    after = _abstract_state(_programs(new, meta["rounds_per_chunk"]), meta["seeds"])
    differ = _shape_changes(before, after)
    if differ:
        raise ValueError(f"--set {' '.join(assignments)} changes the shapes of the training state ({differ}): the "
                         f"checkpoint of {out_dir} would not fit. A diverged run continues only with settings that keep "
                         "them (learning rates, schedules, loss weights); nothing was changed")
    changed = dict(meta, config=new.to_dict())
    changed["changed_after_divergence"] = list(meta.get("changed_after_divergence", [])) + list(assignments)
    return changed


def _shape_changes(before, after, limit: int = 3) -> str:
    flat_before, tree_before = jax.tree_util.tree_flatten_with_path(before)
    flat_after, tree_after = jax.tree_util.tree_flatten_with_path(after)
    if tree_before != tree_after:
        return "its structure differs"
    out = [f"{jax.tree_util.keystr(path)}: {tuple(a.shape)} {a.dtype} -> {tuple(b.shape)} {b.dtype}"
           for (path, a), (_, b) in zip(flat_before, flat_after) if (a.shape, a.dtype) != (b.shape, b.dtype)]
    return "; ".join(out[:limit]) + (f"; and {len(out) - limit} more" if len(out) > limit else "")


def change_diverged_settings(out_dir: str, assignments: list[str]) -> None:
    """Change settings (``key=value`` strings, as ``--set``) of a run that stopped because it diverged, so
    that it continues from its last good checkpoint with them. The parameter shapes must stay the same
    (learning rates, schedules, loss weights: yes; network sizes: no — the checkpoint would not fit); a refused
    change writes nothing."""
    with lock_run_folder(out_dir, "train --resume --set") if os.path.isdir(out_dir) else _no_lock():
        meta = _changed_settings(out_dir, read_meta(out_dir, trainable=True), assignments)
        write_json_atomic(os.path.join(out_dir, "config.json"), meta)
        os.replace(os.path.join(out_dir, "diverged.json"), os.path.join(out_dir, "diverged.previous.json"))


def _record(out_dir: str, start: _Start) -> list[str]:
    """What of a run's record a start over would erase: metrics rows, summaries, a checkpoint once written."""
    found = []
    rows = len(start.metrics.rows)
    diverged_before_any_checkpoint = (os.path.exists(os.path.join(out_dir, "diverged.json"))
                                      and not os.path.exists(os.path.join(out_dir, "progress.json")))
    if rows and not diverged_before_any_checkpoint:
        found.append(f"{rows} rows of metrics.csv")
    found += [n for n in run_files(out_dir) if n.startswith("summary")]
    if os.path.exists(os.path.join(out_dir, "progress.json")) and not start.steps:
        found.append("progress.json (a checkpoint was saved)")
    return found


def resume_run(out_dir: str, checkpoint_seconds: float = 120.0, progress: bool = True,
               stop_after_chunks: int | None = None, episodes: int | None = None,
               assignments: list[str] | None = None, devices: int = 1) -> dict[str, Any] | None:
    """Continue the run in ``out_dir`` from its newest usable checkpoint, on ``devices`` devices (any number that
    divides its seeds: where the seeds run does not change the result).

    ``episodes`` raises its budget first (``extend_budget``), so a finished run can be trained further;
    ``assignments`` change the settings of a diverged run (``change_diverged_settings``). Everything is checked
    before anything is written: the folder's lock, the settings (against the checkpoint's shapes), the checkpoint.
    A damaged newest checkpoint (or one whose rows metrics.csv lacks) falls back to an older one, saying so on
    stderr; a run without a checkpoint starts over only if it has no record to lose (no metrics rows, no summary).
    """
    with lock_run_folder(out_dir, "train --resume") if os.path.isdir(out_dir) else _no_lock():
        meta = read_meta(out_dir, trainable=True)
        new_meta = meta
        if assignments:
            new_meta = _changed_settings(out_dir, new_meta, assignments)
        if episodes is not None:
            new_meta = _extended(out_dir, new_meta, episodes)
        programs = _programs(TrainConfig.from_dict(new_meta["config"]), new_meta["rounds_per_chunk"])
        sharding = seed_sharding(new_meta["seeds"], devices)
        start = _start_point(out_dir, programs, new_meta, need_rows=True)
        rounds_done = start.chunk * programs.trainer.rounds_per_chunk
        twice = start.metrics.duplicate(rounds_done)
        if twice is not None:
            raise ValueError(f"{os.path.join(out_dir, 'metrics.csv')} holds two rows of seed {twice[0]}, round "
                             f"{twice[1]}: two trainings were mixed in this folder, which cannot be resumed; "
                             "start a new run with another --out")
        if start.chunk == 0:
            record = _record(out_dir, start)
            if record:
                why = _skipped_text(start).lstrip("; ") or (
                    "checkpoints/ is missing" if not start.steps else "it has none")
                raise ValueError(f"{out_dir} has no checkpoint to resume from ({why}) but holds a record "
                                 f"({', '.join(record)}): resuming would start it over and erase it. Nothing was "
                                 "changed; start a new run with another --out to train this configuration again")
        # --- everything checked: from here on the run's files change
        _say_skipped(out_dir, start, "resuming from")
        if new_meta != meta:
            write_json_atomic(os.path.join(out_dir, "config.json"), new_meta)
        if assignments:
            os.replace(os.path.join(out_dir, "diverged.json"), os.path.join(out_dir, "diverged.previous.json"))
        _set_aside_early_summary(out_dir, start.chunk < programs.trainer.total_chunks)
        _drop_checkpoints_after(out_dir, start)
        wall = _wall_seconds(out_dir) if start.chunk else 0.0
        _cut_metrics(os.path.join(out_dir, "metrics.csv"), start.metrics, rounds_done)
        return _loop(programs, start.state, start.chunk, out_dir, new_meta, checkpoint_seconds, progress,
                     stop_after_chunks, wall, sharding)


def placed(state, sharding=None):
    """``state`` committed to its device(s) (``sharding``, or the first device), as a restored checkpoint is: a
    fresh and a resumed run then lower to the same program, and the second one loads it from the persistent
    compilation cache instead of compiling it again (an uncommitted array lowers without a sharding)."""
    return jax.device_put(state, sharding if sharding is not None else jax.devices()[0])


def _loop(programs, state, chunk, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, wall_before,
          sharding=None):
    from tqdm import tqdm

    state = placed(state, sharding)
    trainer = programs.trainer
    config = trainer.config
    seed_ids = list(range(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    mngr = _checkpointer(out_dir)
    metrics_path = os.path.join(out_dir, "metrics.csv")
    total = trainer.total_chunks
    episodes_per_chunk = trainer.rounds_per_chunk * config.num_envs
    bar = tqdm(total=total * episodes_per_chunk, initial=chunk * episodes_per_chunk, unit="ep",
               desc=f"{config.algorithm} on {config.scenario}, {meta['seeds']} seeds (episodes per seed)", disable=not progress, dynamic_ncols=True)
    start = time.perf_counter()
    last_ckpt = time.perf_counter()
    last_eval = float("nan")
    done_here = 0
    bounds = value_bounds_of(config, trainer.env)
    # the metrics of the chunks since the last checkpoint: their rows are written with the checkpoint that covers
    # them, so metrics.csv never runs ahead of the run's checkpoints (but for a crash between the two)
    pending: list[tuple[dict[str, np.ndarray], int]] = []
    advice = (f"{out_dir} keeps its last checkpoint: free space, then `jaxmac train --resume {out_dir}` continues "
              "from it")
    try:
        while chunk < total:
            state, metrics = programs.chunk(state)
            metrics = dict(jax.device_get(metrics))
            flags = flag_out_of_bounds(metrics, bounds)
            if flags is not None:
                metrics[OUT_OF_BOUNDS_COLUMN] = flags
            first_round = chunk * trainer.rounds_per_chunk
            pending.append((metrics, first_round))
            problem = check_finite(metrics, seed_ids, first_round)
            outside = out_of_bounds_message(metrics, seed_ids, first_round, bounds)
            if outside and not config.divergence_guard:
                bar.set_postfix_str(f"value out of bounds: {outside.split(' is outside')[0]}")
            if problem or (outside and config.divergence_guard):
                # never checkpoint a diverged state: the newest checkpoint stays the last good one. The rows up to
                # the diverged chunk are written to show where it happened (a resume drops them).
                _append_chunks(metrics_path, pending, seed_ids, advice)
                last_good = mngr.latest_step()
                write_json_atomic(os.path.join(out_dir, "diverged.json"), {
                    "problem": problem or outside, "kind": "non-finite" if problem else "value out of bounds",
                    "chunk": chunk, "last_good_checkpoint": last_good})
                kept = (f"{out_dir} keeps its last good checkpoint (chunk {last_good})" if last_good is not None else
                        f"{out_dir} has no checkpoint from before it (resuming starts the run again)")
                what = f"training diverged at {problem}" if problem else (
                    f"the value estimate diverged at {outside} (set divergence_guard=false to train on regardless)")
                raise RuntimeError(f"{what}; stopped. {kept}: continue with other settings, e.g. "
                                   f"jaxmac train --resume {out_dir} --set lr=...")
            chunk += 1
            done_here += 1
            evals = metrics["eval_disc_return"]
            if np.isfinite(evals).any():
                last_eval = float(np.nanmean(evals[:, np.isfinite(evals).any(0)][:, -1]))
            bar.update(episodes_per_chunk)
            bar.set_postfix(eval_return=f"{last_eval:.1f}", eps=f"{float(metrics['epsilon'][0, -1]):.2f}")
            stopping = stop_after_chunks is not None and done_here >= stop_after_chunks and chunk < total
            if chunk == total or stopping or time.perf_counter() - last_ckpt >= checkpoint_seconds:
                size = _size_of(metrics_path)
                _append_chunks(metrics_path, pending, seed_ids, advice)  # fsynced before the checkpoint
                pending = []
                try:
                    _save_checkpoint(mngr, chunk, state, out_dir, advice)
                except BaseException:
                    _cut_back(metrics_path, size)  # no rows without the checkpoint that covers them
                    raise
                write_json_atomic(os.path.join(out_dir, "progress.json"),
                                  {"chunks_done": chunk, "wall_seconds": wall_before + time.perf_counter() - start})
                last_ckpt = time.perf_counter()
            if stopping:
                return None
    finally:
        bar.close()
        try:
            mngr.close()
        except Exception:  # a failed save may fail again here; the first error is the one to report
            pass
    wall = wall_before + time.perf_counter() - start
    return _finish(programs, state, out_dir, meta, wall)


def _save_checkpoint(mngr, chunk: int, state, out_dir: str, advice: str) -> None:
    import orbax.checkpoint as ocp

    where = os.path.join(out_dir, "checkpoints", str(chunk))
    try:
        mngr.save(chunk, args=ocp.args.StandardSave(_to_saveable(state)))
        mngr.wait_until_finished()
    except OSError as err:
        raise WriteFailed(where, err, advice) from err
    except Exception as err:  # orbax and tensorstore report a full disk in their own exception types
        raise WriteFailed(where, OSError(errno.EIO, _first_line(err)), advice) from err


def _finish(programs, state, out_dir, meta, wall_seconds):
    """Final greedy evaluation per seed, summary.json and the learning-curve plot."""
    from jaxmac.plotting import plot_learning_curve

    trainer = programs.trainer
    config = trainer.config
    keys = jax.vmap(lambda s: jax.random.fold_in(jax.random.key(10_007), s))(
        jnp.arange(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    # greedy: the value learners' evaluation policy, the actor-critics' greedy_act (their sampled one is kept too)
    disc, undisc = programs.greedy_returns(state.params, keys)
    summary = {
        "scenario": config.scenario,
        "algorithm": config.algorithm,
        "seeds": meta["seeds"],
        "seed_offset": meta["seed_offset"],
        "episodes": int(np.asarray(state.episodes)[0]),
        "wall_seconds": wall_seconds,
        "discount": trainer.env.spec.discount,
        "final_greedy_return": disc.tolist(),
        "final_greedy_return_mean": float(disc.mean()),
        "final_greedy_return_undiscounted": undisc.tolist(),
        "final_greedy_return_undiscounted_mean": float(undisc.mean()),
        "optimal_return": OPTIMAL_DISC_RETURN.get(config.scenario),
    }
    if trainer.evaluate_greedy:  # the stochastic evaluation policy of the originals (sampled, un-mixed)
        sampled, sampled_undisc = programs.sampled_returns(state.params, keys)
        summary.update(final_sampled_return=sampled.tolist(), final_sampled_return_mean=float(sampled.mean()),
                       final_sampled_return_undiscounted_mean=float(sampled_undisc.mean()))
    write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
    plot_learning_curve(os.path.join(out_dir, "metrics.csv"), os.path.join(out_dir, "curve.png"),
                        f"{config.algorithm} on {config.scenario}", OPTIMAL_DISC_RETURN.get(config.scenario),
                        label=config.algorithm)
    return summary


def default_out_dir(config: TrainConfig) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return os.path.join("runs", f"{config.scenario}-{config.algorithm}-{stamp}")


