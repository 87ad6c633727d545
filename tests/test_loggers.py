"""``--log tensorboard`` / ``--log wandb``: a run's metrics beyond the progress bar (issue 34, item 5).

- ``--log tensorboard`` writes event files in the run folder whose scalars (``seedS/column``, ``mean/column`` at
  x = episodes per seed) are metrics.csv's values; read back here with our own TFRecord reader (CRCs checked).
- A resumed run continues the same stream without a step twice: after a stop, after a fallback to an older
  checkpoint (its rounds trained again), after a kill that lost the last events (filled in from metrics.csv), and
  when the stream is turned on mid-run (``--resume RUN --log tensorboard``).
- ``--workers``: each worker folder has its own stream of its seeds.
- W&B (a fake ``wandb`` module): offline by default, in the run folder, one W&B run id across resumes.
- A missing library is a one-line error naming the extra, before anything is written.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import struct
import sys
import types

import numpy as np
import pytest

from jaxmac.cli import main
from jaxmac.presets import scenario_config
from jaxmac.runs import read_meta, resume_run, train_run
from jaxmac.runs import workers as run_workers
from jaxmac.runs.loggers import LoggerUnavailable, WandbLogger

tensorboardX = pytest.importorskip("tensorboardX")
from tensorboardX.proto.event_pb2 import Event
from tensorboardX.record_writer import masked_crc32c

# 6 rounds of 8 episodes per seed; rounds_per_chunk=2: 3 chunks, a checkpoint (and its rows logged) after each
CONFIG = scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(
    horizon=20, episodes=48, num_envs=8, eval_every_episodes=16, eval_episodes=2)
STEPS = [8, 16, 24, 32, 40, 48]


def _train(out, **kw):
    return train_run(CONFIG, 2, str(out), rounds_per_chunk=2, progress=False, checkpoint_seconds=0.0, **kw)


# --- reading the event files back ------------------------------------------------------------------------------------

def _event_files(folder):
    return sorted(n for n in os.listdir(folder) if n.startswith("events.out.tfevents."))


def _read_records(path):
    """The records of a TFRecord file (length, masked CRC of the length, data, masked CRC of the data), CRCs
    checked; a torn last record ends them."""
    with open(path, "rb") as f:
        data = f.read()
    pos, out = 0, []
    while pos + 12 <= len(data):
        header = data[pos:pos + 8]
        (length,) = struct.unpack("<Q", header)
        assert struct.unpack("<I", data[pos + 8:pos + 12])[0] == masked_crc32c(header)
        if pos + 12 + length + 4 > len(data):
            break
        body = data[pos + 12:pos + 12 + length]
        assert struct.unpack("<I", data[pos + 12 + length:pos + 16 + length])[0] == masked_crc32c(body)
        out.append(body)
        pos += 16 + length
    return out


def read_scalars(folder):
    """{(tag, step): value} of every scalar in the event files of ``folder``; no (tag, step) twice."""
    out = {}
    for name in _event_files(folder):
        for record in _read_records(os.path.join(folder, name)):
            event = Event()
            event.ParseFromString(record)
            for value in event.summary.value:
                key = (value.tag, int(event.step))
                assert key not in out, f"{key} logged twice"
                out[key] = value.simple_value
    return out


def expected_scalars(metrics_path):
    """What the stream of a run must hold by its metrics.csv: every finite value per seed, and the mean over seeds."""
    with open(metrics_path, newline="") as f:
        rows = list(csv.DictReader(f))
    out, by_step = {}, {}
    for row in rows:
        step = int(row["episodes"])
        for column, text in row.items():
            if column in ("seed", "round", "episodes") or not math.isfinite(float(text)):
                continue
            out[(f"seed{row['seed']}/{column}", step)] = float(text)
            by_step.setdefault((column, step), []).append(float(text))
    for (column, step), values in by_step.items():
        out[(f"mean/{column}", step)] = float(np.mean(values))
    return out


def _assert_stream_is_the_metrics(folder):
    scalars, expected = read_scalars(folder), expected_scalars(os.path.join(folder, "metrics.csv"))
    assert set(scalars) == set(expected)
    for key, value in expected.items():  # event files hold float32
        assert scalars[key] == pytest.approx(np.float32(value), rel=1e-6, abs=1e-6), key
    return scalars


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run logging to TensorBoard, and its stream."""
    out = tmp_path_factory.mktemp("reference") / "run"
    _train(out, log="tensorboard")
    return out, read_scalars(out)


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """A run logging to TensorBoard, stopped (as if killed) after 2 of its 3 chunks."""
    out = tmp_path_factory.mktemp("killed") / "run"
    assert _train(out, log="tensorboard", stop_after_chunks=2) is None
    return out


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


# --- TensorBoard ---------------------------------------------------------------------------------------------------

def test_tensorboard_event_files_hold_the_metrics_csv_values_per_seed_and_their_mean(reference):
    out, scalars = reference
    assert _event_files(out)
    assert read_meta(str(out))["log"] == "tensorboard"  # a resume goes on logging
    _assert_stream_is_the_metrics(out)
    assert sorted({step for _, step in scalars}) == STEPS
    evaluated = sorted(step for tag, step in scalars if tag == "mean/eval_disc_return")
    assert evaluated and len(evaluated) < len(STEPS)  # NaN (no evaluation that round) is left out
    assert {"seed0/loss", "seed1/loss", "mean/loss", "seed0/epsilon", "mean/train_return"} <= {t for t, _ in scalars}


def test_a_resumed_run_continues_the_stream_without_a_step_twice(tmp_path, killed, reference):
    out = _copy(killed, tmp_path / "run")
    assert sorted({step for _, step in read_scalars(out)}) == STEPS[:4]  # the checkpointed rows only
    resume_run(str(out), progress=False, checkpoint_seconds=0.0)
    assert len(_event_files(out)) == 2  # one file per process that logged, read as one stream
    assert read_scalars(out) == reference[1]


def test_after_a_fallback_to_an_older_checkpoint_its_rounds_are_not_logged_again(tmp_path, killed, reference, capfd):
    out = _copy(killed, tmp_path / "run")
    data = out / "checkpoints" / "2" / "default" / "ocdbt.process_0" / "d"
    for name in os.listdir(data):  # the newest checkpoint damaged: the resume trains chunk 2 again
        os.truncate(data / name, 10)
    resume_run(str(out), progress=False, checkpoint_seconds=0.0)
    assert "resuming from checkpoint 1" in capfd.readouterr().err
    assert read_scalars(out) == reference[1]


def test_events_a_kill_lost_are_filled_in_from_the_metrics_on_resume(tmp_path, killed, reference):
    out = _copy(killed, tmp_path / "run")
    (name,) = _event_files(out)
    size = os.path.getsize(out / name)
    last = len(_read_records(out / name)[-1]) + 16
    os.truncate(out / name, size - last // 2)  # the last step's event torn mid-write
    assert max(step for _, step in read_scalars(out)) == 24
    resume_run(str(out), progress=False, checkpoint_seconds=0.0)
    assert read_scalars(out) == reference[1]


def test_a_stream_turned_on_at_resume_starts_with_the_rows_trained_so_far(tmp_path, reference, capsys):
    out = tmp_path / "run"
    assert _train(out, stop_after_chunks=1) is None
    assert not _event_files(out) and "log" not in read_meta(str(out))
    assert main(["train", "--resume", str(out), "--log", "tensorboard", "--no-progress",
                 "--checkpoint-every", "0"]) == 0
    assert read_meta(str(out))["log"] == "tensorboard"
    assert read_scalars(out) == reference[1]
    # and off again: the run's config.json no longer names a logger
    assert main(["train", "--resume", str(out), "--log", "none", "--episodes", "64", "--no-progress"]) == 0
    assert "log" not in read_meta(str(out)) and read_scalars(out) == reference[1]


def test_each_worker_logs_its_seeds_to_its_own_stream(tmp_path, monkeypatch):
    def in_process(out_dir, jobs, resume, progress, total_episodes, checkpoint_seconds=120.0):
        for d in jobs:  # the workers' entry point, in this process (as `python -m jaxmac.runs.workers` runs it)
            assert run_workers._main([d, "--checkpoint-every", "0"] + (["--resume"] if resume else [])) == 0
        return run_workers.merge(out_dir, jobs, 0.0)

    monkeypatch.setattr(run_workers, "_run_and_merge", in_process)
    out = tmp_path / "run"
    run_workers.train_workers(CONFIG, 4, str(out), 2, progress=False, log="tensorboard")
    assert read_meta(str(out))["log"] == "tensorboard"
    for k, seeds in ((0, {"seed0", "seed1"}), (1, {"seed2", "seed3"})):
        folder = out / f"worker{k}"
        assert read_meta(str(folder))["log"] == "tensorboard"
        scalars = _assert_stream_is_the_metrics(folder)
        assert {tag.split("/")[0] for tag, _ in scalars} == seeds | {"mean"}
    assert not _event_files(out)  # the merged folder: the curve and metrics.csv, no stream of its own
    # --resume --log none: every folder's record of it changes; the streams stay as they were
    run_workers.resume_workers(str(out), progress=False, episodes=64, log="none")
    for folder in (out, out / "worker0", out / "worker1"):
        assert "log" not in read_meta(str(folder))
    for k in (0, 1):
        assert "log" not in json.loads((out / f"worker{k}" / "job.json").read_text())
        assert max(step for _, step in read_scalars(out / f"worker{k}")) == 48
        assert expected_scalars(out / f"worker{k}" / "metrics.csv")[(f"seed{2 * k}/epsilon", 64)] >= 0


# --- W&B (a fake wandb module) --------------------------------------------------------------------------------------

class _FakeRun:
    def __init__(self, kw):
        self.kw, self.logged, self.finished = kw, [], False

    def log(self, values, step):
        self.logged.append((step, dict(values)))

    def finish(self):
        self.finished = True


@pytest.fixture
def fake_wandb(monkeypatch):
    runs = []
    module = types.ModuleType("wandb")
    module.init = lambda **kw: runs.append(_FakeRun(kw)) or runs[-1]
    monkeypatch.setitem(sys.modules, "wandb", module)
    monkeypatch.delenv("WANDB_MODE", raising=False)
    return runs


def test_wandb_logs_offline_into_the_run_folder_and_a_resume_goes_on_in_the_same_run(tmp_path, fake_wandb):
    out = tmp_path / "run"
    assert _train(out, log="wandb", stop_after_chunks=2) is None
    meta = read_meta(str(out))
    assert meta["log"] == "wandb" and isinstance(meta["wandb_id"], str)
    (first,) = fake_wandb
    assert first.kw["mode"] == "offline" and first.kw["dir"] == str(out)
    assert first.kw["id"] == meta["wandb_id"] and first.kw["resume"] == "allow"
    assert first.kw["config"]["algorithm"] == "maccen_ddrqn" and first.finished
    assert [step for step, _ in first.logged] == STEPS[:4]
    resume_run(str(out), progress=False, checkpoint_seconds=0.0)
    second = fake_wandb[1]
    assert second.kw["id"] == meta["wandb_id"] and [step for step, _ in second.logged] == STEPS[4:]
    logged = {(tag, step): v for run in fake_wandb for step, values in run.logged for tag, v in values.items()}
    expected = expected_scalars(out / "metrics.csv")
    assert set(logged) == set(expected)
    assert all(logged[k] == pytest.approx(v, rel=1e-12) for k, v in expected.items())


def test_wandb_mode_online_or_from_the_environment(tmp_path, fake_wandb, monkeypatch):
    row = {0: {"loss": 1.5, "eval_disc_return": math.nan}}
    meta = {"config": CONFIG.to_dict(), "seeds": 1, "seed_offset": 0, "wandb_id": "abc"}
    for online, env, mode in ((True, None, "online"), (False, "disabled", "disabled"), (False, None, "offline")):
        if env:
            monkeypatch.setenv("WANDB_MODE", env)
        else:
            monkeypatch.delenv("WANDB_MODE", raising=False)
        logger = WandbLogger(str(tmp_path / mode), meta, online=online)
        logger.log(row, 8)
        logger.close()
        assert fake_wandb[-1].kw["mode"] == mode
        assert fake_wandb[-1].logged == [(8, {"seed0/loss": 1.5, "mean/loss": 1.5})]
        assert json.loads((tmp_path / mode / "wandb" / "jaxmac-logged.json").read_text()) == {"last_step": 8}


# --- refused before anything is written -----------------------------------------------------------------------------

def test_a_missing_library_is_one_line_naming_the_extra_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # import tensorboardX raises ImportError
    monkeypatch.setitem(sys.modules, "wandb", None)
    with pytest.raises(LoggerUnavailable, match=r'pip install -e "\.\[tensorboard\]"'):
        _train(tmp_path / "a", log="tensorboard")
    assert not (tmp_path / "a").exists()
    assert main(["train", "--tiny", "--episodes", "16", "--no-progress", "--log", "wandb",
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("jaxmac: --log wandb needs wandb")
    assert 'pip install -e ".[wandb]"' in err and not (tmp_path / "b").exists()


def test_a_new_run_into_a_folder_of_old_event_files_is_refused(tmp_path, reference):
    out = tmp_path / "run"
    out.mkdir()
    name = _event_files(reference[0])[0]
    shutil.copy(reference[0] / name, out / name)
    with pytest.raises(ValueError, match="holds TensorBoard event files"):
        _train(out, log="tensorboard")
    assert sorted(os.listdir(out)) == [name]
