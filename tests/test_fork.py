"""``jaxmac fork``: a new run from a checkpoint of another replays the source exactly when nothing changes, takes
settings that keep the state's shapes and another budget, records where it came from, and refuses (writing nothing)
what would not fit."""

from __future__ import annotations

import json

import pytest

from jaxmac.cli import main as cli_main
from jaxmac.presets import scenario_config
from jaxmac.runs import resume_run, train_run
from jaxmac.runs.fork import fork_run

CONFIG = scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(horizon=20, episodes=48, num_envs=8)


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """6 rounds of 8 episodes in chunks of 2 rounds, a checkpoint after every chunk (the newest two kept: 2, 3)."""
    out = tmp_path_factory.mktemp("fork") / "source"
    train_run(CONFIG, 2, str(out), rounds_per_chunk=2, progress=False, checkpoint_seconds=0.0)
    return out


def _rows(path):
    return (path / "metrics.csv").read_text().splitlines()


def test_a_fork_with_nothing_changed_replays_the_source_exactly(source, tmp_path):
    fork = tmp_path / "replay"
    meta = fork_run(str(source), str(fork), chunk=2)
    assert meta["forked_from"] == {"run": str(source.resolve()), "chunk": 2, "episodes": 32, "set": []}
    assert len(_rows(fork)) == 1 + 2 * 4  # the header, then 2 seeds x the 4 rounds chunk 2 covers
    summary = resume_run(str(fork), progress=False)
    assert _rows(fork) == _rows(source)  # every metric of the last chunk, evaluations included
    assert summary["final_greedy_return"] == json.loads((source / "summary.json").read_text())["final_greedy_return"]


def test_a_fork_takes_other_settings_and_a_budget_and_says_where_it_came_from(source, tmp_path, capsys):
    fork = tmp_path / "lower-lr"
    assert cli_main(["fork", str(source), "--out", str(fork), "--set", "lr=0.0001", "--episodes", "64"]) == 0
    assert "jaxmac train --resume" in capsys.readouterr().out
    meta = json.loads((fork / "config.json").read_text())
    assert meta["config"]["lr"] == 0.0001 and meta["config"]["episodes"] == 64
    assert meta["forked_from"]["chunk"] == 3 and meta["forked_from"]["set"] == ["lr=0.0001"]  # the newest by default
    assert resume_run(str(fork), progress=False)["episodes"] == 64
    assert _rows(fork)[:1 + 2 * 6] == _rows(source)  # the source's rows, then the fork's own
    assert len(_rows(fork)) == 1 + 2 * 8


@pytest.mark.parametrize("kwargs, message", [
    (dict(chunk=1), "keeps checkpoints after chunks 2, 3 only"),
    (dict(chunk=3), "has trained the whole budget of 48 episodes per seed: give --episodes above 48"),
    (dict(chunk=2, episodes=32), "episodes=32: the fork starts where chunk 2 of .* ends, at 32 episodes per seed"),
    (dict(chunk=2, episodes=40), "episodes=40 ends inside a chunk.*Give episodes=32 or 48"),
    (dict(assignments=["rnn_size=16"]), "changes the shapes of the training state"),
    # the shapes stay, but the checkpoint's chunks are rounds of 8 episodes: 16 would misnumber every episode after it
    (dict(chunk=2, episodes=128, assignments=["num_envs=16"]), "num_envs=16: the checkpoints of .* count rounds of "
                                                                "num_envs=8 episodes per seed"),
])
def test_what_would_not_fit_is_refused_and_nothing_written(source, tmp_path, kwargs, message):
    fork = tmp_path / "refused"
    with pytest.raises(ValueError, match=message):
        fork_run(str(source), str(fork), **kwargs)
    assert not fork.exists()


def test_a_fork_never_writes_into_a_run(source, tmp_path):
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text((source / "config.json").read_text())
    with pytest.raises(ValueError, match="already holds a run"):
        fork_run(str(source), str(other), chunk=2)
    assert sorted(p.name for p in other.iterdir()) == ["config.json"]
    with pytest.raises(ValueError, match="is the run being forked"):
        fork_run(str(source), str(source) + "/", chunk=2)
