"""Sweeps on a Ray cluster (issue 35), on a real local Ray instance (2 CPUs, started once for the module).

- A smoke sweep of 3 cells through Ray ends with the summaries and metrics of the same cells run without Ray; a cell
  with a bad setting fails once, with its message, and the others finish; each cell's attempts.jsonl says it ran
  under Ray (executor, node id).
- A Ray worker killed in the middle of a cell (after its first checkpoint) is retried by Ray: the cell resumes from
  its checkpoint and its metrics.csv equals an uninterrupted run's.
- Interrupting the driver (Ctrl-C) cancels the cell's task; the same call resumes it from its checkpoint.
- Without a shared filesystem a cell trains in the node's scratch folder and its files come back to the driver.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
import ray

from jaxmac.cli import main
from jaxmac.runs import DIVERGED_FILE, lock_holder
from jaxmac.study.cluster import RETURNED_FILES, run_sweep_ray
from jaxmac.study.sweep import ATTEMPTS_FILE, Cell, Method, plan, run_sweep

# three smoke cells of two programs: ToMacVF and tuned ToMacVF on Box Pushing 6x6, and ToMacVF's seed 1
CELLS = (plan("bp", "smoke", only="boxpushing-6x6/tomacvf")
         + plan("bp", "smoke", seeds=(1, 1), only="boxpushing-6x6/tomacvf/"))
# fails in its task (a round of 64 episodes > the budget of 32: train_run's check), and before any task (the
# configuration itself is refused: a target period shorter than a round)
FAILS_IN_TASK = Cell("bp", Method("tomacvf-bad", "tomacvf", (("num_envs", 64), ("target_update_episodes", 0))),
                     "boxpushing-6x6", 0, 1, 32, tiny=True)
REFUSED = Cell("bp", Method("tomacvf-refused", "tomacvf", (("num_envs", 64),)), "boxpushing-6x6", 0, 1, 32, tiny=True)
# ten chunks (checkpointed after each), so that a worker can be killed between two
LONG = dataclasses.replace(CELLS[0], episodes=320)
SUMMARY_KEYS = ("final_greedy_return", "final_greedy_return_undiscounted", "episodes", "seeds", "seed_offset")


@pytest.fixture(scope="module", autouse=True)
def ray_instance():
    """A real local Ray instance for the module (the workers get the suite's XLA flags and compilation cache from
    ``jaxmac.study.cluster.worker_env``)."""
    ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=80 * 2 ** 20)
    yield
    ray.shutdown()


def _quiet(*_):
    pass


@pytest.fixture(scope="module")
def without_ray(tmp_path_factory):
    """The cells run as an embedded sweep (this process, no Ray)."""
    out = tmp_path_factory.mktemp("embedded")
    done = run_sweep(list(CELLS), str(out / "smoke"), progress=False, log=_quiet)
    done.update(run_sweep([LONG], str(out / "long"), progress=False, log=_quiet))  # LONG's path is CELLS[0]'s
    assert set(done.values()) == {"trained"}
    return out


def _read(path) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def _summary(folder) -> dict:
    summary = json.loads(_read(os.path.join(folder, "summary.json")))
    return {k: summary[k] for k in SUMMARY_KEYS}


def _attempts(folder) -> list[dict]:
    return [json.loads(line) for line in _read(os.path.join(folder, ATTEMPTS_FILE)).decode().splitlines()]


def _same_cell(folder, reference):
    assert _summary(folder) == _summary(reference)
    assert _read(os.path.join(folder, "metrics.csv")) == _read(os.path.join(reference, "metrics.csv"))


def test_a_smoke_sweep_on_ray_equals_the_same_cells_without_ray_and_a_bad_cell_fails_once(tmp_path, without_ray,
                                                                                        capsys):
    lines = []
    cells = list(CELLS) + [FAILS_IN_TASK, REFUSED]
    start = time.perf_counter()
    done = run_sweep_ray(cells, str(tmp_path), progress=False, log=lines.append)
    seconds = time.perf_counter() - start
    assert [done[c.path] for c in CELLS] == ["trained"] * 3, (done, lines)
    node = ray.get_runtime_context().get_node_id()
    for cell in CELLS:
        _same_cell(tmp_path / cell.path, without_ray / "smoke" / cell.path)
        (attempt,) = _attempts(tmp_path / cell.path)  # where and how it ran
        assert (attempt["executor"], attempt["node_id"], attempt["action"]) == ("ray", node, "train")
        assert attempt["pid"] != os.getpid() and attempt["devices"] == ["cpu:0"] and attempt["jax"]
        assert _attempts(without_ray / "smoke" / cell.path)[0]["executor"] == "embedded"
    # the bad cells: failed once each, with their own message, not retried
    assert done[FAILS_IN_TASK.path] == ("failed: ValueError: episodes=32 is less than one round of num_envs=64 "
                                        "episodes: the run would train 64 episodes per seed, 2x its budget. Lower "
                                        "num_envs to at most 32, or raise episodes")
    assert len(_attempts(tmp_path / FAILS_IN_TASK.path)) == 1
    assert done[REFUSED.path].startswith("failed: ValueError: target_update_episodes=16 <= num_envs=64")
    for cell in (FAILS_IN_TASK, REFUSED):
        assert [line for line in lines if line.startswith(cell.path)] == [f"{cell.path}: {done[cell.path]}"]
    # a line per finished cell, naming where it ran
    for cell in CELLS:
        assert sum(line.startswith(f"{cell.path}: trained on ") for line in lines) == 1, lines
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".ray-driver")]  # the marker is gone
    print(f"3 smoke cells through Ray: {seconds:.0f} s")

    # the same command again (the CLI): the finished cells are skipped, the bad ones fail again, nothing else runs
    capsys.readouterr()
    assert main(["sweep", "bp", "--protocol", "smoke", "--only", "boxpushing-6x6/tomacvf", "--out", str(tmp_path),
                 "--cluster", "ray", "--no-progress"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == "2 of 2 cells finished"


def _ancestors(pid: int) -> list[int]:
    out = []
    while pid > 1:
        with open(f"/proc/{pid}/stat") as f:
            pid = int(f.read().rsplit(")", 1)[1].split()[1])
        out.append(pid)
    return out


def _a_ray_worker_of_ours(pid: int) -> bool:
    """``pid`` is a Ray worker process (``ray::<task>``) that this test process's Ray instance started."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            command = f.read()
        return command.startswith(b"ray::") and os.getpid() in _ancestors(pid)
    except (OSError, ValueError):
        return False


def _pause_the_worker_after_its_first_checkpoint(folder, stop: threading.Event) -> tuple[int, int] | None:
    """SIGSTOP the Ray worker training ``folder`` (its pid: the cell's lock file, written by the task) once the cell
    has saved its first checkpoint; returns (pid, chunks done), the worker left stopped, or None when ``stop`` is set
    first. The worker runs in slices of ~20 ms between two looks, so it cannot finish the cell between the look that
    sees the first checkpoint and the stop, however loaded the machine (it is stopped while we look)."""
    while not stop.is_set():
        holder = lock_holder(str(folder))
        pid = holder.get("pid", -1) if holder else -1
        if not _a_ray_worker_of_ours(pid):
            time.sleep(0.01)
            continue
        try:
            os.kill(pid, signal.SIGSTOP)
        except ProcessLookupError:  # ended between the look at the lock and the signal
            continue
        try:
            chunks = json.loads(_read(os.path.join(folder, "progress.json")))["chunks_done"]
        except (OSError, ValueError, KeyError):
            chunks = 0
        if chunks >= 1:
            return pid, chunks
        os.kill(pid, signal.SIGCONT)
        time.sleep(0.02)
    return None


def _kill_after_the_first_checkpoint(folder, killed: list, stop: threading.Event) -> None:
    """SIGKILL the Ray worker training ``folder`` once the cell has saved its first checkpoint."""
    paused = _pause_the_worker_after_its_first_checkpoint(folder, stop)
    if paused:
        os.kill(paused[0], signal.SIGKILL)
        killed.append(paused)


def test_a_worker_killed_mid_cell_is_retried_and_the_cell_resumes_to_an_uninterrupted_runs_metrics(
        tmp_path, without_ray):
    folder = tmp_path / LONG.path
    killed, stop = [], threading.Event()
    killer = threading.Thread(target=_kill_after_the_first_checkpoint, args=(folder, killed, stop), daemon=True)
    killer.start()
    try:
        done = run_sweep_ray([LONG], str(tmp_path), progress=False, log=_quiet, checkpoint_seconds=0.0)
    finally:
        stop.set()
        killer.join()
    assert killed, "the cell finished before its worker could be killed"
    pid, chunks_seen = killed[0]
    assert done == {LONG.path: "resumed"}
    first, second = _attempts(folder)
    assert (first["action"], first["pid"], first["executor"]) == ("train", pid, "ray")
    assert (second["action"], second["executor"]) == ("resume", "ray") and second["pid"] != pid
    assert chunks_seen <= second["from_chunk"] <= 10  # resumed from its newest checkpoint, not from the start
    _same_cell(folder, without_ray / "long" / LONG.path)
    print(f"killed worker {pid} after checkpoint {chunks_seen} of 10; resumed from chunk {second['from_chunk']}")


def test_interrupting_the_driver_cancels_the_cell_and_the_same_call_resumes_it(tmp_path, without_ray):
    import _thread

    from jaxmac.study.sweep import cell_status

    folder = tmp_path / LONG.path
    stop, paused, lines = threading.Event(), [], []

    def ctrl_c_after_the_first_checkpoint():
        found = _pause_the_worker_after_its_first_checkpoint(folder, stop)
        if found:
            paused.append(found)
            _thread.interrupt_main()  # as Ctrl-C: KeyboardInterrupt in the driver's loop

    def log(line):
        lines.append(line)
        if line.startswith("interrupted") and paused:  # the driver has cancelled the task: let the worker see it
            os.kill(paused[0][0], signal.SIGCONT)

    interrupter = threading.Thread(target=ctrl_c_after_the_first_checkpoint, daemon=True)
    interrupter.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_sweep_ray([LONG], str(tmp_path), progress=False, log=log, checkpoint_seconds=0.0)
    finally:
        stop.set()
        interrupter.join()
    assert lines[-1] == ("interrupted: 1 unfinished cell(s) keep their newest checkpoints; the same command resumes "
                         "them")
    (attempt,) = _attempts(folder)
    deadline = time.monotonic() + 60
    while _a_ray_worker_of_ours(attempt["pid"]) and time.monotonic() < deadline:  # cancelled: its worker ends
        time.sleep(0.1)
    assert not _a_ray_worker_of_ours(attempt["pid"])
    assert cell_status(str(tmp_path), LONG) == "interrupted"
    assert run_sweep_ray([LONG], str(tmp_path), progress=False, log=_quiet) == {LONG.path: "resumed"}
    assert _attempts(folder)[1]["from_chunk"] >= 1
    _same_cell(folder, without_ray / "long" / LONG.path)


def test_the_eta_scales_the_measured_rates_by_the_finished_cells_durations():
    from jaxmac.study.cluster import _eta_seconds, _format_eta

    a, b, c = CELLS
    rates = {"tomacvf@boxpushing-6x6": {"episodes_per_s": 1.0}, "tomacvf-tuned@boxpushing-6x6": {"episodes_per_s": 2.0}}
    cells = {cell.path: cell for cell in CELLS}
    # a (32 s estimated) took 64 s: the others take twice their estimates too; c has run 10 s of its 64; 2 slots
    assert _eta_seconds([b], {c.path: 10.0}, cells, {a.path: 64.0}, rates, 2) == (32.0 + 54.0) / 2
    assert _eta_seconds([b], {}, cells, {}, {}, 2) is None  # nothing measured, nothing finished
    assert _eta_seconds([b, c], {}, cells, {a.path: 30.0}, {}, 1) == 60.0  # no rates: the finished cells' mean
    assert (_format_eta(None), _format_eta(61), _format_eta(3 * 3600 + 60)) == ("ETA ?", "ETA ~2 min", "ETA ~3:01 h")


def test_without_a_shared_filesystem_a_cells_files_come_back_to_the_driver(tmp_path, without_ray):
    out, scratch = tmp_path / "sweep", tmp_path / "scratch"
    cell = CELLS[0]
    done = run_sweep_ray([cell], str(out), progress=False, log=_quiet, shared=False, scratch=str(scratch))
    assert done == {cell.path: "trained"}
    # no checkpoints (they stay on the node), no diverged.json (it did not diverge)
    assert sorted(os.listdir(out / cell.path)) == sorted(set(RETURNED_FILES) - {DIVERGED_FILE})
    _same_cell(out / cell.path, without_ray / "smoke" / cell.path)
    (node_folder,) = [os.path.join(root, cell.path) for root in (scratch / d for d in os.listdir(scratch))]
    assert os.path.isdir(os.path.join(node_folder, "checkpoints"))
    assert _read(os.path.join(node_folder, "metrics.csv")) == _read(out / cell.path / "metrics.csv")
    assert _attempts(out / cell.path)[0]["executor"] == "ray"
    assert run_sweep_ray([cell], str(out), progress=False, log=_quiet, shared=False,
                         scratch=str(scratch)) == {cell.path: "skipped"}


@pytest.mark.parametrize("args, message", [
    (["--cluster", "ray", "--gpus-per-cell", "1", "--devices", "2"], "--devices 2 with --gpus-per-cell 1"),
    (["--cluster", "ray", "--cpus-per-cell", "0"], "--cpus-per-cell 0: give a number > 0"),
    (["--cluster", "ray", "--gpus-per-cell", "1"],
     "the local Ray instance has 2 CPUs, 0 GPUs; a cell asks for 1 CPU and 1 GPU per cell"),
    (["--ray-address", "auto"], "are options of --cluster ray"),
])
def test_ray_options_are_checked_before_anything_runs(tmp_path, capsys, args, message):
    assert main(["sweep", "bp", "--protocol", "smoke", "--only", "boxpushing-6x6/tomacvf/", "--out", str(tmp_path),
                 "--no-progress", *args]) == 2
    assert message in capsys.readouterr().err
    assert not os.listdir(tmp_path)


def test_the_embedded_sweep_does_not_import_ray():
    code = ("import sys, jaxmac.cli, jaxmac.study.sweep\njaxmac.cli.build_parser()\n"
            "assert 'ray' not in sys.modules, 'ray imported'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
