"""A sweep on a Ray cluster: every cell a Ray task (``jaxmac sweep EXP --cluster ray``).

    jaxmac sweep EXP --cluster ray [--ray-address ADDRESS] [--cpus-per-cell N] [--gpus-per-cell N]

Without an address Ray does as ``ray.init()`` does: it joins the cluster named by ``RAY_ADDRESS`` or started on this
machine with ``ray start``, else starts a local Ray instance (on every core; it ends with the sweep); with one
(``auto``: the cluster this node belongs to, and never a new one; ``HOST:6379``; ``ray://HOST:10001``) the sweep joins
that cluster. Ray is an optional
extra (``pip install -e ".[cluster]"``) imported by this module only: the embedded sweep (``run_sweep``) never
needs it.

A task is one cell: it takes the cell's folder lock, trains or resumes it (``jaxmac.study.sweep.run_cell``, the code
path of the embedded sweep) and records where it ran in the cell's ``attempts.jsonl`` (executor ``ray``, node, task
and job ids, host, process, devices, JAX's version). Ray schedules the tasks by the resources they ask for
(``cpus_per_cell``, ``gpus_per_cell``), so at most as many run at once as the cluster holds; each task runs in a
process of its own (``max_calls=1``: a GPU's memory and XLA's flags start fresh for every cell).

Faults are Ray's own retries: a task whose worker process or node dies is run again (``retries`` times), and the new
attempt resumes the cell from its newest checkpoint, ending with the result of an uninterrupted cell (checkpoints
are saved every ``checkpoint_seconds``). A task that fails for its own reason (a bad setting, a diverged run) raises,
and is not retried (``retry_exceptions=False``): the sweep reports it once, with its message, and the other cells
finish. Interrupting the driver (Ctrl-C) cancels the tasks; every cell keeps its newest checkpoint, and the same
command resumes them.

Where results go: the driver writes a marker file into the sweep folder and each task looks for it. Where the task
sees it (a shared filesystem, or a task on the driver's machine), the cell trains in the sweep folder as in an
embedded sweep. Where not, it trains in the node's scratch folder (``$JAXMAC_RAY_SCRATCH``, else
``<tmp>/jaxmac-ray``; under a folder named after the driver's host and sweep folder, so that a retry or a rerun on
that node resumes it) and returns the finished cell's small files (``RETURNED_FILES``), which the driver writes into
the sweep folder; the checkpoints stay on the node.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import socket
import tempfile
import time
import uuid

from jaxmac.runs.divergence import DIVERGED_FILE
from jaxmac.study.sweep import ATTEMPTS_FILE, Cell, cell_status, diverged_text, estimate_seconds, run_cell

EXECUTOR = "ray"
# what a cell trained without the sweep folder sends back: the run folder less its checkpoints (summary.json, or
# diverged.json where the divergence guard stopped it, last: it is what makes a cell finished, or diverged)
RETURNED_FILES = ("config.json", "metrics.csv", "curve.png", ATTEMPTS_FILE, DIVERGED_FILE, "summary.json")
MARKER_PREFIX = ".ray-driver-"  # + a token per driver: the file a task looks for to know it sees the sweep folder
SCRATCH_ENV = "JAXMAC_RAY_SCRATCH"


class Board:
    """Which cells' tasks are running now (a Ray actor without resources): the tasks say when they start and end,
    the driver reads it for its progress bar. A task whose worker died stays listed until its retry starts."""

    def __init__(self):
        self.running: dict[str, dict] = {}

    def started(self, path: str, info: dict) -> None:
        self.running[path] = info

    def ended(self, path: str) -> None:
        self.running.pop(path, None)

    def now(self) -> dict[str, dict]:
        return dict(self.running)


def scratch_folder(out_dir: str, driver_host: str, scratch: str | None = None) -> str:
    """Where a node that does not see the sweep folder ``out_dir`` (of the driver on ``driver_host``) trains its
    cells: the same folder for every task of that sweep folder on that node, so that a retry or a rerun resumes."""
    base = scratch or os.environ.get(SCRATCH_ENV) or os.path.join(tempfile.gettempdir(), "jaxmac-ray")
    digest = hashlib.sha1(f"{driver_host}:{out_dir}".encode()).hexdigest()[:12]
    return os.path.join(base, f"{os.path.basename(out_dir.rstrip(os.sep)) or 'sweep'}-{digest}")


def cell_task(cell: Cell, out_dir: str, token: str, driver_host: str, interrupted_at_driver: bool, devices: int,
              checkpoint_seconds: float, shared: bool | None, scratch: str | None, board) -> dict:
    """The body of a cell's Ray task (runs on a worker): train or resume ``cell``; returns what was done, where, and
    the cell's files when it ran outside the sweep folder."""
    import ray

    from jaxmac.runs import enable_compilation_cache

    start = time.perf_counter()
    context = ray.get_runtime_context()
    where = {"executor": EXECUTOR, "node_id": context.get_node_id(), "task_id": context.get_task_id(),
             "job_id": context.get_job_id(), "ray": ray.__version__}
    if shared is None:
        shared = os.path.exists(os.path.join(out_dir, MARKER_PREFIX + token))
    if not shared and interrupted_at_driver:
        raise ValueError(f"{cell.path} was interrupted in the driver's sweep folder {out_dir}, whose checkpoints this "
                         f"node ({socket.gethostname()}) does not see: resume it without --cluster, or on a cluster "
                         "that shares the folder")
    base = out_dir if shared else scratch_folder(out_dir, driver_host, scratch)
    info = {"node_id": where["node_id"], "host": socket.gethostname(), "pid": os.getpid()}
    _tell(board, "started", cell.path, info)
    try:
        enable_compilation_cache()
        done = run_cell(cell, base, devices=devices, progress=False, log=lambda *_: None,
                        checkpoint_seconds=checkpoint_seconds, where=where)
    finally:
        _tell(board, "ended", cell.path)
    files = {}
    if not shared and done != "busy":
        folder = os.path.join(base, cell.path)
        for name in RETURNED_FILES:
            if os.path.exists(os.path.join(folder, name)):
                with open(os.path.join(folder, name), "rb") as f:
                    files[name] = f.read()
    return dict(info, done=done, shared=shared, files=files, seconds=time.perf_counter() - start,
                folder=os.path.join(base, cell.path))


def _tell(board, method: str, *args) -> None:
    if board is None:
        return
    try:  # progress only: a lost board must not fail a cell
        getattr(board, method).remote(*args)
    except Exception:
        pass


def _strip_device_count(flags: str) -> str:
    return " ".join(f for f in flags.split() if not f.startswith("--xla_force_host_platform_device_count"))


def worker_env(devices: int, gpus_per_cell: float) -> dict[str, str]:
    """Environment variables of the cells' worker processes: this process's XLA flags (and JAXMAC_CACHE, the
    compilation cache, where set), a CPU cell's host split into ``devices`` devices, and a GPU shared between
    cells without JAX's preallocation of most of its memory."""
    env = {}
    flags = _strip_device_count(os.environ.get("XLA_FLAGS", ""))
    if devices > 1 and not gpus_per_cell:
        flags = f"{flags} --xla_force_host_platform_device_count={devices}".strip()
    if flags:
        env["XLA_FLAGS"] = flags
    if os.environ.get("JAXMAC_CACHE"):
        env["JAXMAC_CACHE"] = os.environ["JAXMAC_CACHE"]
    if 0 < gpus_per_cell < 1:
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    return env


def cell_devices(devices: int | None, gpus_per_cell: float) -> int:
    """The devices a cell's seeds are sharded over: ``devices``, by default the whole GPUs of a cell (else 1)."""
    if gpus_per_cell < 0:
        raise ValueError(f"--gpus-per-cell {gpus_per_cell:g}: give a number >= 0")
    if devices is None:
        return max(1, int(gpus_per_cell))
    if gpus_per_cell and devices > max(1, int(gpus_per_cell)):
        raise ValueError(f"--devices {devices} with --gpus-per-cell {gpus_per_cell:g}: a cell sees the GPUs Ray gives "
                         "it; ask for at least as many GPUs per cell as devices")
    return devices


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _failure(err: BaseException, retries: int) -> str:
    import ray

    if isinstance(err, ray.exceptions.RayTaskError):  # the cell's own error: its message, without Ray's traceback
        cause = getattr(err, "cause", None)
        return _one_line(f"{type(cause).__name__}: {cause}" if cause is not None else err)
    if isinstance(err, ray.exceptions.TaskCancelledError):
        return "cancelled"
    first = str(err).strip().splitlines()[0] if str(err).strip() else ""
    return _one_line(f"{type(err).__name__} after {retries} retries ({first}); the cell keeps its newest checkpoint "
                     "and the same command resumes it")


def _write_bytes_atomic(path: str, data: bytes) -> None:
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_returned(out_dir: str, cell: Cell, files: dict[str, bytes]) -> None:
    """Write a cell's files, returned by a task that ran outside the sweep folder, into its folder there (holding
    the folder's lock; summary.json last; the task's attempt lines appended to the folder's own)."""
    from jaxmac.runs import RunFolderBusy, lock_run_folder

    if "summary.json" not in files and DIVERGED_FILE not in files:
        raise RunFolderBusy(f"{cell.path}: the task returned neither summary.json nor {DIVERGED_FILE}")
    path = os.path.join(out_dir, cell.path)
    with lock_run_folder(path, "sweep --cluster ray (writing a returned cell)"):
        if cell_status(out_dir, cell) == "done":
            return
        for name in RETURNED_FILES:
            if name not in files:
                continue
            if name == ATTEMPTS_FILE:
                with open(os.path.join(path, name), "ab") as f:
                    f.write(files[name])
                    f.flush()
                    os.fsync(f.fileno())
            else:
                _write_bytes_atomic(os.path.join(path, name), files[name])


def _eta_seconds(pending: list[Cell], running: dict[str, float], cells: dict[str, Cell], durations: dict[str, float],
                 rates: dict, slots: int) -> float | None:
    """Seconds until the sweep ends: the measured rates' estimates of the cells left (``estimate_seconds``), scaled by
    how long the finished cells took against their estimates; without rates, the finished cells' mean duration.
    ``running``: path -> seconds it has run. None while nothing says (no rates, no finished cell)."""
    estimates = {p: e[0] for p in list(running) + [c.path for c in pending]
                 if (e := estimate_seconds(cells[p], rates)) is not None}
    timed = {p: estimate_seconds(cells[p], rates) for p in durations}
    pairs = [(durations[p], e[0]) for p, e in timed.items() if e is not None and e[0] > 0]
    scale = sum(d for d, _ in pairs) / sum(e for _, e in pairs) if pairs else 1.0
    mean = sum(durations.values()) / len(durations) if durations else None

    def left(path: str, elapsed: float = 0.0) -> float | None:
        whole = estimates[path] * scale if path in estimates else mean
        return None if whole is None else max(0.0, whole - elapsed)

    parts = [left(p, t) for p, t in running.items()] + [left(c.path) for c in pending]
    if any(p is None for p in parts):
        return None
    return sum(parts) / max(1, slots)


def _format_eta(seconds: float | None) -> str:
    if seconds is None:
        return "ETA ?"
    minutes = math.ceil(seconds / 60)
    return f"ETA ~{minutes // 60}:{minutes % 60:02d} h" if minutes >= 60 else f"ETA ~{minutes} min"


def _a_local_instance_of_ours() -> bool:
    """Whether this process started the Ray instance it is connected to (a new local one: no node will join it)."""
    try:
        import ray

        return bool(ray._private.worker._global_node.head)  # a private field: False (only warn) if it moves
    except Exception:
        return False


def _slots(cpus_per_cell: float, gpus_per_cell: float) -> tuple[int, str]:
    import ray

    have = ray.cluster_resources()
    cpus, gpus = have.get("CPU", 0.0), have.get("GPU", 0.0)
    slots = [cpus // cpus_per_cell] + ([gpus // gpus_per_cell] if gpus_per_cell else [])
    return int(min(slots)), f"{cpus:g} CPUs, {gpus:g} GPUs"


def run_sweep_ray(cells: list[Cell], out_dir: str, devices: int | None = None, progress: bool = True, log=None,
                  checkpoint_seconds: float = 120.0, address: str | None = None, cpus_per_cell: float = 1.0,
                  gpus_per_cell: float = 0.0, retries: int = 3, shared: bool | None = None,
                  scratch: str | None = None, rates: dict | None = None,
                  init: dict | None = None) -> dict[str, str]:
    """Run every cell not done yet as a Ray task; returns {cell path: 'trained' | 'resumed' | 'extended' | 'skipped' |
    'busy' | 'failed: MESSAGE'}. Uses the Ray instance this process is connected to, else ``ray.init(address, **init)``
    (None: ``RAY_ADDRESS`` or a cluster started on this machine, else a new local instance), and disconnects at the
    end (a local instance it started ends). ``shared``: whether the
    tasks see ``out_dir`` (None: each task looks); ``scratch``: the nodes' folder for cells outside it;
    ``rates``: measured rates (``load_rates``) for the ETA. Ctrl-C cancels the tasks and raises KeyboardInterrupt."""
    import ray
    from tqdm import tqdm

    if cpus_per_cell <= 0:
        raise ValueError(f"--cpus-per-cell {cpus_per_cell:g}: give a number > 0")
    devices = cell_devices(devices, gpus_per_cell)
    if retries < 0:
        raise ValueError(f"--retries {retries}: give a number >= 0")
    out_dir = os.path.abspath(out_dir)
    by_path = {c.path: c for c in cells}
    results: dict[str, str] = {}
    bar = None
    statuses = {}
    for cell in cells:  # a cell whose settings or folder are refused fails alone, before anything starts
        try:
            statuses[cell.path] = cell_status(out_dir, cell)
        except ValueError as err:
            results[cell.path] = f"failed: {_one_line(f'{type(err).__name__}: {err}')}"

    def say(line: str) -> None:
        if log is not None:
            log(line)
        elif bar is not None and not bar.disable:
            bar.write(line)
        else:
            print(line, flush=True)

    for cell in cells:
        if cell.path not in statuses:
            say(f"{cell.path}: {results[cell.path]}")
        elif statuses[cell.path] == "done":
            say(f"{cell.path}: done")
            results[cell.path] = "skipped"
        elif statuses[cell.path] == "diverged":
            say(f"{cell.path}: diverged, not rerun ({diverged_text(os.path.join(out_dir, cell.path))})")
            results[cell.path] = "diverged"
    todo = [c for c in cells if statuses.get(c.path) in ("new", "interrupted", "shorter")]
    if not todo:
        return results

    started_here = not ray.is_initialized()
    if started_here:
        options = {"include_dashboard": False}
        options.update(init or {})
        ray.init(address=address, **options)
    marker = os.path.join(out_dir, MARKER_PREFIX + uuid.uuid4().hex)
    refs: dict = {}
    try:
        slots, held = _slots(cpus_per_cell, gpus_per_cell)
        asked = f"{cpus_per_cell:g} CPU" + (f" and {gpus_per_cell:g} GPU" if gpus_per_cell else "") + " per cell"
        if slots < 1:
            if _a_local_instance_of_ours():
                raise ValueError(f"the local Ray instance has {held}; a cell asks for {asked}")
            say(f"the Ray cluster has {held} now; a cell asks for {asked}: the cells wait for nodes that have it")
        say(f"Ray: {len(todo)} cells as tasks of {asked}, {max(slots, 0)} at once on the cluster ({held})")
        os.makedirs(out_dir, exist_ok=True)
        with open(marker, "w") as f:
            f.write(json.dumps({"host": socket.gethostname(), "pid": os.getpid()}))
        board = ray.remote(num_cpus=0)(Board).remote()
        task = ray.remote(max_calls=1)(cell_task).options(
            num_cpus=cpus_per_cell, num_gpus=gpus_per_cell, max_retries=retries, retry_exceptions=False,
            **({"runtime_env": {"env_vars": env}} if (env := worker_env(devices, gpus_per_cell)) else {}))
        host = socket.gethostname()
        for cell in todo:
            ref = task.remote(cell, out_dir, os.path.basename(marker)[len(MARKER_PREFIX):], host,
                              statuses[cell.path] in ("interrupted", "shorter"), devices, checkpoint_seconds, shared,
                              scratch,
                              board)
            refs[ref] = cell
        bar = tqdm(total=len(todo), unit="cell", desc="cells", disable=not progress, dynamic_ncols=True,
                   bar_format="{desc}: {n_fmt}/{total_fmt} {bar} [{elapsed}{postfix}]")
        started_at: dict[str, float] = {}
        durations: dict[str, float] = {}
        failed = 0
        last_look = 0.0
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=1.0)
            for ref in ready:
                cell = refs.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as err:
                    results[cell.path] = f"failed: {_failure(err, retries)}"
                    failed += 1
                    say(f"{cell.path}: {results[cell.path]}")
                else:
                    try:
                        if result["files"]:
                            write_returned(out_dir, cell, result["files"])
                    except (ValueError, OSError) as err:  # the sweep folder's cell is held here, or unwritable
                        results[cell.path] = f"failed: {_one_line(f'{type(err).__name__}: {err}')}"
                        failed += 1
                        say(f"{cell.path}: {results[cell.path]} (its files stay in {result['folder']})")
                        bar.update(1)
                        continue
                    results[cell.path] = result["done"]
                    if result["done"] in ("trained", "resumed", "extended"):
                        durations[cell.path] = result["seconds"]
                    where = f"{result['host']} (node {result['node_id'][:8]}, pid {result['pid']})"
                    what = {"busy": "being trained by another sweep process (left to it)"}.get(
                        result["done"], result["done"])
                    say(f"{cell.path}: {what} on {where} in {result['seconds']:.0f} s"
                        + ("" if result["shared"] else f"; files returned from {result['folder']}"))
                bar.update(1)
            now = time.monotonic()
            if progress and (ready or now - last_look > 2.0):
                last_look = now
                try:
                    running = ray.get(board.now.remote(), timeout=5.0)
                except Exception:
                    running = {}
                waiting = {c.path for c in refs.values()}
                for path in running:
                    started_at.setdefault(path, now)
                running_for = {p: now - started_at[p] for p in running if p in waiting}
                pending = [c for c in refs.values() if c.path not in running_for]
                eta = _eta_seconds(pending, running_for, by_path, durations, rates or {}, max(1, slots))
                finished = len(todo) - len(refs) - failed
                bar.set_postfix_str(f"done {finished}, running {len(running_for)}, pending {len(pending)}"
                                    + (f", failed {failed}" if failed else "") + f", {_format_eta(eta)}")
    except KeyboardInterrupt:
        for ref in refs:
            try:
                ray.cancel(ref, force=True)
            except Exception:
                pass
        say(f"interrupted: {len(refs)} unfinished cell(s) keep their newest checkpoints; the same command resumes "
            "them")
        raise
    finally:
        if bar is not None:
            bar.close()
        try:
            os.remove(marker)
        except OSError:
            pass
        if started_here:
            ray.shutdown()
    return results
