"""Overcooked A/B/C: conformance to the original's traces, the exact planner, API invariants,
the scripted policy, metadata and errors."""

from __future__ import annotations

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference import require_traces, trace_dir, trace_files

import envs_jax
from envs_jax.conformance.__main__ import main as conformance_main
from envs_jax.overcooked import layouts, planner
from envs_jax.overcooked.plan_table import build_table, make_exact_planner, pair_index
from envs_jax.overcooked.scripted import scripted_actions
from envs_jax.policies import uniform_random_actions

TRACE_DIR = trace_dir("overcooked")
TRACES = trace_files("overcooked", "overcooked_*.npz")
KEY = jax.random.key(0)
N_LANES = 3 * 256  # planner tests: one compiled search for both
search = jax.jit(jax.vmap(planner.plan_exact))


@pytest.fixture(scope="module")
def env():
    return envs_jax.make("overcooked-A")


def random_policy(key, ts):
    """Uniform over available actions for free agents; busy agents send junk (must be ignored)."""
    return jnp.where(ts.mac_done, uniform_random_actions(key, ts.avail_actions), -3)


def scan_rollout(env, key, n_steps, policy=None):
    """Timesteps [n_steps + 1] (reset first) and the primitive actions taken [n_steps, 3].
    ``policy(env, state, key)``; default uniform random."""
    state, ts0 = env.reset(key)

    def body(carry, k):
        state, ts = carry
        actions = random_policy(k, ts) if policy is None else policy(env, state, k)
        state, ts = env.step(k, state, actions)
        return (state, ts), (ts, state.core.prim)

    _, (tss, prims) = jax.lax.scan(body, (state, ts0), jax.random.split(key, n_steps))
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), ts0, tss), prims


# --- conformance --------------------------------------------------------------------------------


def test_traces_are_the_documented_set():
    require_traces("overcooked", TRACES)
    assert [os.path.basename(p) for p in TRACES] == ["overcooked_A.npz", "overcooked_B.npz", "overcooked_C.npz"]
    total = 0
    for path in TRACES:
        with np.load(path) as d:
            assert len(d["ep_len"]) == 40 and json.loads(str(d["meta_json"]))["n_agent"] == 3
            total += int(d["ep_len"].sum())
    assert total == 19977


def test_conformance_all_traces(capsys):
    require_traces("overcooked", TRACES)
    assert conformance_main(TRACES) == 0
    out = capsys.readouterr().out
    assert out.count("OK ") == 3 and out.strip().splitlines()[-1] == "19977/19977 transitions match"


def test_conformance_reports_a_corrupted_trace(tmp_path, capsys):
    require_traces("overcooked", TRACES)
    with np.load(TRACES[0]) as d:
        data = {k: d[k] for k in d.files}
    row = data["ep_step_start"][3] + 5
    data["t_prim"] = data["t_prim"].copy()
    data["t_prim"][row, 1] = (data["t_prim"][row, 1] + 1) % 5  # one wrong primitive action
    path = tmp_path / "overcooked_A_bad.npz"
    np.savez(path, **data)
    assert conformance_main([str(path)]) == 1
    out = capsys.readouterr().out
    assert "MISMATCH" in out and "episode 3, step 5" in out and "'prim'" in out
    assert out.strip().splitlines()[-1] == "6734/6735 transitions match"


# --- planner --------------------------------------------------------------------------------------


def _random_belief_maps(rng, n, floor):
    """Belief maps as the env builds them: background, five items (mostly on counters, up to three
    on the floor: phantoms), two teammates and the own cell s on the floor.

    Returns (pm int[n, 49], s, t, mates int[n, 2], items int[n, 5]); targets are any cell."""
    cells, walls = np.flatnonzero(floor), np.flatnonzero(~floor)
    out = []
    for _ in range(n):
        items = rng.choice(walls, 5)
        k = rng.integers(0, 4)
        items[:k] = rng.choice(cells, k)
        mates, s = rng.choice(cells, 2), rng.choice(cells)
        pm = np.where(floor, 0, 1)
        pm[items] = 3
        pm[mates] = 2
        pm[s] = 2
        t = rng.integers(49) if rng.random() < 0.7 else rng.choice(np.flatnonzero(pm != 0))
        out.append((pm, s, t, mates, items))
    return tuple(np.array(x) for x in zip(*out))


def test_search_matches_a_plain_heapq_search():
    """The fixed-array heap emulation equals Python's heapq with the original's non-strict order."""
    rng = np.random.default_rng(0)
    floor = np.zeros((7, 7), bool)
    floor[1:6, 1:6] = True
    floor[rng.random((7, 7)) < 0.1] = False  # some extra walls
    pms, s, t, _, _ = _random_belief_maps(rng, N_LANES, floor.reshape(-1))
    ref = [planner.plan_reference(pm.reshape(7, 7), divmod(int(a), 7), divmod(int(b), 7)) for pm, a, b in zip(pms, s, t)]
    got = search(jnp.asarray((pms == 0) | (pms == 2)), jnp.asarray(pms == 2), s, t)
    np.testing.assert_array_equal(np.asarray(got), ref)
    assert len(set(ref)) == 5  # every direction and "no path" occur


def test_table_planner_equals_the_search_batched_and_unbatched():
    """Table answers plus the chunked fallback (under vmap) and the per-agent fallback (unbatched)
    give exactly the search's answers, on belief maps with and without phantom items."""
    env = envs_jax.make("overcooked-C")
    rng = np.random.default_rng(1)
    floor = env.layout.floor.reshape(-1)
    pms, s, t, mates, items = _random_belief_maps(rng, N_LANES, floor)
    passable, agent = (pms == 0) | (pms == 2), pms == 2
    expected = np.asarray(search(passable, agent, s, t))
    args = [x.reshape(256, 3, *x.shape[1:]) for x in (s, t, mates, items, np.ones(len(s), bool))]
    batched = jax.jit(jax.vmap(env._plan))(*args)
    np.testing.assert_array_equal(np.asarray(batched).reshape(-1), expected)
    unbatched = jax.jit(env._plan)
    for b in range(0, 256, 37):
        np.testing.assert_array_equal(np.asarray(unbatched(*(x[b] for x in args))), expected[3 * b: 3 * b + 3])
    # The search-only planner of ``fast_planner=False`` builds the same belief maps.
    search_only = jax.jit(jax.vmap(make_exact_planner(env.layout.floor)))(*args)
    np.testing.assert_array_equal(np.asarray(search_only).reshape(-1), expected)
    # Both paths were exercised: most answers come from the table, some need the search.

    table = build_table("C")
    fi, n = table.floor_index, table.n_floor
    lo, hi = np.sort(fi[mates], axis=1).T
    entry = table.entries[(fi[s] * 49 + t) * (n * (n + 1) // 2) + pair_index(lo, hi, n)]
    blocked = ((~passable[:, table.floor_cells]) << np.arange(n)).sum(1)
    from_table = (entry >> 3) & blocked == 0
    assert 0.5 < from_table.mean() < 1.0
    np.testing.assert_array_equal((entry & 7)[from_table], expected[from_table])


# --- jit / vmap / Python loop, retracing, invariants ---------------------------------------------


@pytest.fixture(scope="module")
def rollouts_a(env):
    """Map A, one compiled call: 32 random 200-step episodes (no auto-reset) and, as lane 32,
    the scripted policy's episode."""
    keys = jax.random.split(jax.random.key(7), 33)

    def mixed(env, state, key, scripted):
        return jnp.where(scripted, scripted_actions(env, state), random_policy(key, env.observe(state)))

    def lane(key, scripted):
        return scan_rollout(env, key, 200, policy=lambda e, st, k: mixed(e, st, k, scripted))

    ts, prims = jax.jit(jax.vmap(lane))(keys, jnp.arange(33) == 32)
    return keys, ts, prims


@pytest.fixture(scope="module")
def random_rollouts(rollouts_a):
    keys, ts, prims = rollouts_a
    return keys[:32], jax.tree_util.tree_map(lambda x: x[:32], ts), prims[:32]


def test_python_loop_of_jitted_steps_equals_the_batched_scan_ignores_keys_and_never_retraces(env, random_rollouts):
    keys, batched, _ = random_rollouts
    traces = []

    @jax.jit
    def step(key, state, actions):
        traces.append(1)
        return env.step(key, state, actions)

    policy = jax.jit(random_policy)

    for e in (0, 5):
        key = keys[e]
        state, ts = env.reset(key)
        out = [ts]
        for k in jax.random.split(key, 200):
            # Another step key than the scan's: the env has no randomness, so nothing changes.
            state, ts = step(jax.random.fold_in(k, 1), state, policy(k, ts))
            out.append(ts)
        single = jax.tree_util.tree_map(lambda *x: np.stack(x), *out)
        for a, b in zip(jax.tree_util.tree_leaves(single), jax.tree_util.tree_leaves(batched)):
            np.testing.assert_array_equal(a, np.asarray(b)[e])
    assert len(traces) == 1


def test_nested_vmap_equals_flat_vmap(env, random_rollouts):
    """vmap over seeds of vmap over envs (the planner's batching rule then runs nested)."""
    keys, flat_ts, _ = random_rollouts
    nested, _ = jax.jit(jax.vmap(jax.vmap(lambda k: scan_rollout(env, k, 200))))(keys[:8].reshape(2, 4))
    for a, b in zip(jax.tree_util.tree_leaves(nested), jax.tree_util.tree_leaves(flat_ts)):
        np.testing.assert_array_equal(np.asarray(a).reshape(8, *np.shape(a)[2:]), np.asarray(b)[:8])


def test_obs_real_obs_macro_and_mac_done_are_consistent(random_rollouts):
    _, ts, _ = random_rollouts
    done = np.asarray(ts.mac_done)
    obs_m, obs_r = np.asarray(ts.obs_macro), np.asarray(ts.obs_real)
    assert done[:, 0].all()
    np.testing.assert_array_equal(obs_m[done], obs_r[done])
    busy = ~done[:, 1:]
    np.testing.assert_array_equal(obs_m[:, 1:][busy], obs_m[:, :-1][busy])
    assert (obs_m[:, 1:][busy] != obs_r[:, 1:][busy]).any()  # frozen observations really are stale
    # Each agent always sees itself; the task one-hot is constant.
    for i in range(3):
        assert (obs_r[:, :, i, 19 + 2 * i: 21 + 2 * i] > 0).all()
    np.testing.assert_array_equal(obs_r[..., 25:], np.broadcast_to(np.eye(7)[6], obs_r[..., 25:].shape))


def test_t_m_counts_progress_and_busy_agents_keep_their_macro_action(random_rollouts):
    _, ts, prims = random_rollouts
    done, t_m, mac = (np.asarray(x) for x in (ts.mac_done, ts.t_m, ts.mac))
    prev_done = done[:, :-1]
    np.testing.assert_array_equal(t_m[:, 1:], np.where(prev_done, 0, t_m[:, :-1] + 1))
    np.testing.assert_array_equal(mac[:, 1:][~prev_done], mac[:, :-1][~prev_done])
    # stay and the direction macros always end after one step; others can run for many.
    one_step = np.isin(mac[:, 1:], [0, 10, 11, 12, 13])
    assert done[:, 1:][one_step].all() and t_m.max() > 10
    assert set(np.unique(np.asarray(prims))) == {0, 1, 2, 3, 4}


def test_rewards_truncation_and_termination(env, random_rollouts):
    _, ts, _ = random_rollouts
    r = np.asarray(ts.reward)[:, 1:]
    t, term, trunc = np.asarray(ts.t), np.asarray(ts.terminated), np.asarray(ts.truncated)
    # Every reward is -0.1 + 10 chops - 5 wrong deliveries (+200 on termination).
    events = np.round((r + 0.1) * 10).astype(int)
    np.testing.assert_allclose(r, events / 10 - 0.1, atol=1e-5)
    assert ((events % 50 == 0) | term[:, 1:]).all() and (events < 0).any() and (events > 0).any()
    np.testing.assert_array_equal(trunc, (t >= env.spec.horizon) & ~term)
    np.testing.assert_array_equal(np.asarray(ts.state)[:, 0], np.broadcast_to(np.asarray(ts.state)[0, 0], (32, 32)))


# --- scripted policy: the learning ceiling ----------------------------------------------------------


SCRIPTED = {"A": (35, 226.5), "B": (44, 225.6), "C": (44, 225.6)}  # steps to the delivery, return


@pytest.mark.parametrize("map_name", ["A", "B", "C"])
def test_scripted_policy_delivers_the_salad(map_name, rollouts_a):
    if map_name == "A":
        ts = jax.tree_util.tree_map(lambda x: x[32], rollouts_a[1])
    else:
        env = envs_jax.make(f"overcooked-{map_name}")
        ts, _ = jax.jit(lambda k: scan_rollout(env, k, 200, policy=lambda e, st, _: scripted_actions(e, st)))(KEY)
    term = np.asarray(ts.terminated)
    assert term.any()
    n = int(np.argmax(term))
    rewards = np.asarray(ts.reward)[1: n + 1]
    assert (n, round(float(rewards.sum()), 3)) == SCRIPTED[map_name]
    chops = np.round((rewards[:-1] + 0.1) / 10).astype(int)  # three chop rewards, nothing wrong delivered
    assert rewards[-1] == pytest.approx(199.9, abs=1e-4) and chops.sum() == 3 and (chops >= 0).all()


# --- metadata, overrides, rendering, errors ---------------------------------------------------------


def test_spec_metadata():
    for name, n_act in (("A", 14), ("B", 15), ("C", 15)):
        s = envs_jax.make(f"overcooked-{name}").spec
        assert (s.name, s.num_agents, s.num_actions, s.obs_sizes, s.state_dim) == (
            f"overcooked-{name}", 3, (n_act,) * 3, (32,) * 3, 32,
        )
        assert (s.horizon, s.discount) == (200, 0.99)
        assert s.action_names[0][:10] == (
            "stay", "get tomato", "get lettuce", "get onion", "get plate 1", "get plate 2",
            "go to knife 1", "go to knife 2", "deliver", "chop",
        )
        assert s.action_names[0][-4:] == ("right", "down", "left", "up")
    assert envs_jax.make("overcooked-B").spec.action_names[1][10] == "go to counter"


def test_overrides_change_rewards_and_horizon():
    from envs_jax.overcooked.physics import Events

    env = envs_jax.make("overcooked-A", reward_step=-1.0, reward_wrong=-7.0, horizon=3)
    assert env.spec.horizon == 3 and env.config.reward_chop == 10.0 and env.config.reward_step == -1.0
    two_chops_one_wrong = Events(jnp.int32(2), jnp.int32(1), jnp.int32(0))
    assert float(env.reward(two_chops_one_wrong)) == pytest.approx(-1.0 + 20.0 - 7.0)
    state, _ = env.reset(KEY)
    assert [bool(env.observe(state.replace(t=jnp.int32(t))).truncated) for t in (2, 3)] == [False, True]


def test_render_shows_the_kitchen(env):
    state, _ = env.reset(KEY)
    text = env.render(state)
    for token in ("A1", "A2", "A3", "K1", "K2", "D", "t0", "l0", "o0", "P1", "P2", "t = 0"):
        assert token in text
    rows = text.splitlines()
    assert rows[2].split()[0] == "1" and rows[2].split()[1] == "K1"  # row x=1 starts with knife 1


@pytest.mark.parametrize(
    "name,overrides,needle",
    [
        ("overcooked-D", {}, "valid Overcooked names: overcooked-A, overcooked-B, overcooked-C"),
        ("overcooked-a", {}, "valid Overcooked names"),
        ("overcooked", {}, "valid names"),
        ("overcooked-A", {"horizn": 50}, "valid overrides"),
        ("overcooked-A", {"horizon": 50.0}, "must be of type int"),
        ("overcooked-A", {"reward_chop": "10"}, "must be of type float"),
        ("overcooked-A", {"horizon": 0}, "horizon"),
        ("overcooked-A", {"discount": 1.5}, "discount"),
        ("overcooked-A", {"obs_radius": 0}, "obs_radius"),
    ],
)
def test_make_rejects_bad_input(name, overrides, needle):
    with pytest.raises(ValueError, match=needle):
        envs_jax.make(name, **overrides)


def test_step_rejects_bad_actions(env):
    state, _ = env.reset(KEY)
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        env.step(KEY, state, jnp.zeros(2, jnp.int32))
    with pytest.raises(ValueError, match="integers"):
        env.step(KEY, state, jnp.zeros(3, jnp.float32))
    with pytest.raises(ValueError, match="agent 2 is free and sent action 14"):
        env.step(KEY, state, jnp.array([0, 0, 14]))  # 14 actions on map A
    with pytest.raises(ValueError, match="agent 0 is free and sent action -1"):
        env.step(KEY, state, jnp.array([-1, 0, 0]))


def test_layouts_match_the_spec_tables():
    a, b, c = (layouts.build_layout(m) for m in "ABC")
    assert a.floor.sum() == 25 and b.floor.sum() == 20 and c.floor.sum() == 21
    assert b.counter_cells.tolist() == [[3, 3], [2, 3], [4, 3], [1, 3], [5, 3]]
    assert c.counter_cells.tolist() == [[3, 3], [2, 3], [4, 3], [1, 3]] and c.floor[5, 3]
    with pytest.raises(ValueError, match="valid maps"):
        layouts.build_layout("D")
