"""The divergence guard and the target period: a value learner whose mean value estimate leaves the bounds every
return of its env lies in is flagged in metrics.csv and stopped with a message (keeping its last good checkpoint);
one that stays inside trains to the end; the bounds hold on real episodes; a target period that would copy the
target after every round is refused."""

from __future__ import annotations

import csv
import json

import envs_jax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_jax.core import RewardBounds, value_bounds
from envs_jax.policies import uniform_random_actions
from jaxmac.presets import scenario_config
from jaxmac.runs import OUT_OF_BOUNDS_COLUMN, RunDiverged, flag_out_of_bounds, out_of_bounds_message, train_run
from jaxmac.runs import loop as run_loop

CONFIG = scenario_config("boxpushing-6x6", tiny=True).override(
    horizon=20, episodes=48, num_envs=8, batch_size=8, buffer_episodes=16, eval_every_episodes=16, eval_episodes=2,
    target_update_episodes=16, eps_decay_episodes=16)


def _rows(out):
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


# --- the bounds -------------------------------------------------------------------------------------------------

def test_value_bounds_sum_the_worst_step_over_the_horizon_and_cap_the_best_episode():
    assert value_bounds(RewardBounds(-2.0, 50.0), 1.0, 10) == (-20.0, 50.0)
    low, high = value_bounds(RewardBounds(-1.0, 5.0), 0.5, 3)
    assert (low, high) == (-1.75, 5.0)  # 1 + 0.5 + 0.25
    assert value_bounds(RewardBounds(3.0, -1.0), 0.9, 4) == (0.0, 0.0)  # a value can always be 0-bounded


@pytest.mark.parametrize("name", ["boxpushing-6x6", "overcooked-A", "warehouse-A"])
def test_random_episodes_stay_inside_the_reward_bounds(name):
    """Every step pays at least step_min and no episode collects more positive reward than episode_max; every
    discounted return-to-go lies in value_bounds."""
    env = envs_jax.make(name)
    bounds = env.reward_bounds()
    low, high = value_bounds(bounds, env.spec.discount, env.spec.horizon)

    @jax.jit
    def rewards(key):
        k_reset, k_run = jax.random.split(key)
        state, ts = env.reset(k_reset)

        def body(carry, k):
            state, ts, over = carry
            k_act, k_step = jax.random.split(k)
            state, nxt = env.step(k_step, state, uniform_random_actions(k_act, ts.avail_actions))
            reward = jnp.where(over, 0.0, nxt.reward)
            return (state, nxt, over | nxt.done), reward

        _, r = jax.lax.scan(body, (state, ts, jnp.zeros((), bool)), jax.random.split(k_run, env.spec.horizon))
        return r

    r = np.asarray(jax.vmap(rewards)(jax.random.split(jax.random.key(0), 32)), np.float64)  # [episodes, H]
    assert r.min() >= bounds.step_min
    assert np.clip(r, 0, None).sum(1).max() <= bounds.episode_max
    gammas = env.spec.discount ** np.arange(r.shape[1])
    to_go = np.array([[(r[e, t:] * gammas[: r.shape[1] - t]).sum() for t in range(r.shape[1])] for e in range(len(r))])
    assert low <= to_go.min() and to_go.max() <= high


@pytest.mark.parametrize("variant,scripted", [("A", 533), ("B", 533), ("C", 801), ("D", 803), ("E", 1053)])
def test_the_scripted_warehouse_returns_lie_below_the_upper_bound(variant, scripted):
    env = envs_jax.make(f"warehouse-{variant}")
    assert scripted <= value_bounds(env.reward_bounds(), 1.0, env.spec.horizon)[1] < 1.25 * scripted


def test_flags_and_message_name_the_first_seed_and_round_outside():
    metrics = {"episodes": np.array([[8, 16, 24], [8, 16, 24]]),
               "q_tot_mean": np.array([[np.nan, 5.0, 30.0], [np.nan, 12.0, 1.0]])}
    flags = flag_out_of_bounds(metrics, (-10.0, 10.0))
    np.testing.assert_array_equal(flags, [[0, 0, 1], [0, 1, 0]])  # NaN (no gradient step) is not flagged
    metrics[OUT_OF_BOUNDS_COLUMN] = flags
    message = out_of_bounds_message(metrics, [4, 5], 100, (-10.0, 10.0))
    assert message.startswith("seed 5, round 101 (episode 16): q_tot_mean = 12 is outside the value bounds [-10, 10]")
    assert flag_out_of_bounds({"episodes": metrics["episodes"], "loss": metrics["q_tot_mean"]}, (0.0, 1.0)) is None


# --- the guard in a run -----------------------------------------------------------------------------------------

def test_a_run_inside_the_bounds_trains_to_the_end_unflagged(tmp_path):
    summary = train_run(CONFIG, 2, str(tmp_path / "ok"), rounds_per_chunk=2, progress=False)
    rows = _rows(tmp_path / "ok")
    assert summary["episodes"] == 48 and len(rows) == 2 * 6
    trained = [r for r in rows if float(r["round_updates"]) > 0]
    assert trained and all(float(r[OUT_OF_BOUNDS_COLUMN]) == 0 for r in trained)


def test_a_run_outside_the_bounds_is_stopped_keeping_its_last_good_checkpoint(tmp_path, monkeypatch):
    """Bounds shrunk to ±1e-9 around 0 (any trained value estimate is outside them): the first round with a
    gradient step (the second: training starts at 16 stored episodes) is flagged and the run stops before
    checkpointing it."""
    monkeypatch.setattr(run_loop, "value_bounds_of", lambda config, env: (-1e-9, 1e-9))
    out = tmp_path / "div"
    with pytest.raises(RunDiverged, match=r"value estimate diverged at seed \d, round 1 \(episode 16\): "
                                           r"q_tot_mean = .* outside the value bounds \[-1e-09, 1e-09\].*--resume"):
        train_run(CONFIG.override(start_train_episodes=16), 2, str(out), rounds_per_chunk=1, progress=False,
                  checkpoint_seconds=0.0)
    record = json.loads((out / "diverged.json").read_text())
    rows = _rows(out)
    first_trained = min(int(r["round"]) for r in rows if float(r["round_updates"]) > 0)
    assert record["kind"] == "value out of bounds" and record["chunk"] == first_trained
    assert record["last_good_checkpoint"] == first_trained  # chunks 1..first_trained saved, the flagged one not
    assert all(float(r[OUT_OF_BOUNDS_COLUMN]) == 1 for r in rows if int(r["round"]) == first_trained)
    assert not (out / "summary.json").exists()


def test_with_the_guard_off_a_run_outside_the_bounds_trains_on_flagged(tmp_path, monkeypatch):
    monkeypatch.setattr(run_loop, "value_bounds_of", lambda config, env: (-1e-9, 1e-9))
    summary = train_run(CONFIG.override(divergence_guard=False), 1, str(tmp_path / "off"), rounds_per_chunk=2,
                        progress=False)
    rows = _rows(tmp_path / "off")
    assert summary["episodes"] == 48
    assert all(float(r[OUT_OF_BOUNDS_COLUMN]) == (float(r["round_updates"]) > 0) for r in rows)


def test_divergence_margin_is_validated():
    with pytest.raises(ValueError, match="divergence_margin=-0.1 must be a finite number >= 0"):
        CONFIG.override(divergence_margin=-0.1)
    with pytest.raises(ValueError, match="divergence_margin=nan"):
        CONFIG.override(divergence_margin=float("nan"))


# --- the target period ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("period,envs", [(16, 16), (16, 32), (1, 8)])
def test_a_target_copied_after_every_round_is_refused_naming_both_values(period, envs):
    with pytest.raises(ValueError, match=f"target_update_episodes={period} <= num_envs={envs}.*"
                                         "target_update_episodes=0 to train without a target network on purpose"):
        CONFIG.override(num_envs=envs, target_update_episodes=period)


def test_a_period_of_zero_copies_the_target_after_every_round():
    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.trainer import make_train

    config = CONFIG.override(target_update_episodes=0)
    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env), rounds_per_chunk=3)
    state, _ = jax.jit(trainer.train_chunk)(jax.jit(trainer.init)(jax.random.key(0)))
    assert int(state.updates) > 0
    jax.tree_util.tree_map(np.testing.assert_array_equal, state.params, state.target_params)


def test_the_paper_overcooked_table_is_refused_and_runs_with_the_explicit_no_target_setting():
    with pytest.raises(ValueError, match="target_update_episodes=16 <= num_envs=32.*after every gradient step"):
        scenario_config("overcooked-A", paper=True)
    literal = scenario_config("overcooked-A", paper=True, overrides=dict(target_update_episodes=0))
    assert (literal.updates_per_round, literal.lr, literal.batch_size) == (1, 3e-4, 64)


def test_the_defaults_are_the_learning_settings_and_the_paper_is_one_flag_away():
    for name in ("overcooked-A", "overcooked-B", "overcooked-C"):
        config = scenario_config(name)
        assert (config.target_update_episodes, config.updates_per_round) == (128, 4)
    assert scenario_config("overcooked-C").target_polyak == 0.05  # hard copies on A and B
    paper_c = scenario_config("overcooked-C", paper=True, overrides=dict(target_update_episodes=0))
    assert scenario_config("overcooked-A").target_polyak == paper_c.target_polyak == 0
    for name in ("warehouse-A", "warehouse-E"):
        assert scenario_config(name).discount == 0.99
        assert scenario_config(name, paper=True).discount == 0.0  # the env's own: 1
    assert scenario_config("boxpushing-6x6") == scenario_config("boxpushing-6x6", paper=True)
    assert scenario_config("overcooked-A", "mac_iaicc", paper=True) == scenario_config("overcooked-A", "mac_iaicc")


def test_old_run_records_with_a_one_round_period_read_as_zero():
    values = scenario_config("boxpushing-14x14", "mac_iaicc").to_dict()
    assert values["target_update_episodes"] == 0 and values["num_envs"] == 48
    values["target_update_episodes"] = 48  # as written before the rule
    assert type(CONFIG).from_dict(values) == scenario_config("boxpushing-14x14", "mac_iaicc")
