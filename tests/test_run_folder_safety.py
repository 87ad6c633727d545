"""A run folder has one owner and its record survives crashes and refused commands (issue 32).

- A second training or resume of a folder in use is refused, naming the holder; the first run ends as an undisturbed
  one. A sweep cell whose holder died (or whose lock file is stale or empty) is taken over.
- A resume after a damaged newest checkpoint, or a metrics.csv cut mid-line, ends with the metrics of an
  uninterrupted run.
- A command that is refused leaves the run's files byte for byte as they were (resume without a checkpoint, --out
  into a folder of a run's files, a --set that does not fit the checkpoint).
- Every expected failure is one line on stderr, never a traceback.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

from jaxmac.cli import main
from jaxmac.presets import scenario_config
from jaxmac.runs import (LOCK_FILE, RunFolderBusy, live_holder, load_run, lock_run_folder, resume_run,
                         train_run)
from jaxmac.runs import loop as run_loop

CONFIG = scenario_config("boxpushing-6x6", tiny=True).override(
    horizon=20, episodes=48, num_envs=8, batch_size=8, buffer_episodes=16, eval_every_episodes=16, eval_episodes=2,
    target_update_episodes=16, eps_decay_episodes=16)
# CONFIG on the command line (two chunks of two rounds: the same programs as the tests' rounds_per_chunk=2)
CLI_CONFIG = ["--tiny", "--episodes", "48", "--seeds", "2", "--no-progress"] + [
    a for kv in ("horizon=20", "num_envs=8", "batch_size=8", "buffer_episodes=16", "eval_every_episodes=16",
                 "eval_episodes=2", "target_update_episodes=16", "eps_decay_episodes=16") for a in ("--set", kv)]


def _train(out, **kw):
    return train_run(CONFIG, 2, str(out), rounds_per_chunk=2, progress=False, **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run."""
    out = tmp_path_factory.mktemp("reference") / "run"
    summary = _train(out)
    return out, summary


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """A run killed after 2 of its 3 chunks, checkpointed after each (checkpoints 1 and 2, rows of rounds 0-3)."""
    out = tmp_path_factory.mktemp("killed") / "run"
    assert _train(out, checkpoint_seconds=0.0, stop_after_chunks=2) is None
    return out


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


def _files(folder) -> dict[str, bytes]:
    """Every file under ``folder`` (and every folder, as None), by relative path."""
    out = {}
    for root, dirs, names in os.walk(folder):
        for name in dirs:
            out[os.path.relpath(os.path.join(root, name), folder)] = None
        for name in names:
            with open(os.path.join(root, name), "rb") as f:
                out[os.path.relpath(os.path.join(root, name), folder)] = f.read()
    return out


def _read(path) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def _same_run(out, reference, summary=None):
    ref, ref_summary = reference
    assert _read(out / "metrics.csv") == _read(ref / "metrics.csv")
    assert json.loads(_read(out / "config.json")) == json.loads(_read(ref / "config.json"))
    if summary is not None:
        for key in ("final_greedy_return", "final_greedy_return_undiscounted", "episodes"):
            assert summary[key] == ref_summary[key], key


def _one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


def _cli(*args):
    """``jaxmac ARGS`` in a new process (the run this test trains holds the folder)."""
    return subprocess.run([sys.executable, "-m", "jaxmac.cli", *args], capture_output=True, text=True, timeout=120)


def _when_the_first_chunk_is_done(monkeypatch, action):
    """Run ``action`` once, while the run trains (after its first chunk)."""
    real, seen = run_loop.check_finite, []

    def hook(*args):
        if not seen:
            seen.append(action())
        return real(*args)

    monkeypatch.setattr(run_loop, "check_finite", hook)
    return seen


# --- one owner ------------------------------------------------------------------------------------------------------

def test_a_second_training_into_a_folder_in_use_is_refused_and_the_first_run_is_undisturbed(
        tmp_path, monkeypatch, reference):
    out = tmp_path / "run"
    second = _when_the_first_chunk_is_done(
        monkeypatch, lambda: _cli("train", *CLI_CONFIG, "--set", "lr=0.0005", "--out", str(out)))
    summary = _train(out)
    assert second[0].returncode == 2
    line = _one_line(second[0].stderr)
    assert f"{out} is in use by jaxmac train (pid {os.getpid()} on host" in line
    _same_run(out, reference, summary)
    assert not (out / LOCK_FILE).exists()  # released (and removed) when the run ended


def test_concurrent_resumes_are_refused_and_the_run_ends_as_an_uninterrupted_one(
        tmp_path, monkeypatch, killed, reference):
    out = _copy(killed, tmp_path / "run")
    second = _when_the_first_chunk_is_done(monkeypatch, lambda: _cli("train", "--resume", str(out), "--no-progress"))
    summary = resume_run(str(out), progress=False)
    assert second[0].returncode == 2
    assert f"in use by jaxmac train --resume (pid {os.getpid()}" in _one_line(second[0].stderr)
    _same_run(out, reference, summary)


def test_a_lock_is_taken_over_when_its_holder_dies_and_is_reentrant_in_its_process(tmp_path):
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time\nfrom jaxmac.runs import lock_run_folder\n"
        "lock = lock_run_folder(sys.argv[1])\nprint('locked', flush=True)\ntime.sleep(120)"), str(out)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RunFolderBusy, match=f"in use by jaxmac train \\(pid {holder.pid} on host"):
            lock_run_folder(str(out))
        assert live_holder(str(out))["pid"] == holder.pid  # what a sweep's dry run calls "running"
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (out / LOCK_FILE).exists()  # the dead holder's file stays, and blocks nothing
    assert live_holder(str(out)) is None
    elsewhere = dict(json.loads((out / LOCK_FILE).read_text()), pid=os.getpid(), host="another-host")
    (out / LOCK_FILE).write_text(json.dumps(elsewhere))
    assert live_holder(str(out)) is None  # another host's process cannot be looked at from here
    with lock_run_folder(str(out)) as first:
        with lock_run_folder(str(out)):  # the same process again: a sweep's cell, then the run inside it
            pass
        assert first and json.loads((out / LOCK_FILE).read_text())["pid"] == os.getpid()
    assert not (out / LOCK_FILE).exists()


def _fake_runs(monkeypatch, calls):
    """train_run / resume_run that only write the files a run folder would have."""
    import jaxmac.runs

    def train_run(config, seeds, out, seed_offset=0, **kw):
        with lock_run_folder(out):  # as the real one: the sweep's own lock is taken again
            meta = {"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset}
            (open(os.path.join(out, "config.json"), "w")).write(json.dumps(meta))
            open(os.path.join(out, "summary.json"), "w").write("{}")
            calls.append(("train", out))

    monkeypatch.setattr(jaxmac.runs, "train_run", train_run)  # where jaxmac.study.sweep looks them up
    monkeypatch.setattr(jaxmac.runs, "resume_run", lambda out, **kw: calls.append(("resume", out)))


def test_a_sweep_cell_is_left_to_a_live_holder_and_taken_over_when_it_died_or_its_lock_file_is_stale(
        tmp_path, monkeypatch):
    from jaxmac.runs import LOCK_FILE as LOCK
    from jaxmac.study.sweep import plan, run_sweep

    calls = []
    _fake_runs(monkeypatch, calls)
    cells = plan("ablation", "smoke", only="overcooked-B/")[:3]
    held, reused_pid, empty = (tmp_path / c.path for c in cells)
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time\nfrom jaxmac.study.sweep import claim_cell\n"
        "lock = claim_cell(sys.argv[1])\nprint('locked', flush=True)\ntime.sleep(120)"), str(held)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        # a lock file naming a live process that holds no lock (PIDs are reused), and the empty one a full disk left
        reused_pid.mkdir(parents=True)
        (reused_pid / LOCK).write_text(json.dumps({"host": os.uname().nodename, "pid": os.getppid()}))
        empty.mkdir(parents=True)
        (empty / LOCK).write_text("")
        done = run_sweep(cells, str(tmp_path), log=lambda *_: None)
        assert [done[c.path] for c in cells] == ["busy", "trained", "trained"]
        assert ("train", str(held)) not in calls
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert json.loads((held / LOCK).read_text())["pid"] == holder.pid  # the dead holder's lock file
    done = run_sweep(cells, str(tmp_path), log=lambda *_: None)
    assert [done[c.path] for c in cells] == ["trained", "skipped", "skipped"]
    assert not any((tmp_path / c.path / LOCK).exists() for c in cells)


# --- crash-consistent files -----------------------------------------------------------------------------------------

def _damage(checkpoint):
    data = checkpoint / "default" / "ocdbt.process_0" / "d"
    for name in os.listdir(data):
        os.truncate(data / name, 10)


def test_a_damaged_newest_checkpoint_falls_back_to_the_older_one(tmp_path, killed, reference, capfd):
    out = _copy(killed, tmp_path / "run")
    _damage(out / "checkpoints" / "2")
    (out / "checkpoints" / "3.orbax-checkpoint-tmp-1700000000").mkdir()  # a save a crash interrupted
    _, _, chunks, _ = load_run(str(out))  # what jaxmac eval shows
    assert chunks == 1
    err = capfd.readouterr().err
    assert "checkpoint 2 cannot be restored" in err and "using checkpoint 1" in err
    assert len(err.strip().splitlines()) == 2 and "Traceback" not in err
    summary = resume_run(str(out), progress=False)
    err = capfd.readouterr().err
    assert "checkpoint 2 cannot be restored" in err and "resuming from checkpoint 1" in err
    _same_run(out, reference, summary)
    assert "3" in os.listdir(out / "checkpoints") and not any("tmp" in n for n in os.listdir(out / "checkpoints"))


@pytest.mark.parametrize("cut", ["in the rows of the newest checkpoint", "after the rows of the newest checkpoint"])
def test_a_metrics_file_cut_mid_line_resumes_to_the_uninterrupted_metrics(tmp_path, killed, reference, cut):
    out = _copy(killed, tmp_path / "run")
    data = _read(out / "metrics.csv")
    if cut.startswith("in"):  # the last row (seed 1, round 3) half written: checkpoint 2 lacks it, 1 is used
        data = data[:len(data) - len(data.splitlines(keepends=True)[-1]) // 2]
    else:  # a crash while appending the rows of the next chunk
        data += b"0,4,40,0.5,-1"
    (out / "metrics.csv").write_bytes(data)
    summary = resume_run(str(out), progress=False)
    _same_run(out, reference, summary)


# --- a refused command changes nothing ------------------------------------------------------------------------------

def _refused(out, command, match):
    """``command`` (a ``jaxmac`` command line) fails with one line matching ``match``, leaving ``out`` as it was."""
    before = _files(out)
    result = _cli(*command)
    assert result.returncode == 2, result.stderr
    assert match in _one_line(result.stderr)
    assert _files(out) == before


def test_a_metrics_file_cut_midway_is_refused_not_resumed_with_rounds_lost(tmp_path, killed):
    out = _copy(killed, tmp_path / "run")
    lines = _read(out / "metrics.csv").splitlines(keepends=True)
    (out / "metrics.csv").write_bytes(b"".join(lines[:2]) + lines[2][:5])  # seed 0 round 0, then cut
    _refused(out, ["train", "--resume", str(out)], "has no checkpoint to resume from (checkpoint 2 is not matched "
                                                   "by metrics.csv")


def test_resuming_a_finished_run_without_checkpoints_is_refused(tmp_path, reference):
    out = _copy(reference[0], tmp_path / "run")
    shutil.rmtree(out / "checkpoints")
    _refused(out, ["train", "--resume", str(out), "--episodes", "64"],
             "has no checkpoint to resume from (checkpoints/ is missing) but holds a record (12 rows of metrics.csv, "
             "summary.json")


def test_a_run_killed_before_its_first_checkpoint_starts_over(tmp_path, reference):
    out = tmp_path / "run"
    out.mkdir()
    shutil.copy(reference[0] / "config.json", out / "config.json")
    summary = resume_run(str(out), progress=False)
    _same_run(out, reference, summary)


def test_out_into_a_folder_of_a_runs_files_is_refused(tmp_path, killed):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "metrics.csv").write_text("seed,round,episodes\n0,0,8\n")
    _refused(foreign, ["train", *CLI_CONFIG, "--out", str(foreign)], "holds files of a run (metrics.csv) but no "
                                                                     "config.json")
    lost = _copy(killed, tmp_path / "lost")
    os.remove(lost / "config.json")
    _refused(lost, ["train", *CLI_CONFIG, "--out", str(lost)],
             "holds files of a run (checkpoints, metrics.csv, progress.json) but no config.json")
    _refused(killed, ["train", *CLI_CONFIG, "--out", str(killed)], "already holds a run; use resume")


def test_a_set_that_does_not_fit_the_checkpoint_of_a_diverged_run_changes_nothing(tmp_path, killed):
    out = _copy(killed, tmp_path / "run")
    (out / "diverged.json").write_text(json.dumps({"problem": "seed 0, round 4: loss = nan", "kind": "non-finite",
                                                   "chunk": 2, "last_good_checkpoint": 2}))
    _refused(out, ["train", "--resume", str(out), "--set", "rnn_size=16"],
             "--set rnn_size=16 changes the shapes of the training state")


# --- one line, never a traceback ------------------------------------------------------------------------------------

def _broken_config(text):
    def make(tmp_path):
        (tmp_path / "run").mkdir()
        (tmp_path / "run" / "config.json").write_text(text)
        return ["train", "--resume", str(tmp_path / "run")]
    return make


def _no_checkpoint(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text(json.dumps({
        "config": CONFIG.to_dict(), "seeds": 2, "seed_offset": 0, "rounds_per_chunk": 2}))
    return ["eval", str(tmp_path / "run")]


def _existing_file(tmp_path):
    (tmp_path / "file").write_text("x")
    return ["train", "--tiny", "--out", str(tmp_path / "file")]


CASES = {
    "grad_clip=nan": (lambda p: ["train", "--tiny", "--set", "grad_clip=nan", "--out", str(p / "r")],
                      "grad_clip=nan must be a finite number"),
    "macro_loss_weight=nan": (lambda p: ["train", "--tiny", "--set", "macro_loss_weight=nan", "--out", str(p / "r")],
                              "macro_loss_weight=nan must be a finite number"),
    "--out /proc/x": (lambda p: ["train", "--tiny", "--out", "/proc/jaxmac-test/x"],
                      "cannot create /proc/jaxmac-test/x: No such file or directory; choose a writable --out"),
    "--out an existing file": (_existing_file, "is an existing file, not a run folder: choose another --out"),
    "config.json of {}": (_broken_config("{}"), "config.json is not a jaxmac run's config"),
    "config.json of garbage": (_broken_config("\x00garbage{"), "config.json is broken (not valid JSON"),
    "eval without a checkpoint": (_no_checkpoint, "has no checkpoint (none saved yet, or none that restores)"),
    "num_envs over the budget": (
        lambda p: ["train", "--tiny", "--episodes", "64", "--set", "num_envs=100000", "--set",
                   "buffer_episodes=100000", "--set", "target_update_episodes=0", "--out", str(p / "r")],
        "episodes=64 is less than one round of num_envs=100000 episodes"),
    "sizes beyond the memory": (
        lambda p: ["train", "--tiny", "--set", "batch_size=1000000000", "--set", "buffer_episodes=1000000000",
                   "--out", str(p / "r")],
        "GiB (training state"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_an_expected_failure_is_one_line_naming_what_to_fix(tmp_path, capsys, case):
    make, match = CASES[case]
    command = make(tmp_path)
    assert main(command) == 2
    out, err = capsys.readouterr()
    line = _one_line(err)
    assert line.startswith("jaxmac: ") and match in line, line
    assert not (tmp_path / "r").exists()  # a refused new run leaves no folder behind


def test_a_full_disk_while_writing_the_metrics_is_one_line_and_the_run_resumes(tmp_path, capsys, monkeypatch,
                                                                              reference):
    out = tmp_path / "run"
    real_fsync = os.fsync

    def disk_full_for_metrics(fd):
        if os.readlink(f"/proc/self/fd/{fd}").endswith("metrics.csv"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", disk_full_for_metrics)
    assert main(["train", *CLI_CONFIG, "--checkpoint-every", "0", "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"cannot write {out / 'metrics.csv'}: No space left on device;" in line and "--resume" in line
    assert not (out / "metrics.csv").exists()  # the failed append is cut off: no rows without their checkpoint
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    _same_run(out, reference)


def _npz_cut_in_half() -> bytes:
    import io

    import numpy as np

    buffer = io.BytesIO()
    np.savez(buffer, obs=np.arange(1000), reward=np.ones(100))
    return buffer.getvalue()[:len(buffer.getvalue()) // 2]


@pytest.mark.parametrize("content", [b"", "truncated", b"seed,round\n0,1\n"], ids=["empty", "truncated .npz", "text"])
def test_a_bad_trace_file_is_one_line_naming_it(tmp_path, capsys, content):
    from envs_jax.conformance.__main__ import main as conformance

    path = tmp_path / "trace.npz"
    path.write_bytes(_npz_cut_in_half() if content == "truncated" else content)
    assert conformance([str(path)]) == 1
    out, err = capsys.readouterr()
    assert err == "" and "Traceback" not in out
    assert out.splitlines()[0].startswith(f"ERROR {path}: {path} is not a readable .npz trace file")
    assert "pickle" not in out and len(out.splitlines()) == 2  # that line and the total
