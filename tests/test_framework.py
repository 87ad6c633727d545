"""The shared run machinery every learner uses: every metric reaches metrics.csv, a diverging run stops with a message
naming seed, round and metric and keeps its last good checkpoint, and a diverged run continues with other settings."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxmac.presets import scenario_config
from jaxmac.runs import check_finite, resume_run, train_run
from jaxmac.runs import loop as run_loop
from jaxmac.trainer import default_rounds_per_chunk

CONFIG = scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(horizon=20, episodes=48, num_envs=8)


def test_check_finite_names_seed_round_and_metric():
    ok = {"round_updates": np.array([[0, 3], [0, 2]]), "loss": np.array([[np.nan, 1.0], [np.nan, 2.0]]),
          "grad_norm": np.array([[np.nan, 1.0], [np.nan, 1.0]]), "param_norm": np.ones((2, 2))}
    assert check_finite(ok, [5, 6], 10) is None  # NaN loss only where no gradient step ran
    bad = dict(ok, loss=np.array([[np.nan, 1.0], [np.nan, np.inf]]))
    assert check_finite(bad, [5, 6], 10) == "seed 6, round 11: loss = inf"
    bad = dict(ok, param_norm=np.array([[1.0, 1.0], [np.nan, 1.0]]))
    assert check_finite(bad, [5, 6], 10) == "seed 6, round 10: param_norm = nan"


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "cen"
    summary = train_run(CONFIG, 2, str(out), rounds_per_chunk=2, progress=False)
    return out, summary


def test_every_reported_metric_is_a_column(finished):
    out, summary = finished
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    columns = set(rows[0])
    for name in ("seed", "round", "episodes", "env_steps", "updates", "round_updates", "loss", "grad_norm",
                 "param_norm", "cen_loss", "cen_q_mean", "jert_entries", "eval_disc_return"):
        assert name in columns, name
    assert len(rows) == 2 * 48 // 8
    trained = [r for r in rows if float(r["round_updates"]) > 0]
    assert trained and all(np.isfinite(float(r["cen_loss"])) for r in trained)
    assert summary["algorithm"] == "maccen_ddrqn"


def test_a_run_trains_its_budget_rounded_up_to_a_round_only_and_says_so(tmp_path, capsys):
    """44 episodes at 8 a round: 6 rounds, said on stderr; the chunk (about one evaluation period, 4 rounds) is the
    divisor of 6 nearest it, 3, so the run ends at 48 episodes, not at two whole chunks of 4 rounds (64)."""
    config = CONFIG.override(episodes=44)
    assert default_rounds_per_chunk(config) == 3 and config.eval_every_episodes == 4 * config.num_envs
    summary = train_run(config, 1, str(tmp_path / "exact"), progress=False)
    assert "episodes=44 is not a multiple of num_envs=8" in capsys.readouterr().err
    assert summary["episodes"] == 48
    with open(tmp_path / "exact" / "metrics.csv", newline="") as f:
        assert [int(r["episodes"]) for r in csv.DictReader(f)] == [8, 16, 24, 32, 40, 48]


@settings(max_examples=200, deadline=None)
@given(episodes=st.integers(1, 200_000), num_envs=st.integers(1, 64), eval_every=st.integers(1, 5_000))
def test_the_default_chunk_divides_the_rounds_near_one_evaluation_period(episodes, num_envs, eval_every):
    config = CONFIG.override(episodes=max(episodes, num_envs), num_envs=num_envs, buffer_episodes=max(64, num_envs),
                             eval_every_episodes=eval_every)
    rounds = -(-config.episodes // num_envs)
    period = min(rounds, max(1, -(-max(eval_every, num_envs) // num_envs)))  # one evaluation period, in rounds
    chunk = default_rounds_per_chunk(config)
    assert rounds % chunk == 0 and 1 <= chunk <= 2 * period
    # no divisor of the rounds within twice the period is nearer to it (ratio-wise)
    distance = abs(np.log(chunk / period))
    assert not [n for n in range(1, 2 * period + 1) if rounds % n == 0 and abs(np.log(n / period)) < distance - 1e-12]


def test_a_budget_that_ends_inside_a_chunk_is_refused_naming_the_budgets_that_do_not(finished, tmp_path):
    out, _ = finished  # chunks of 2 rounds x 8 episodes
    with pytest.raises(ValueError, match="episodes=56 ends inside a chunk.*Give episodes=48 or 64"):
        resume_run(str(out), progress=False, episodes=56)
    assert json.loads((out / "config.json").read_text())["config"]["episodes"] == 48  # nothing changed
    with pytest.raises(ValueError, match="episodes=48 ends inside a chunk.*Give episodes=32 or 64"):
        train_run(CONFIG, 1, str(tmp_path / "chunks-of-4"), rounds_per_chunk=4, progress=False)
    assert not (tmp_path / "chunks-of-4").exists()


def test_a_raised_budget_of_partial_rounds_is_said_as_a_new_run_says_it(finished, tmp_path, capsys):
    import shutil

    from jaxmac.runs import extend_budget

    out = tmp_path / "copy"
    shutil.copytree(finished[0], out)  # chunks of 2 rounds x 8 episodes: 60 ends on one (8 rounds, 64 episodes)
    extend_budget(str(out), 60)
    assert "episodes=60 is not a multiple of num_envs=8" in capsys.readouterr().err
    assert json.loads((out / "config.json").read_text())["config"]["episodes"] == 60
    extend_budget(str(out), 64)  # whole rounds: nothing to say
    assert capsys.readouterr().err == ""


def test_a_diverging_run_stops_and_continues_with_other_settings(tmp_path, monkeypatch):
    out = tmp_path / "div"
    calls = {"n": 0}
    real = run_loop.check_finite

    def diverge_on_second_chunk(metrics, seed_ids, first_round):
        calls["n"] += 1
        return "seed 1, round 3: loss = nan" if calls["n"] == 2 else real(metrics, seed_ids, first_round)

    monkeypatch.setattr(run_loop, "check_finite", diverge_on_second_chunk)
    with pytest.raises(RuntimeError, match="diverged at seed 1, round 3: loss = nan.*--resume"):
        train_run(CONFIG, 2, str(out), rounds_per_chunk=2, progress=False, checkpoint_seconds=0.0)
    record = json.loads((out / "diverged.json").read_text())
    assert record["last_good_checkpoint"] == 1  # the diverged chunk was not saved
    monkeypatch.setattr(run_loop, "check_finite", real)
    with pytest.raises(ValueError, match="belongs to"):  # a bad setting is refused before anything changes
        resume_run(str(out), progress=False, assignments=["overestimate_weight=0.5"])
    summary = resume_run(str(out), progress=False, assignments=["lr=0.0005"])
    assert summary["episodes"] == 48
    meta = json.loads((out / "config.json").read_text())
    assert meta["config"]["lr"] == 0.0005 and meta["changed_after_divergence"] == ["lr=0.0005"]
    with pytest.raises(ValueError, match="did not diverge"):
        resume_run(str(out), progress=False, assignments=["lr=0.001"])


def test_a_config_of_another_version_is_refused_naming_the_fields():
    values = CONFIG.to_dict()
    assert type(CONFIG).from_dict(values) == CONFIG  # the round trip of run folders
    values["algo"]["hysteresis_start"] = 0.2  # not a Mac-Cen-DDRQN setting
    with pytest.raises(ValueError, match=r"\['hysteresis_start'\] are not fields of maccen_ddrqn"):
        type(CONFIG).from_dict(values)
