"""ToMacVF end to end at tiny sizes: determinism, vmap over seeds, learning signal, resume, ablations."""

from __future__ import annotations

import csv
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from _buffer_fixtures import config_for, synthetic_rollout

from jaxmac.algos.registry import make_algorithm
from jaxmac.algos.base import Progress
from jaxmac.buffer import episode
from jaxmac.buffer import ring as ring_lib
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.networks import jert_sequence, slot_inputs
from jaxmac.runs import finish_run, load_run, placed, resume_run, train_run
from jaxmac.trainer import make_train

TINY = scenario_config("boxpushing-6x6", tiny=True).override(
    horizon=20, episodes=32, num_envs=8, batch_size=8, buffer_episodes=16, eval_every_episodes=16,
    eval_episodes=2, target_update_episodes=16, eps_decay_episodes=16,
)
PROGRESS = Progress(episodes=jnp.int32(0), env_steps=jnp.int32(0), updates=jnp.int32(0))


def build(config=TINY, rounds_per_chunk=2):
    env = make_env(config)
    return make_train(config, env, make_algorithm(config, env), rounds_per_chunk)


@pytest.fixture(scope="module")
def trainer():
    return build()


@pytest.fixture(scope="module")
def vmapped_run(trainer):
    """Two seeds vmapped, two chunks: (final state, metrics [seeds, rounds])."""
    init = jax.jit(jax.vmap(trainer.init))
    chunk = jax.jit(trainer.seeds_chunk)
    state = init(jnp.stack([jax.random.key(0), jax.random.key(1)]))
    rows = []
    for _ in range(trainer.total_chunks):
        state, m = chunk(state)
        rows.append(jax.device_get(m))
    return state, {k: np.concatenate([r[k] for r in rows], 1) for k in rows[0]}


def test_vmap_over_seeds_equals_single_seed_runs_and_is_deterministic(trainer, vmapped_run):
    _, batched = vmapped_run
    init, chunk = jax.jit(trainer.init), jax.jit(trainer.train_chunk)
    for seed in (0, 1):
        state = init(jax.random.key(seed))
        rows = []
        for _ in range(trainer.total_chunks):
            state, m = chunk(state)
            rows.append(jax.device_get(m))
        single = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
        for k, v in single.items():
            np.testing.assert_allclose(v, batched[k][seed], rtol=1e-4, atol=1e-4, err_msg=k)
    # the two seeds really are different runs
    assert not np.allclose(batched["train_return"][0], batched["train_return"][1])
    assert np.isfinite(batched["loss"][:, -1]).all()
    assert np.isfinite(batched["eval_disc_return"][:, -1]).all()


def test_same_seed_gives_identical_metrics(trainer, vmapped_run):
    _, first = vmapped_run
    init = jax.jit(jax.vmap(trainer.init))
    chunk = jax.jit(trainer.seeds_chunk)
    state = init(jnp.stack([jax.random.key(0), jax.random.key(1)]))
    state, m = chunk(state)
    for k, v in jax.device_get(m).items():
        np.testing.assert_array_equal(v, first[k][:, : trainer.rounds_per_chunk], err_msg=k)


def test_loss_decreases_on_a_fixed_batch(trainer, vmapped_run):
    state, _ = vmapped_run
    state = jax.tree_util.tree_map(lambda x: x[0], state)
    batch, _ = ring_lib.sample(state.ring, jax.random.key(3), TINY.batch_size)
    loss_fn = trainer.algorithm.loss
    opt = optax.adam(3e-3)

    @jax.jit
    def fit(params):
        def step(carry, _):
            params, opt_state = carry
            (loss, _), grads = jax.value_and_grad(loss_fn, has_aux=True)(
                params, state.target_params, batch, jax.random.key(0), PROGRESS)
            updates, opt_state = opt.update(grads, opt_state)
            return (optax.apply_updates(params, updates), opt_state), loss

        _, losses = jax.lax.scan(step, (params, opt.init(params)), None, 60)
        return losses

    losses = np.asarray(fit(state.params))
    assert losses[-1] < 0.5 * losses[0], losses[[0, -1]]


@pytest.mark.parametrize(
    "overrides",
    [dict(buffer="mac_jert", obs_mode="macro"), dict(mixer_params="state"),
     dict(buffer="mac_jert", obs_mode="macro", mixer_params="state"),
     dict(mixer="vdn"), dict(obs_mode="macro"), dict(n_step=3, use_time_pe=False, attn_window=5)],
    ids=["wo_sjert", "wo_atpg", "wo_both", "vdn", "obs_macro", "nstep_nope_window"],
)
def test_ablation_switches_give_a_learning_signal(overrides, vmapped_run):
    """Every switch: the loss on a real batch is finite and has a non-zero gradient, and the
    decentralised policy acts."""
    state, _ = vmapped_run
    ring = jax.tree_util.tree_map(lambda x: x[0], state.ring)
    batch, _ = ring_lib.sample(ring, jax.random.key(1), TINY.batch_size)
    config = TINY.override(**overrides)
    env = make_env(config)
    algo = make_algorithm(config, env)
    params = algo.init_params(jax.random.key(0))

    @jax.jit
    def loss_and_act(params):
        (loss, _), grads = jax.value_and_grad(algo.loss, has_aux=True)(params, params, batch, jax.random.key(0), PROGRESS)
        _, ts = env.reset(jax.random.key(0))
        _, actions = algo.act(params, algo.init_carry(env.spec.num_agents), ts, jax.random.key(1), 0.5)
        return loss, optax.tree.norm(grads), actions

    loss, grad_norm, actions = loss_and_act(params)
    assert np.isfinite(loss) and float(grad_norm) > 0
    assert ((0 <= np.asarray(actions)) & (np.asarray(actions) < 8)).all()


def test_mac_jert_ablation_trains_end_to_end():
    config = TINY.override(episodes=16, buffer="mac_jert", obs_mode="macro")
    t = build(config, rounds_per_chunk=2)
    init = jax.jit(t.init)
    state, metrics = jax.jit(t.train_chunk)(init(jax.random.key(0)))
    assert np.isfinite(np.asarray(metrics["loss"])[-1])
    moved = jax.tree_util.tree_map(lambda a, b: bool(jnp.any(a != b)), state.params, init(jax.random.key(0)).params)
    assert any(jax.tree_util.tree_leaves(moved)), "no parameter changed"


def test_mac_jert_with_real_observations_is_refused_naming_both_values():
    with pytest.raises(ValueError) as err:
        TINY.override(buffer="mac_jert")  # obs_mode defaults to "real"
    assert "buffer='mac_jert'" in str(err.value) and "obs_mode='real'" in str(err.value)
    with pytest.raises(ValueError, match="obs_mode='real'"):
        TINY.override_strings(["buffer=mac_jert", "obs_mode=real"])
    assert TINY.override_strings(["buffer=mac_jert", "obs_mode=macro"]).algo.obs_mode == "macro"


def _read(path):
    with open(path, newline="") as f:
        return list(csv.reader(f))


def test_resume_equals_uninterrupted(tmp_path):
    config = TINY.override(episodes=48)
    full = train_run(config, 2, str(tmp_path / "full"), rounds_per_chunk=2, progress=False)
    assert train_run(config, 2, str(tmp_path / "killed"), rounds_per_chunk=2, progress=False,
                     stop_after_chunks=1) is None
    assert not os.path.exists(tmp_path / "killed" / "summary.json")
    resumed = resume_run(str(tmp_path / "killed"), progress=False)
    for key in ("final_greedy_return", "final_greedy_return_undiscounted", "episodes"):
        assert resumed[key] == full[key], key
    assert _read(tmp_path / "full" / "metrics.csv") == _read(tmp_path / "killed" / "metrics.csv")
    summary = json.loads((tmp_path / "full" / "summary.json").read_text())
    for key in ("scenario", "algorithm", "seeds", "episodes", "wall_seconds", "final_greedy_return",
                "final_greedy_return_mean", "final_greedy_return_undiscounted",
                "final_greedy_return_undiscounted_mean"):
        assert key in summary
    assert len(summary["final_greedy_return"]) == 2 and summary["episodes"] == 48
    assert (tmp_path / "full" / "curve.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="already holds a run"):
        train_run(config, 2, str(tmp_path / "full"), progress=False)
    # the state a run trains from lowers as a restored one does: a resumed run reuses the compiled program
    _, restored, _, _ = load_run(str(tmp_path / "killed"))
    fresh = placed(jax.jit(jax.vmap(build(config).init))(jax.vmap(jax.random.key)(jnp.arange(2))))
    probe = jax.jit(lambda state: jax.tree_util.tree_map(jnp.sum, state.params))
    assert probe.lower(fresh).as_text() == probe.lower(restored).as_text()


def test_extending_a_finished_run_equals_a_run_with_the_larger_budget(tmp_path):
    config = TINY.override(episodes=32)
    # two seeds as in test_resume_equals_uninterrupted: the same programs, compiled once for both tests
    longer = train_run(config.override(episodes=64), 2, str(tmp_path / "long"), rounds_per_chunk=2, progress=False)
    short = train_run(config, 2, str(tmp_path / "short"), rounds_per_chunk=2, progress=False)
    with pytest.raises(ValueError, match="episodes=16: a run can only be extended.*budget of 32"):
        resume_run(str(tmp_path / "short"), progress=False, episodes=16)
    extended = resume_run(str(tmp_path / "short"), progress=False, episodes=64)
    assert extended["episodes"] == 64
    assert extended["final_greedy_return"] == longer["final_greedy_return"]
    assert _read(tmp_path / "long" / "metrics.csv") == _read(tmp_path / "short" / "metrics.csv")
    # finishing a run of budget 64 after 32 episodes ends it as the run of budget 32 ended
    per_chunk = 2 * config.num_envs
    assert train_run(config.override(episodes=64), 2, str(tmp_path / "stopped"), rounds_per_chunk=2, progress=False,
                     stop_after_chunks=32 // per_chunk) is None
    finished = finish_run(str(tmp_path / "stopped"))
    assert finished["final_greedy_return"] == short["final_greedy_return"]
    assert (finished["episodes"], finished["stopped_at"], finished["budget"]) == (32, 32, 64)
    assert _read(tmp_path / "stopped" / "metrics.csv") == _read(tmp_path / "long" / "metrics.csv")[:len(
        _read(tmp_path / "stopped" / "metrics.csv"))]
    with pytest.raises(ValueError, match="already finished"):
        finish_run(str(tmp_path / "stopped"))
    # an early-finished run trained on: its early summary set aside, it ends as the run of budget 64
    resumed = resume_run(str(tmp_path / "stopped"), progress=False)
    assert resumed["final_greedy_return"] == longer["final_greedy_return"]
    assert json.loads((tmp_path / "stopped" / "summary.stopped-at-32.json").read_text())["stopped_at"] == 32
    assert _read(tmp_path / "stopped" / "metrics.csv") == _read(tmp_path / "long" / "metrics.csv")


def test_cli_resume_refuses_options_it_would_ignore(tmp_path, capsys):
    from jaxmac.cli import main

    assert main(["train", "--resume", str(tmp_path), "--set", "lr=0.1"]) == 2
    assert "--set cannot change it" in capsys.readouterr().err


def test_cli_seeds_are_a_count_or_a_range_and_reach_the_run(monkeypatch, capsys):
    import argparse

    import jaxmac.runs
    from jaxmac.cli import main, seed_range

    assert seed_range("4") == (0, 4) and seed_range("4:8") == (4, 4) and seed_range("0:1") == (0, 1)
    for bad in ("0", "8:4", "4:4", "-1:3", "a:b", "2.5"):
        with pytest.raises(argparse.ArgumentTypeError, match="--seeds"):
            seed_range(bad)
    calls = []
    monkeypatch.setattr(jaxmac.runs, "train_run", lambda config, seeds, out, **kw: calls.append((seeds, kw)))
    assert main(["train", "--tiny", "--seeds", "4:8", "--out", "unused", "--no-progress"]) == 0
    assert calls[0][0] == 4 and calls[0][1]["seed_offset"] == 4
    assert main(["train", "--tiny", "--seeds", "3", "--out", "unused", "--no-progress"]) == 0
    assert calls[1][0] == 3 and calls[1][1]["seed_offset"] == 0
    with pytest.raises(SystemExit):
        main(["train", "--seeds", "5:2"])
    assert "need 0 <= A < B" in capsys.readouterr().err


def test_presets_are_the_scenario_settings_with_their_overrides_and_refuse_what_they_fix(capsys):
    from jaxmac.cli import main
    from jaxmac.presets import PRESETS, preset_config

    for name, preset in PRESETS.items():
        config, _ = preset_config(name)
        base = scenario_config(preset.scenario, preset.algorithm).flat_dict()
        changed = {k: v for k, v in config.flat_dict().items() if base[k] != v}
        assert changed == preset.overrides, name  # every override takes effect, nothing else changes
    assert main(["train", "--preset", "quickstart", "--scenario", "overcooked-A"]) == 2
    assert "--scenario cannot be combined" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown preset 'fast'; valid presets: .*quickstart"):
        preset_config("fast")


def test_config_errors_name_the_value():
    with pytest.raises(ValueError, match="buffer='sjert'.*choices"):
        TINY.override(buffer="sjert")
    with pytest.raises(ValueError, match="unknown config key 'lrate'"):
        TINY.override_strings(["lrate=0.1"])
    with pytest.raises(ValueError, match="unknown scenario"):
        scenario_config("boxpushing-7x7")


@pytest.mark.parametrize("scenario,default", [("boxpushing-6x6", 0.98), ("overcooked-A", 0.99), ("warehouse-A", 1.0)])
def test_discount_override_reaches_the_env_and_the_replay_slots(scenario, default):
    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.trainer import make_train

    assert make_env(scenario_config(scenario, tiny=True, paper=True)).spec.discount == default  # the env's own
    config = scenario_config(scenario, tiny=True).override_strings(["discount=0.9"])
    env = make_env(config)
    assert env.spec.discount == 0.9
    assert make_train(config, env, make_algorithm(config, env)).slot_config.discount == 0.9
    with pytest.raises(ValueError, match=r"discount=1.5 must be in \(0, 1\]"):
        TINY.override(discount=1.5)


def test_overestimate_weight_downweights_only_positive_td_errors():
    from jaxmac.losses import td_mse

    delta = jnp.array([2.0, -2.0, 1.0, 5.0])
    mask = jnp.array([True, True, True, False])
    assert float(td_mse(delta, mask)) == pytest.approx((4 + 4 + 1) / 3)
    assert float(td_mse(delta, mask, 0.25)) == pytest.approx((0.25 * 4 + 4 + 0.25 * 1) / 3)
    # a traced (scheduled) weight, as the hysteretic learners pass it
    assert float(jax.jit(td_mse)(delta, mask, jnp.float32(0.25))) == pytest.approx((0.25 * 4 + 4 + 0.25 * 1) / 3)
    with pytest.raises(ValueError, match=r"overestimate_weight=0.0 must be in \(0, 1\]"):
        TINY.override(overestimate_weight=0.0)
    with pytest.raises(ValueError, match=r"overestimate_weight_end=1.5 must be in \(0, 1\]"):
        TINY.override(overestimate_weight_end=1.5, overestimate_anneal_episodes=10)
    with pytest.raises(ValueError, match=r"overestimate_anneal_start=-1 must be >= 0"):
        TINY.override(overestimate_anneal_start=-1, overestimate_anneal_episodes=10)
    with pytest.raises(ValueError, match=r"overestimate_weight_end=0.5 .* overestimate_anneal_episodes=0 turns off"):
        TINY.override(overestimate_weight_end=0.5)


@pytest.mark.parametrize("end", ["truncated", "terminated"])
def test_jert_sequence_is_the_decision_rows_then_the_bootstrap_row(end):
    """Mac-JERT ablation: entry k (k < c) is decision row start[k]; entry c is the row after the last kept step.

    Checked against the per-row inputs of the same slot: a truncated episode must bootstrap from the
    real next row, not from padding.
    """
    rng = np.random.default_rng(3)
    h, n, length = 12, 2, 9
    mac_done = rng.random((h, n)) < 0.35
    reset_ts, traj, _ = synthetic_rollout(mac_done, rng.normal(size=h), length, end=end, obs_dim=3, num_actions=4)
    slot = episode.write_episode(config_for(h, n, 0.9), reset_ts, traj)
    batch = jax.tree_util.tree_map(lambda x: x[None], slot)
    jv, seq, tau, state = jax.jit(jert_sequence)(batch)
    rows_inputs, _ = slot_inputs(batch, "macro")
    rows_state = batch.decode_state()

    count = int(jv.mask[0].sum())
    assert 0 < count < h  # the bootstrap row lies inside the padding, the case that matters
    rows = np.append(np.asarray(jv.start[0, :count]), int(jv.step[0, count - 1]) + 1)
    for field in ("obs", "t", "prev_t", "prev_mac", "prev_t_m"):
        np.testing.assert_array_equal(np.asarray(getattr(seq, field))[0, :count + 1],
                                      np.asarray(getattr(rows_inputs, field))[0, rows], err_msg=field)
    np.testing.assert_array_equal(np.asarray(state)[0, :count + 1], np.asarray(rows_state)[0, rows])
    np.testing.assert_array_equal(np.asarray(tau)[0, count], np.asarray(jv.next_t_m)[0, count - 1])
    np.testing.assert_array_equal(np.asarray(seq.reset)[0], np.arange(h + 1) == 0)
