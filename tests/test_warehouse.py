"""Warehouse Tool Delivery A–E: conformance to the reference's traces, the scripted policy's
returns, jit/vmap/plain equality, retracing, the quirk switches, noise sampling, errors."""

from __future__ import annotations

import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference import require_traces, trace_dir, trace_files

import envs_jax
from envs_jax.conformance import warehouse as adapter
from envs_jax.conformance.__main__ import main as conformance_main
from envs_jax.warehouse import InjectedNoiseEnv, Noise, make_warehouse
from envs_jax.warehouse.scripted import ScriptedPolicy
from envs_jax.warehouse.variants import DEFAULT_CONFIGS, LAYOUTS

TRACE_DIR = trace_dir("warehouse")
TRACES = trace_files("warehouse", "warehouse_*.npz")


def random_policy(key, ts):
    """Uniform over available actions; busy agents get junk (must be ignored)."""
    a = jax.random.categorical(key, jnp.where(ts.avail_actions, 0.0, -jnp.inf))
    return jnp.where(ts.mac_done, a, -7)


def scan_rollout(env, key, n_steps):
    """Random rollout inside ``lax.scan`` (no auto-reset): stacked timesteps [n_steps + 1]."""
    state, ts0 = env.reset(key)

    def body(carry, _):
        key, state, ts = carry
        key, k_act, k_step = jax.random.split(key, 3)
        state, ts = env.step(k_step, state, random_policy(k_act, ts))
        return (key, state, ts), ts

    _, tss = jax.lax.scan(body, (key, state, ts0), None, n_steps)
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), ts0, tss)


def loop_rollout(env, step, key, n_steps):
    """The same rollout as a Python loop over ``step`` (plain or jitted)."""
    state, ts = env.reset(key)
    out = [ts]
    for _ in range(n_steps):
        key, k_act, k_step = jax.random.split(key, 3)
        state, ts = step(k_step, state, random_policy(k_act, ts))
        out.append(ts)
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *out)


def assert_trees_equal(a, b):
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.fixture(scope="module")
def env_e():
    return envs_jax.make("warehouse-E")


@pytest.fixture(scope="module")
def traced_step(env_e):
    """``jit(env.step)`` that counts its traces."""
    traces = []

    @jax.jit
    def step(key, state, actions):
        traces.append(1)
        return env_e.step(key, state, actions)

    step.traces = traces
    return step


# --- conformance ------------------------------------------------------------------------------


def test_traces_cover_the_documented_set():
    require_traces("warehouse", TRACES)
    assert len(TRACES) == 10, f"expected the 10 Warehouse trace files in {TRACE_DIR}"
    counts = {False: [0, 0], True: [0, 0]}  # noisy -> [episodes, transitions]
    for path in TRACES:
        with np.load(path) as d:
            noisy = path.endswith("_noise.npz")
            counts[noisy][0] += len(d["ep_offsets"]) - 1
            counts[noisy][1] += int((d["t"] > 0).sum())
    assert counts == {False: [80, 16510], True: [20, 3649]}


def test_conformance_all_traces(capsys):
    require_traces("warehouse", TRACES)
    assert conformance_main(TRACES) == 0
    out = capsys.readouterr().out
    assert out.count("OK ") == 10
    assert out.strip().splitlines()[-1] == "20159/20159 transitions match"


def test_conformance_reports_corrupted_traces(tmp_path, capsys):
    require_traces("warehouse", TRACES)
    path = tmp_path / "warehouse_A_bad.npz"
    with np.load(TRACES[0]) as d:  # warehouse_A.npz: compiled replay reused from the test above
        data = {k: d[k] for k in d.files}
    off = data["ep_offsets"]
    data["reward"] = data["reward"].copy()
    data["reward"][off[3] + 5] += 1.0  # episode 3, step 5
    data["rb_xy"] = data["rb_xy"].copy()
    data["rb_xy"][off[7] + 9, 1, 0] += 1e-12  # a position off by far less than float32 resolution
    np.savez(path, **data)
    assert conformance_main([str(path)]) == 1
    out = capsys.readouterr().out
    assert "MISMATCH" in out and "episode 3, step 5 (one-step): field 'reward'" in out
    assert not out.splitlines()[-1].startswith("2679/2679")
    # Positions are compared exactly: a 1e-12 error is caught (episode 7 comes first now).
    data["reward"][off[3] + 5] -= 1.0
    np.savez(path, **data)
    assert conformance_main([str(path)]) == 1
    assert "episode 7, step 9 (one-step): field 'rb_xy'" in capsys.readouterr().out


def test_continuous_motion_path_reproduces_the_paper_traces():
    """The float32 motion used with noise, run noise-free on E's paper trace: every discrete
    field still matches; positions agree to 1e-6 but not bit-exactly (hence the motion graph)."""
    require_traces("warehouse", TRACES)
    with np.load(os.path.join(TRACE_DIR, "warehouse_E.npz")) as d:
        data = {k: d[k] for k in d.files}
    config = dataclasses.replace(DEFAULT_CONFIGS["E"], move_noise_std=0.05)
    env = InjectedNoiseEnv(LAYOUTS["E"], config, "warehouse-E")  # injects the recorded zero draws
    ok_step, first_step, ok_roll, first_roll = adapter._replay(env, data, adapter._expected_t_m(data), {
        "state": 1e-5, "rb_xy": 1e-6})
    assert first_step is None and first_roll is None and ok_step.all() and ok_roll.all()


# --- the scripted policy ------------------------------------------------------------------------


@pytest.mark.parametrize("variant,ret,steps", [("A", 533, 67), ("B", 533, 67), ("C", 801, 99), ("D", 803, 97),
                                               ("E", 1053, 127)])
def test_scripted_policy_reaches_the_known_returns(variant, ret, steps):
    env = envs_jax.make(f"warehouse-{variant}")
    policy = ScriptedPolicy(env)

    @jax.jit
    def episode(key):
        state, _ = env.reset(key)

        def body(carry, _):
            state, over, ret, length = carry
            state, ts = env.step(key, state, policy(state))
            ret += jnp.where(over, 0.0, ts.reward)
            length += jnp.where(over, 0, 1)
            return (state, over | ts.done, ret, length), ts.terminated & ~over

        init = (state, jnp.zeros((), bool), jnp.zeros(()), jnp.zeros((), jnp.int32))
        (_, _, ret, length), terminated = jax.lax.scan(body, init, None, env.spec.horizon)
        return ret, length, terminated.any()

    got_ret, got_len, terminated = episode(jax.random.key(0))
    assert (float(got_ret), int(got_len), bool(terminated)) == (ret, steps, True)


# --- jit / vmap / plain equality, retracing, determinism ----------------------------------------


def test_jit_vmap_and_plain_execution_agree(env_e, traced_step):
    keys = jax.random.split(jax.random.key(3), 3)
    plain = loop_rollout(env_e, env_e.step, keys[0], 6)  # eager, op by op (slow: keep short)
    jitted = loop_rollout(env_e, traced_step, keys[0], 6)
    assert_trees_equal(plain, jitted)
    batched = jax.jit(jax.vmap(lambda k: scan_rollout(env_e, k, 6)))(keys)
    assert_trees_equal(plain, jax.tree_util.tree_map(lambda x: x[0], batched))
    for i in (1, 2):
        lane = jax.tree_util.tree_map(lambda x, i=i: x[i], batched)
        assert_trees_equal(loop_rollout(env_e, traced_step, keys[i], 6), lane)


def test_step_does_not_retrace(env_e, traced_step):
    loop_rollout(env_e, traced_step, jax.random.key(5), 12)
    loop_rollout(env_e, traced_step, jax.random.key(6), 3)
    assert len(traced_step.traces) == 1


def test_noisy_env_is_a_pure_function_of_the_key():
    env = envs_jax.make("warehouse-C", move_noise_std=0.05, fetch_duration_noise=True)
    keys = jax.random.split(jax.random.key(9), 4)
    run = jax.jit(jax.vmap(lambda k: scan_rollout(env, k, 60)))
    a, b = run(keys), run(keys)
    assert_trees_equal(a, b)
    xy = np.asarray(a.state[:, :, :4])  # robot positions differ between keys once they move
    assert not np.array_equal(xy[0], xy[1])


def test_noise_sampler_distribution():
    env = envs_jax.make("warehouse-D", move_noise_std=0.05, fetch_duration_noise=True)
    state, _ = jax.jit(env.reset)(jax.random.key(0))
    noise = jax.jit(jax.vmap(env.sample_noise, in_axes=(0, None)))(jax.random.split(jax.random.key(1), 20000), state.core)
    move = np.asarray(noise.move)
    assert move.shape == (20000, 3, 2)
    assert abs(move.mean()) < 0.002 and abs(move.std() - 0.05) < 0.002
    values, counts = np.unique(np.asarray(noise.fetch), return_counts=True)
    assert values.tolist() == [-1, 0, 1, 2] and np.all(np.abs(counts / 20000 - 0.25) < 0.02)
    quiet = envs_jax.make("warehouse-D").sample_noise(jax.random.key(1), state.core)
    assert not np.asarray(quiet.move).any() and int(quiet.fetch) == 0


# --- the quirk switches (SPEC §12; defaults reproduce the reference) ----------------------------
# Eager steps on E-shaped envs only: configs do not change shapes, so the op-by-op compilations
# of the equality test above are reused.


def run_actions(env, joint_actions):
    """Eager steps with fixed joint actions; returns the stacked timesteps."""
    state, _ = env.reset(jax.random.key(0))
    out = []
    for a in joint_actions:
        state, ts = env.step(jax.random.key(0), state, jnp.asarray(a, jnp.int32))
        out.append(ts)
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *out)


def test_e_go_tool_room_takes_an_extra_step_unless_corrected():
    go_tr = [[4, 4, 4, 0]] * 3  # robot 0 starts 2 steps from TRW
    quirky = run_actions(envs_jax.make("warehouse-E"), go_tr)
    fixed = run_actions(envs_jax.make("warehouse-E", arrival_exit_on_go_tr=False), go_tr)
    assert quirky.mac_done[:, 0].tolist() == [False, False, True]
    assert fixed.mac_done[:, 0].tolist() == [False, True, True]
    assert not any(envs_jax.make(f"warehouse-{v}").config.arrival_exit_on_go_tr for v in "ABCD")


def test_pass_to_robot_2_is_only_judged_at_its_end_unless_corrected():
    # F passes to robot 2 at step 1; robot 2 reaches its table at step 3 and waits at step 4,
    # when the pass ends: the 3-robot reference releases it (empty staging, no penalty).
    actions = [[5, 5, 5, 3]] * 4
    quirky = run_actions(envs_jax.make("warehouse-E"), actions)
    fixed = run_actions(envs_jax.make("warehouse-E", check_every_pass=True), actions)
    assert quirky.reward.tolist() == [-1, -1, -1, -1] and quirky.mac_done[3].tolist() == [False, False, True, True]
    assert fixed.reward.tolist() == [-1, -1, -1, -11] and fixed.mac_done[3].tolist() == [False, False, False, True]
    # Passes to robots 0 and 1 are checked at their start in every variant.
    to_robot_1 = run_actions(envs_jax.make("warehouse-E"), [[5, 5, 5, 2]] * 4)
    assert to_robot_1.reward.tolist() == [-1, -1, -1, -11]


@pytest.mark.parametrize("overrides,terminated", [({}, True), ({"done_at_horizon": False}, False)])
def test_horizon_is_terminal_only_in_e(overrides, terminated):
    env = envs_jax.make("warehouse-E", horizon=3, **overrides)
    ts = run_actions(env, [[0] * env.num_agents] * 3)
    assert ts.terminated.tolist() == [False, False, terminated]
    assert ts.truncated.tolist() == [False, False, not terminated]
    assert not any(envs_jax.make(f"warehouse-{v}").config.done_at_horizon for v in "ABCD")


# --- metadata, rendering, errors ----------------------------------------------------------------


@pytest.mark.parametrize(
    "variant,agents,actions,obs,state,horizon",
    [
        ("A", 3, (4, 4, 6), (18, 18, 5), 29, 200),
        ("B", 3, (4, 4, 6), (18, 18, 5), 29, 200),
        ("C", 3, (5, 5, 6), (23, 23, 5), 34, 250),
        ("D", 4, (5, 5, 5, 7), (23, 23, 23, 6), 39, 250),
        ("E", 4, (6, 6, 6, 7), (28, 28, 28, 6), 44, 300),
    ],
)
def test_spec_metadata(variant, agents, actions, obs, state, horizon):
    env = envs_jax.make(f"warehouse-{variant}")
    s = env.spec
    assert (s.num_agents, s.num_actions, s.obs_sizes, s.state_dim, s.horizon, s.discount) == (
        agents, actions, obs, state, horizon, 1.0)
    assert s.action_names[0][-2:] == ("Go-TR", "Get-Tool") and s.action_names[-1][:2] == ("Wait", "Pass-R0")
    assert s.agent_names[-1] == "fetch"
    _, ts = jax.eval_shape(env.reset, jax.random.key(0))
    assert ts.obs_macro.shape == (agents, max(obs)) and ts.state.shape == (state,)
    assert ts.avail_actions.shape == (agents, max(actions))
    np.testing.assert_array_equal(env.action_mask, np.arange(max(actions))[None, :] < np.array(actions)[:, None])


def test_render_shows_positions_staging_baskets_and_humans(env_e):
    state, _ = env_e.reset(jax.random.key(0))
    state, _ = env_e.step(jax.random.key(0), state, jnp.array([0, 1, 5, 4]))
    text = env_e.render(state)
    for needle in ("warehouse-E", "robot0 at (3.76,3.75)", "Go-W0", "basket [0, 0, 0]", "F Search-T0",
                   "staging []", "human3 phase 0/3 timer 39"):
        assert needle in text, needle
    grid = text.splitlines()[1:12]
    assert sum(row.count("A") + row.count("B") + row.count("C") + row.count("D") for row in grid) == 4


@pytest.mark.parametrize(
    "name,overrides,needle",
    [
        ("warehouse-F", {}, "valid names"),
        ("warehouse-a", {}, "valid names"),
        ("warehouse-A", {"horizn": 50}, "valid overrides"),
        ("warehouse-A", {"horizon": "200"}, "must be of type int"),
        ("warehouse-A", {"horizon": 0}, "horizon=0"),
        ("warehouse-A", {"discount": 1.5}, r"discount=1.5 must be in \(0, 1\]"),
        ("warehouse-A", {"discount": 0.0}, r"discount=0.0 must be in \(0, 1\]"),
        ("warehouse-A", {"fetch_duration_noise": 1}, "must be of type bool"),
        ("warehouse-A", {"move_noise_std": -0.1}, "move_noise_std"),
        ("warehouse-A", {"n_each_obj": 0}, "n_each_obj"),
        ("warehouse-C", {"human_durations": ((40,) * 4,) * 2}, "3 sequences"),
        ("warehouse-C", {"human_durations": ((40, 40, 40),) * 3}, "human_durations"),
        ("warehouse-C", {"human_durations": ((40, 40, 0, 40),) * 3}, "positive ints"),
    ],
)
def test_make_rejects_bad_input(name, overrides, needle):
    with pytest.raises(ValueError, match=needle):
        envs_jax.make(name, **overrides)


def test_overrides_are_applied():
    with pytest.raises(ValueError, match="valid variants"):
        make_warehouse("F")
    assert envs_jax.make("warehouse-A").spec.discount == 1.0  # every original script's γ
    env = envs_jax.make("warehouse-A", horizon=150, human_durations=[[18] * 4, [18] * 4], delay_penalty=0.0,
                        discount=0.99)
    assert env.spec.horizon == 150 and env.config.human_durations == ((18,) * 4,) * 2
    assert env.spec.discount == 0.99
    state, _ = jax.jit(env.reset)(jax.random.key(0))
    assert np.asarray(state.core.h_time).tolist() == [18, 18]


def test_step_rejects_bad_actions(env_e):
    state, _ = env_e.reset(jax.random.key(0))
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=r"shape \(4,\)"):
        env_e.step(key, state, jnp.zeros(3, jnp.int32))
    with pytest.raises(ValueError, match="integers"):
        env_e.step(key, state, jnp.zeros(4, jnp.float32))
    with pytest.raises(ValueError, match=r"agent 1 is free and sent action 6, valid choices are \[0, 1, 2, 3, 4, 5\]"):
        env_e.step(key, state, jnp.array([0, 6, 0, 0]))
    with pytest.raises(ValueError, match="agent 3 is free and sent action 7"):
        env_e.step(key, state, jnp.array([0, 0, 0, 7]))
    # Busy agents' entries are ignored, whatever they are.
    state, _ = env_e.step(key, state, jnp.array([0, 1, 2, 4]))
    assert not np.asarray(state.mac_done).any()
    env_e.step(key, state, jnp.array([-1, 99, 7, -5]))
    with pytest.raises(TypeError, match="expects a Noise"):
        InjectedNoiseEnv(env_e.layout, env_e.config, "warehouse-E").step(key, state, jnp.zeros(4, jnp.int32))
    Noise(move=jnp.zeros((3, 2)), fetch=jnp.zeros((), jnp.int32))  # the injectable type


def test_trace_metadata_matches_our_spec():
    require_traces("warehouse", TRACES)
    for path in TRACES:
        with np.load(path) as d:
            meta = json.loads(str(d["meta_json"]))
        env = adapter.env_for_trace(meta)
        assert list(env.spec.obs_sizes) == meta["obs_dims"] and list(env.spec.num_actions) == meta["n_actions"]
