"""Run folders: the thin host loop around the compiled trainer (seeds, progress, metrics, checkpoints, plots).

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

The modules, one job each:

    folders.py      the folder's lock, which files make it a run's, config.json (read_meta), atomic and fsynced writes
    metrics_csv.py  metrics.csv: its columns, rows appended as checkpoints cover them, read back and cut on resume
    checkpoints.py  orbax checkpoints: save, find, restore (falling back to older ones), remove stale ones
    divergence.py   the divergence guard's checks: non-finite metrics, value estimates outside the env's bounds
    programs.py     the jitted programs of a setting (init, chunk, final evaluations), built once per process
    resources.py    compilation cache, host devices, seed sharding, the budget and memory checks before compiling
    loop.py         train, resume, finish, extend, change a diverged run's settings; the chunk loop; the run's end
    fork.py         ``jaxmac fork``: a new run folder from a checkpoint of another, other settings or budget
    workers.py      several training processes on one machine (``jaxmac train --workers N``), merged at the end
    loggers.py      live views of a run: TensorBoard event files or W&B (``--log``), fed the rows a checkpoint covers
    evaluation.py   ``jaxmac eval``: greedy episodes of a run's checkpoint, played, printed and drawn
    qtot.py         ``jaxmac qtot``: ToMacVF's Q_tot along a greedy episode of a run, beside the return-to-go

This package re-exports the names callers use. ``workers`` is imported on first use of one of its names only: it is
also the workers' entry point (``python -m jaxmac.runs.workers``), which must find it not imported yet.
"""

from jaxmac.runs.divergence import (DIVERGED_FILE, OUT_OF_BOUNDS_COLUMN, VALUE_METRICS, WATCHED, RunDiverged,
                                    check_finite, diverged_record, flag_out_of_bounds, out_of_bounds_message,
                                    value_bounds_of)
from jaxmac.runs.folders import (LOCK_FILE, RUN_FILE_PATTERNS, RUN_FILES, FolderLock, RunFolderBusy, WriteFailed,
                                 default_out_dir, is_finished, live_holder, lock_holder, lock_run_folder, read_meta,
                                 refuse_run_files, run_files, try_lock_run_folder, write_json_atomic)
from jaxmac.runs.loop import (change_diverged_settings, extend_budget, finish_run, load_run, resume_run,
                              train_run)
from jaxmac.runs.metrics_csv import METRIC_COLUMNS, metric_columns
from jaxmac.runs.resources import (check_budget, check_memory, check_new_run, enable_compilation_cache,
                                   machine_memory, memory_estimate, placed, seed_sharding, use_host_devices)

_WORKER_NAMES = ("is_worker_run", "merge", "resume_workers", "split_seeds", "train_workers")

__all__ = [
    "DIVERGED_FILE", "LOCK_FILE", "METRIC_COLUMNS",
    "OUT_OF_BOUNDS_COLUMN", "RUN_FILES", "RUN_FILE_PATTERNS", "VALUE_METRICS", "WATCHED",
    "FolderLock", "RunDiverged", "RunFolderBusy", "WriteFailed",
    "change_diverged_settings", "check_budget", "check_finite", "check_memory", "check_new_run", "default_out_dir",
    "diverged_record",
    "enable_compilation_cache", "extend_budget", "finish_run", "flag_out_of_bounds", "is_finished", "live_holder",
    "load_run", "lock_holder", "lock_run_folder", "machine_memory", "memory_estimate", "metric_columns",
    "out_of_bounds_message",
    "placed", "read_meta", "refuse_run_files", "resume_run", "run_files", "seed_sharding", "train_run",
    "try_lock_run_folder", "use_host_devices", "value_bounds_of", "write_json_atomic",
    *_WORKER_NAMES,
]


def __getattr__(name: str):
    if name in _WORKER_NAMES:
        from jaxmac.runs import workers

        return getattr(workers, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
