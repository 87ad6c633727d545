"""A run folder's files: its one owner (an OS lock on ``run.lock``), which files make a folder a run's, its
``config.json`` (``read_meta``) and the writes that survive a crash (atomic JSON, fsynced appends, cut back on failure).
"""

from __future__ import annotations

import dataclasses
import errno
import fnmatch
import json
import os
import socket
import time
from typing import Any

from envs_jax.validation import is_integer
from jaxmac.algos import registry  # noqa: F401  (registers every learner's settings, which config.json names)
from jaxmac.config import TrainConfig
from jaxmac.runs.divergence import DIVERGED_FILE, DIVERGED_PREVIOUS_FILE

# --- one owner per run folder ------------------------------------------------------------------------------------

LOCK_FILE = "run.lock"
# The files that make a folder a run's (``train_run`` refuses a folder holding any of them).
RUN_FILES = ("config.json", "metrics.csv", "summary.json", "progress.json", DIVERGED_FILE, DIVERGED_PREVIOUS_FILE,
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


def live_holder(out_dir: str) -> dict | None:
    """The holder of ``out_dir``'s lock if it is a live process on this host (its pid, host, command, since), else None.

    Read without touching the lock: a probe that took it, however briefly, could make a starting ``jaxmac sweep``
    process skip the cell. A lock file is removed when its holder lets go, so one left behind names a killed process;
    its pid counts only while that process lives (a reused pid would read as alive: this is for messages only)."""
    holder = lock_holder(out_dir)
    if not holder or holder.get("host") != socket.gethostname() or not is_integer(holder.get("pid")):
        return None
    try:
        os.kill(int(holder["pid"]), 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # alive, another user's
        pass
    return holder


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
    missing = [k for k in needed if not is_integer(meta.get(k))]
    if missing:
        raise ValueError(f"{path} is broken: it lacks {', '.join(missing)} (an integer each); {fix}")
    try:
        TrainConfig.from_dict(meta["config"])
    except (ValueError, TypeError, KeyError) as err:
        raise ValueError(f"{path} holds invalid settings ({err}); {fix}") from err
    return meta


def fsync_dir(path: str) -> None:
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


def append_text(path: str, text: str, advice: str = "") -> None:
    """Append ``text`` to ``path`` and fsync it (on disk before the checkpoint that covers it is saved). A failed
    append (a full disk) is cut off again, so that the file never holds rows no checkpoint covers."""
    size = size_of(path)
    try:
        with open(path, "a", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
    except OSError as err:
        cut_back(path, size)
        raise WriteFailed(path, err, advice) from err


def size_of(path: str) -> int | None:
    return os.path.getsize(path) if os.path.exists(path) else None


def cut_back(path: str, size: int | None) -> None:
    """Return ``path`` to the ``size`` it had (None: it did not exist), best effort: rows a failed checkpoint would
    have covered go (a partial line left behind is dropped by the next resume)."""
    try:
        if size is None:
            os.remove(path)
        else:
            os.truncate(path, size)
    except OSError:
        pass


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


def read_progress(out_dir: str) -> dict | None:
    """The run's ``progress.json`` (what its newest checkpoint covers: ``chunks_done``, and ``wall_seconds`` of
    training accumulated over resumes); None before the first checkpoint or when it cannot be read."""
    try:
        with open(os.path.join(out_dir, "progress.json")) as f:
            progress = json.load(f)
    except (OSError, ValueError):
        return None
    return progress if isinstance(progress, dict) else None


def is_finished(out_dir: str) -> bool:
    return os.path.exists(os.path.join(out_dir, "summary.json"))


def default_out_dir(config: TrainConfig) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return os.path.join("runs", f"{config.scenario}-{config.algorithm}-{stamp}")
