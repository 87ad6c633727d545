"""Live views of a run beyond the progress bar (``jaxmac train --log tensorboard|wandb``): the rows of metrics.csv,
handed on as checkpoints cover them, to TensorBoard event files in the run folder or to a W&B run.

Both are optional extras, imported only when a run logs to them (``pip install -e ".[tensorboard]"`` or
``".[wandb]"``). Each round is one step, at x = the episodes trained per seed (metrics.csv's ``episodes``); its
tags are ``seed{S}/{column}`` for every seed and column of metrics.csv (but ``seed``, ``round``, ``episodes``) and
``mean/{column}``, the mean over the seeds. A metric not computed that round (NaN in metrics.csv: the evaluation
columns between evaluations) is left out of the step.

What is logged never runs ahead of what a resume keeps: a chunk's rows are handed on only once the checkpoint that
covers them is saved (the rows of a diverged chunk, which a resume drops, never are). A logger knows the last step
its stream holds (``last_step``: TensorBoard reads it back from the event files, W&B keeps it in
``wandb/jaxmac-logged.json``) and skips every step up to it, so a resumed run continues the same stream without a
step twice; and at the start of every (resumed) run the rows of metrics.csv past that step are logged first, so a
stream turned on mid-run (``--resume RUN --log tensorboard``), or one whose last events a kill lost, is filled in.

The run's choice is recorded in its config.json (``"log"``), so that ``--resume`` goes on logging. With
``--workers`` each worker folder ``RUN/workerK`` is an ordinary run folder with its own stream (its seeds; ``mean/``
is over them); ``tensorboard --logdir RUN`` shows the workers side by side, and their W&B runs share the group
``RUN``'s name.
"""

from __future__ import annotations

import csv
import glob
import json
import math
import os
import sys
import uuid
from collections.abc import Iterable
from typing import Any, Protocol

import numpy as np

LOG_CHOICES = ("none", "tensorboard", "wandb", "wandb:online")
# what each logger imports, and the extra that installs it
_LIBRARIES = {"tensorboard": ("tensorboardX", "tensorboard"), "wandb": ("wandb", "wandb")}
EVENT_FILES = "events.out.tfevents.*"
WANDB_STEP_FILE = os.path.join("wandb", "jaxmac-logged.json")
_NOT_LOGGED = ("seed", "round", "episodes")

RowsBySeed = dict[int, dict[str, float]]


class MetricsLogger(Protocol):
    """Where a run's metrics go besides metrics.csv. ``log`` is called once per round, in step order, with every
    seed's row (column -> value; NaN where not computed); steps up to ``last_step`` are already in the stream and
    are skipped. ``flush`` is called after each checkpoint's rows, ``close`` at the end of the run (however it ends)."""

    last_step: int

    def log(self, rows_by_seed: RowsBySeed, step: int) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...


class LoggerUnavailable(ValueError):
    """The library of the run's logger is not installed (a one-line error naming the extra that installs it)."""


# --- the choice, as given and as recorded in config.json -----------------------------------------------------------

def log_choice(log: str | None) -> str | None:
    """``log`` checked (one of ``LOG_CHOICES``); ``None`` for no logger."""
    if log is None or log == "none":
        return None
    if log not in LOG_CHOICES:
        raise ValueError(f"log={log!r}: choose one of {', '.join(LOG_CHOICES)}")
    return log


def _kind(log: str) -> str:
    return log.split(":")[0]


def require(log: str | None) -> None:
    """Import the library of ``log`` (nothing for None), or raise ``LoggerUnavailable`` naming the extra."""
    log = log_choice(log)
    if log is None:
        return
    module, extra = _LIBRARIES[_kind(log)]
    try:
        __import__(module)
    except ImportError as err:
        raise LoggerUnavailable(f"--log {log} needs {module}, which is not installed ({err}): "
                                f"pip install -e \".[{extra}]\" (or pip install {module}), or give --log none"
                                ) from None


def with_logger(meta: dict[str, Any], log: str | None) -> dict[str, Any]:
    """``meta`` (a config.json) recording ``log``: ``"log"`` (absent for none) and, for W&B, the run's id (kept if
    it had one, so a resumed run goes on in the same W&B run)."""
    log = log_choice(log)
    out = {k: v for k, v in meta.items() if k != "log"}
    if log is not None:
        out["log"] = log
        if _kind(log) == "wandb" and not isinstance(out.get("wandb_id"), str):
            out["wandb_id"] = uuid.uuid4().hex[:12]
    return out


def check_new_stream(log: str | None, out_dir: str) -> None:
    """Before a new run writes anything: the logger's library is there, and the folder holds no event files of
    another run (the new run's steps would mix with theirs, and a resume would take their last step for its own)."""
    log = log_choice(log)
    require(log)
    if log == "tensorboard" and _event_files(out_dir):
        raise ValueError(f"{out_dir} holds TensorBoard event files ({os.path.basename(_event_files(out_dir)[0])}) "
                         "of another run: a new run's would mix with them. Move them away or choose another --out")


# --- opening the run's logger and feeding it ------------------------------------------------------------------------

def open_logger(out_dir: str, meta: dict[str, Any]) -> MetricsLogger | None:
    """The logger ``meta`` (the run's config.json) records, None if none; its library imported (or
    ``LoggerUnavailable``). Writes nothing until it logs a step."""
    log = log_choice(meta.get("log"))
    if log is None:
        return None
    require(log)
    if log == "tensorboard":
        return TensorBoardLogger(out_dir)
    return WandbLogger(out_dir, meta, online=log == "wandb:online")


class Guarded:
    """A logger whose failure (a full disk, a W&B error) is one warning on stderr and ends its logging, never the
    training: the rows stay in metrics.csv, and a later ``--resume`` logs those it missed."""

    def __init__(self, logger: MetricsLogger):
        self.logger: MetricsLogger | None = logger

    def _call(self, what: str, *args) -> None:
        if self.logger is None:
            return
        try:
            getattr(self.logger, what)(*args)
        except Exception as err:  # noqa: BLE001  (the training goes on; the user is told once)
            print(f"jaxmac: logging to {type(self.logger).__name__} failed ({type(err).__name__}: {err}); it stops "
                  "for this run (metrics.csv keeps every row; a --resume logs the rows it missed)", file=sys.stderr)
            logger, self.logger = self.logger, None
            if what != "close":
                try:
                    logger.close()
                except Exception:  # noqa: BLE001, S110  (the first failure is the one reported)
                    pass

    def log_rows(self, rounds: Iterable[tuple[int, RowsBySeed]]) -> None:
        """Log ``(step, rows_by_seed)`` of consecutive rounds, then flush."""
        for step, rows in rounds:
            if self.logger is None:
                return
            if step > self.logger.last_step:
                self._call("log", rows, step)
        self._call("flush")

    def close(self) -> None:
        self._call("close")


def rounds_of_metrics_file(path: str, after_step: int = 0) -> list[tuple[int, RowsBySeed]]:
    """metrics.csv's rows past ``after_step`` as ``(step, rows_by_seed)`` per round, in round order."""
    if not os.path.exists(path):
        return []
    by_round: dict[int, tuple[int, RowsBySeed]] = {}
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if not header or header[:3] != ["seed", "round", "episodes"]:
            return []
        for fields in reader:
            if len(fields) != len(header):
                continue
            try:
                seed, rnd, episodes = int(fields[0]), int(fields[1]), int(fields[2])
                row = {k: float(v) for k, v in zip(header[3:], fields[3:])}
            except ValueError:
                continue
            if episodes > after_step:
                by_round.setdefault(rnd, (episodes, {}))[1][seed] = row
    return [by_round[r] for r in sorted(by_round)]


def rounds_of_chunks(path: str, chunks: list[tuple[dict[str, np.ndarray], int]], seed_ids: list[int]
                     ) -> list[tuple[int, RowsBySeed]]:
    """The rounds of chunks just appended to metrics.csv (``path``) as ``(step, rows_by_seed)``: their columns
    those of its header, their values as written there (so the stream and the file agree)."""
    if not chunks:
        return []
    with open(path, newline="") as f:
        columns = next(csv.reader(f))[3:]
    out = []
    for metrics, _ in chunks:
        seeds, rounds = np.shape(metrics["episodes"])
        for r in range(rounds):
            rows = {seed_ids[s]: {k: float(metrics[k][s, r]) if k in metrics else math.nan for k in columns}
                    for s in range(seeds)}
            out.append((int(metrics["episodes"][0, r]), rows))
    return out


def scalars(rows_by_seed: RowsBySeed) -> dict[str, float]:
    """A step's tags: ``seed{S}/{column}`` for every finite value, and ``mean/{column}`` over the seeds that have one."""
    out: dict[str, float] = {}
    columns: dict[str, list[float]] = {}
    for seed in sorted(rows_by_seed):
        for k, v in rows_by_seed[seed].items():
            if k in _NOT_LOGGED or not math.isfinite(v):
                continue
            out[f"seed{seed}/{k}"] = v
            columns.setdefault(k, []).append(v)
    for k, values in columns.items():
        out[f"mean/{k}"] = float(np.mean(values))
    return out


# --- TensorBoard ----------------------------------------------------------------------------------------------------

def _event_files(folder: str) -> list[str]:
    return sorted(glob.glob(os.path.join(glob.escape(folder), EVENT_FILES)))


def _records(data: bytes) -> Iterable[bytes]:
    """The complete records of a TFRecord file's bytes (8-byte length, 4-byte CRC, data, 4-byte CRC each); a torn
    last record (a kill mid-write) ends them."""
    pos = 0
    while pos + 12 <= len(data):
        (length,) = np.frombuffer(data, "<u8", 1, pos)
        end = pos + 12 + int(length) + 4
        if end > len(data):
            return
        yield data[pos + 12:end - 4]
        pos = end


def last_event_step(folder: str) -> int:
    """The highest step of a scalar in the event files of ``folder`` (0 if none)."""
    from tensorboardX.proto.event_pb2 import Event

    last = 0
    for path in _event_files(folder):
        try:
            with open(path, "rb") as f:
                data = f.read()
        except OSError:
            continue
        for record in _records(data):
            event = Event()
            try:
                event.ParseFromString(record)
            except Exception:  # noqa: BLE001  (a damaged record: what follows it is not trusted)
                break
            if event.HasField("summary") and event.summary.value:
                last = max(last, int(event.step))
    return last


class TensorBoardLogger:
    """Scalars in TensorBoard event files in the run folder (``tensorboardX``), one event per step holding all its
    tags. Every process that logs writes a file of its own; TensorBoard reads a folder's files as one run."""

    def __init__(self, out_dir: str):
        self.out_dir = out_dir
        self.last_step = last_event_step(out_dir)
        self._writer = None

    def _open(self):
        from tensorboardX import FileWriter

        # a suffix of our own: two writers in the same second (a run stopped and resumed at once) must not share
        # a file name (the second would truncate the first's file)
        taken = {os.path.basename(p) for p in _event_files(self.out_dir)}
        k = len(taken)
        while any(name.endswith(f".jaxmac{k}") for name in taken):
            k += 1
        return FileWriter(self.out_dir, max_queue=1000, flush_secs=30, filename_suffix=f".jaxmac{k}")

    def log(self, rows_by_seed: RowsBySeed, step: int) -> None:
        from tensorboardX.proto.summary_pb2 import Summary

        if step <= self.last_step:
            return
        values = [Summary.Value(tag=tag, simple_value=value) for tag, value in scalars(rows_by_seed).items()]
        if not values:
            return
        if self._writer is None:
            self._writer = self._open()
        self._writer.add_summary(Summary(value=values), global_step=step)
        self.last_step = step

    def flush(self) -> None:
        if self._writer is not None:
            self._writer.flush()

    def close(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()


# --- Weights & Biases -----------------------------------------------------------------------------------------------

class WandbLogger:
    """A W&B run (``wandb``), offline by default: its files go to ``RUN/wandb`` (``wandb sync RUN/wandb/offline-run-*``
    uploads them later). ``online`` (``--log wandb:online``), or the environment's ``WANDB_MODE``, sends it as it
    runs; ``WANDB_PROJECT`` names the project (default ``jaxmac``). The run's id is kept in config.json, so a resumed
    run goes on in the same W&B run; the last step sent is kept in ``RUN/wandb/jaxmac-logged.json``."""

    def __init__(self, out_dir: str, meta: dict[str, Any], online: bool = False):
        self.out_dir = out_dir
        self.meta = meta
        self.mode = "online" if online else os.environ.get("WANDB_MODE", "offline")
        self.last_step = self._read_last_step()
        self._run = None

    def _read_last_step(self) -> int:
        try:
            with open(os.path.join(self.out_dir, WANDB_STEP_FILE)) as f:
                return int(json.load(f)["last_step"])
        except (OSError, ValueError, KeyError, TypeError):
            return 0

    def _open(self):
        import wandb

        folder = os.path.abspath(self.out_dir)
        in_workers = os.path.exists(os.path.join(folder, "job.json"))  # a worker's folder of a --workers run
        name = os.path.basename(folder)
        config = dict(self.meta.get("config", {}), seeds=self.meta.get("seeds"),
                      seed_offset=self.meta.get("seed_offset"))
        return wandb.init(project=os.environ.get("WANDB_PROJECT", "jaxmac"), dir=self.out_dir, mode=self.mode,
                          id=self.meta.get("wandb_id"), resume="allow", config=config,
                          name=f"{os.path.basename(os.path.dirname(folder))}/{name}" if in_workers else name,
                          group=os.path.basename(os.path.dirname(folder)) if in_workers else None)

    def log(self, rows_by_seed: RowsBySeed, step: int) -> None:
        if step <= self.last_step:
            return
        values = scalars(rows_by_seed)
        if not values:
            return
        if self._run is None:
            self._run = self._open()
        self._run.log(values, step=step)
        self.last_step = step

    def flush(self) -> None:
        if self._run is None:
            return
        from jaxmac.runs.folders import write_json_atomic

        os.makedirs(os.path.join(self.out_dir, "wandb"), exist_ok=True)
        write_json_atomic(os.path.join(self.out_dir, WANDB_STEP_FILE), {"last_step": self.last_step})

    def close(self) -> None:
        if self._run is None:
            return
        self.flush()
        run, self._run = self._run, None
        run.finish()
