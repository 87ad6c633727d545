"""Box Pushing: conformance to the original's traces, API invariants, errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference import require_traces, trace_dir, trace_files

import envs_jax
from envs_jax.boxpushing import GT_BB0, GT_BB1, PUSH, STAY
from envs_jax.conformance.__main__ import main as conformance_main

TRACE_DIR = trace_dir("boxpushing")
TRACES = trace_files("boxpushing", "bp_g*.npz")


@pytest.fixture(scope="module")
def env():
    return envs_jax.make("boxpushing-6x6")


@pytest.fixture(scope="module")
def jit_step(env):
    return jax.jit(env.step)


def random_policy(key, ts, env):
    """Uniform over available actions; busy agents get junk (must be ignored)."""
    logits = jnp.where(ts.avail_actions, 0.0, -jnp.inf)
    a = jax.random.categorical(key, logits)
    return jnp.where(ts.mac_done, a, -7)


def rollout(env, step, key, n_steps):
    """Eager Python loop over ``step`` (the plain reference for jit/vmap checks)."""
    state, ts = env.reset(key)
    out = [ts]
    for t in range(n_steps):
        key, k_act, k_step = jax.random.split(key, 3)
        state, ts = step(k_step, state, random_policy(k_act, ts, env))
        out.append(ts)
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *out)


def scan_rollout(env, key, n_steps):
    state, ts0 = env.reset(key)

    def body(carry, _):
        key, state, ts = carry
        key, k_act, k_step = jax.random.split(key, 3)
        state, ts = env.step(k_step, state, random_policy(k_act, ts, env))
        return (key, state, ts), ts

    _, tss = jax.lax.scan(body, (key, state, ts0), None, n_steps)
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), ts0, tss)


# --- conformance --------------------------------------------------------------------------


def test_traces_cover_the_documented_set():
    require_traces("boxpushing", TRACES)
    assert len(TRACES) == 10, f"expected the 10 Box Pushing trace files in {TRACE_DIR}"
    reset_eps = synth_eps = 0
    for path in TRACES:
        with np.load(path) as d:
            n = int(d["from_reset"].sum())
            reset_eps += n
            synth_eps += len(d["from_reset"]) - n
    assert (reset_eps, synth_eps) == (148, 240)


def test_conformance_all_traces(capsys):
    require_traces("boxpushing", TRACES)
    assert conformance_main(TRACES) == 0
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1] == "8328/8328 transitions match"


def test_conformance_reports_a_corrupted_trace(tmp_path, capsys):
    require_traces("boxpushing", TRACES)
    path = tmp_path / "bp_g06_bad.npz"
    with np.load(TRACES[0]) as d:
        data = {k: d[k] for k in d.files}
    data["reward"] = data["reward"].copy()
    data["reward"][3, 5] += 1.0  # one wrong reward in episode 3, step 5
    np.savez(path, **data)
    assert conformance_main([str(path)]) == 1
    out = capsys.readouterr().out
    assert "MISMATCH" in out and "episode 3, step 5" in out and "'reward'" in out
    assert "transitions match" in out.splitlines()[-1] and not out.splitlines()[-1].startswith("1035/1035")


def test_conformance_rejects_unknown_format(tmp_path, capsys):
    path = tmp_path / "other.npz"
    np.savez(path, x=np.zeros(3))
    assert conformance_main([str(path)]) == 1
    assert "not a recognised trace format" in capsys.readouterr().out


# --- known returns (SPEC §13) ---------------------------------------------------------------


@pytest.mark.parametrize("g,disc_opt", [(6, 270.605), (8, 259.691), (10, 244.125)])
def test_big_box_plan_reaches_the_optimal_return(g, disc_opt):
    env = envs_jax.make(f"boxpushing-{g}x{g}")
    step = jax.jit(env.step)
    state, ts = env.reset(jax.random.key(0))
    ret, disc = 0.0, 1.0
    goals = jnp.array([GT_BB0, GT_BB1])
    while not bool(ts.done):
        at_wp = np.asarray(state.core.wp) == np.array([GT_BB0, GT_BB1])
        both_ready = at_wp.all() and np.asarray(state.mac_done).all() and (np.asarray(state.core.head) == 0).all()
        a = jnp.full(2, PUSH) if both_ready else jnp.where(jnp.asarray(at_wp), STAY, goals)
        state, ts = step(jax.random.key(0), state, a)
        ret += disc * float(ts.reward)
        disc *= 0.98
    assert bool(ts.terminated) and not bool(ts.truncated)
    assert ret == pytest.approx(disc_opt, abs=1e-3)
    assert int(ts.t) == (6 if g == 6 else int(1.5 * g - 4))


# --- jit / vmap / plain equality, retracing, determinism --------------------------------------


def test_jit_vmap_and_plain_execution_agree(env, jit_step):
    keys = jax.random.split(jax.random.key(3), 3)
    plain = rollout(env, env.step, keys[0], 8)  # eager, op by op (slow: keep short)
    jitted = rollout(env, jit_step, keys[0], 8)
    for a, b in zip(jax.tree_util.tree_leaves(plain), jax.tree_util.tree_leaves(jitted)):
        np.testing.assert_array_equal(a, b)
    single = jax.jit(lambda k: scan_rollout(env, k, 8))
    batched = jax.jit(jax.vmap(lambda k: scan_rollout(env, k, 8)))(keys)
    for i, k in enumerate(keys):
        ref = plain if i == 0 else single(k)
        for a, b in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(batched)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[i])


def test_step_does_not_retrace(env):
    traces = []

    @jax.jit
    def step(key, state, actions):
        traces.append(1)
        return env.step(key, state, actions)

    state, ts = env.reset(jax.random.key(0))
    key = jax.random.key(1)
    for _ in range(6):
        key, k1, k2 = jax.random.split(key, 3)
        state, ts = step(k2, state, random_policy(k1, ts, env))
    assert len(traces) == 1


def test_same_key_same_episode(env):
    a = jax.jit(lambda k: scan_rollout(env, k, 40))(jax.random.key(11))
    b = jax.jit(lambda k: scan_rollout(env, k, 40))(jax.random.key(11))
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_array_equal(x, y)


# --- macro-action bookkeeping invariants ------------------------------------------------------


@pytest.fixture(scope="module")
def random_rollouts():
    """64 random 100-step rollouts on 8x8 (no auto-reset), stacked [E, H+1, ...]."""
    env = envs_jax.make("boxpushing-8x8")
    keys = jax.random.split(jax.random.key(7), 64)
    return env, jax.jit(jax.vmap(lambda k: scan_rollout(env, k, 100)))(keys)


def test_obs_real_obs_macro_and_mac_done_are_consistent(random_rollouts):
    _, ts = random_rollouts
    done = np.asarray(ts.mac_done)  # [E, T, n]
    obs_m, obs_r = np.asarray(ts.obs_macro), np.asarray(ts.obs_real)
    assert done[:, 0].all()  # everyone is free at reset
    # Where a macro-action just ended the macro-observation is the real one ...
    np.testing.assert_array_equal(obs_m[done], obs_r[done])
    # ... elsewhere it is frozen at its previous value.
    busy = ~done[:, 1:]
    np.testing.assert_array_equal(obs_m[:, 1:][busy], obs_m[:, :-1][busy])
    # and the frozen observation really differs from the real one somewhere.
    assert (obs_m[:, 1:][busy] != obs_r[:, 1:][busy]).any()


def test_t_m_counts_progress_and_busy_agents_keep_their_macro_action(random_rollouts):
    _, ts = random_rollouts
    done, t_m, mac = (np.asarray(x) for x in (ts.mac_done, ts.t_m, ts.mac))
    prev_done = done[:, :-1]
    np.testing.assert_array_equal(t_m[:, 1:], np.where(prev_done, 0, t_m[:, :-1] + 1))
    np.testing.assert_array_equal(mac[:, 1:][~prev_done], mac[:, :-1][~prev_done])
    # Box Pushing's one-step actions always terminate at once.
    one_step = np.isin(mac[:, 1:], [5, 6, 7])
    assert done[:, 1:][one_step].all()


def test_truncated_exactly_at_the_horizon(random_rollouts):
    env, ts = random_rollouts
    t, term, trunc = np.asarray(ts.t), np.asarray(ts.terminated), np.asarray(ts.truncated)
    np.testing.assert_array_equal(trunc, (t >= env.spec.horizon) & ~term)
    assert not (term & trunc).any()


def test_auto_reset_keeps_the_final_timestep():
    env = envs_jax.AutoReset(envs_jax.make("boxpushing-6x6", horizon=12))

    def run(key):
        state, _ = env.reset(key)

        def body(carry, _):
            key, state = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = random_policy(k_act, state.timestep, env)
            state, ts = env.step(k_step, state, actions)
            return (key, state), (ts, state.timestep)

        _, out = jax.lax.scan(body, (key, state), None, 60)
        return out

    final, nxt = jax.jit(run)(jax.random.key(5))
    done = np.asarray(final.done)
    assert done.sum() >= 5  # at most 12 steps per episode
    # The returned timestep is the real end of the episode, the next one to act from is a reset.
    assert (np.asarray(final.t)[done] >= 1).all()
    assert (np.asarray(nxt.t)[done] == 0).all() and np.asarray(nxt.mac_done)[done].all()
    assert (np.asarray(nxt.t)[~done] == np.asarray(final.t)[~done]).all()
    np.testing.assert_array_equal(np.asarray(final.truncated), (np.asarray(final.t) == 12) & ~np.asarray(final.terminated))


# --- metadata, rendering, errors --------------------------------------------------------------


def test_spec_metadata(env):
    s = env.spec
    assert (s.num_agents, s.num_actions, s.obs_sizes, s.state_dim) == (2, (8, 8), (5, 5), 18)
    assert (s.horizon, s.discount, s.obs_dim, s.max_actions) == (100, 0.98, 5, 8)
    assert s.action_names[0][4] == "Push"
    cfg = envs_jax.make("boxpushing-10x10").config
    assert (cfg.big_box_reward, cfg.small_box_reward, cfg.penalty, cfg.step_cost) == (300.0, 20.0, -10.0, -0.1)


def test_render_shows_agents_boxes_and_goal(env):
    state, _ = env.reset(jax.random.key(0))
    text = env.render(state)
    rows = text.splitlines()
    assert rows[0].endswith("<- goal") and len([r for r in rows if r.startswith(("s", ".", "0", "B"))]) >= 1
    assert "0>" in text and "1<" in text and text.count("s") >= 2 and text.count("B") == 2


@pytest.mark.parametrize(
    "name,overrides,needle",
    [
        ("boxpushing-7x7", {}, "valid grids"),
        ("boxpushing-32x32", {}, "valid grids"),
        ("boxpushing-2x2", {}, "valid grids"),
        ("boxpushing-6x8", {}, "square"),
        ("boxpush-6x6", {}, "valid names"),
        ("boxpushing-6x6", {"horizn": 50}, "valid overrides"),
        ("boxpushing-6x6", {"horizon": "50"}, "must be of type int"),
        ("boxpushing-6x6", {"discount": True}, "must be of type float"),
        ("boxpushing-6x6", {"discount": 1.5}, "discount"),
        ("boxpushing-6x6", {"grid": 8}, "grid"),
    ],
)
def test_make_rejects_bad_input(name, overrides, needle):
    with pytest.raises(ValueError, match=needle):
        envs_jax.make(name, **overrides)


def test_step_rejects_bad_actions(env):
    state, _ = env.reset(jax.random.key(0))
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(key, state, jnp.zeros(3, jnp.int32))
    with pytest.raises(ValueError, match="integers"):
        env.step(key, state, jnp.zeros(2, jnp.float32))
    with pytest.raises(ValueError, match="agent 1 is free and sent action 8"):
        env.step(key, state, jnp.array([0, 8]))
    with pytest.raises(ValueError, match="agent 0 is free and sent action -1"):
        env.step(key, state, jnp.array([-1, 0]))
    # A busy agent's entry is ignored, whatever it is.
    state, _ = env.step(key, state, jnp.array([GT_BB0, GT_BB1]))
    assert not np.asarray(state.mac_done).any()
    env.step(key, state, jnp.array([-1, 99]))
