"""The decentralised value baselines and the value learners' schedule against plain-Python references written
here: the Mac-CERT → Mac-JERT alignment, the MacDec-Q and Mac-Dec-MADDRQN losses (step-by-step nets, brute-force
conditional argmax), the trainer's train_every_steps / target_update_steps / Polyak schedule, and config errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from _learner_helpers import episode_slot as learner_episode_slot
from _value_references import available_argmax, brute_force_conditional_argmax, stack

import envs_jax
from jaxmac import trainer
from jaxmac.algos.families import centralised, decentralised
from jaxmac.algos.registry import REGISTRY, make_algorithm
from jaxmac.algos.base import Progress
from jaxmac.buffer import views, windows
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.networks.drqn import DRQN, AgentDRQN

H, GAMMA, L = 24, 0.9, 5


# --- helpers ------------------------------------------------------------------------------------------------------


def episode_slot(seed, length, end="truncated", **kwargs):
    """A synthetic episode slot of H rows (``_learner_helpers.episode_slot``); ``last_done`` (bool[n]) forces the
    pattern of the last step (e.g. so that a terminal step is kept by some agent)."""
    return learner_episode_slot(seed, length, end, h=H, **kwargs)


_window = jax.jit(windows.window_views, static_argnums=3)


def store_all(store, slots):
    """Stacked stored views of the slots (one compiled store for the batch)."""
    return jax.jit(jax.vmap(store))(stack(slots))


def window_steps(info, first):
    """The valid steps of the window ``first … first+L−1`` in order."""
    return range(max(first, 0), min(first + L, info["length"]))


def returns_since(info, start, tau, gamma):
    return sum(gamma ** j * float(info["reward"][start + j]) for j in range(tau))


def terminal_step(info, t):
    return info["end"] == "terminated" and t == info["length"] - 1


def agent_q_sequences(net, params, i, xs, n):
    """Agent i's net run one decision at a time from a zero state (the other agents get zero inputs: their
    parameters are separate, so agent i's outputs do not depend on them)."""
    step = _agent_step(net)
    h, out = jnp.zeros((n, net.hidden)), []
    for x in xs:
        inp = np.zeros((1, n, len(x)), np.float32)
        inp[0, i] = x
        q, h = step(params, jnp.asarray(inp), jnp.zeros((1,), bool), h)
        out.append(np.asarray(q[0, i]))
    return out


def joint_q_sequences(net, params, xs):
    """The centralised net run one joint decision at a time from a zero state."""
    step = _agent_step(net)
    h, out = jnp.zeros((net.hidden,)), []
    for x in xs:
        q, h = step(params, jnp.asarray(x, jnp.float32).reshape(1, -1), jnp.zeros((1,), bool), h)
        out.append(np.asarray(q[0]))
    return out


_STEPS = {}


def _agent_step(net):
    if net not in _STEPS:
        _STEPS[net] = jax.jit(net.apply)
    return _STEPS[net]


def agent_entries(info, first, i):
    """Agent i's Mac-CERT entries of a window: (step, start, tau)."""
    t_m = info["t_m"]
    return [(t, t - int(t_m[t, i]), int(t_m[t, i]) + 1) for t in window_steps(info, first) if info["mac_done"][t, i]]


def joint_entries(info, first):
    """The window's Mac-JERT entries: (step, start, tau)."""
    t_m = info["t_m"]
    return [(t, t - int(t_m[t].min()), int(t_m[t].min()) + 1) for t in window_steps(info, first)
            if info["mac_done"][t].any()]


# --- 1. Mac-CERT → Mac-JERT alignment ------------------------------------------------------------------------


@pytest.mark.parametrize("n", [2, 3])
def test_cert_to_jert_index_equals_a_running_index(n):
    cases = [(10 * n + 0, 24, "none", 0.35), (10 * n + 1, 17, "terminated", 0.5), (10 * n + 2, 9, "truncated", 0.2),
             (10 * n + 3, 1, "terminated", 0.6), (10 * n + 4, 20, "truncated", 0.8)]
    built = [episode_slot(seed, length, end, n=n, p=p) for seed, length, end, p in cases]
    stored = store_all(windows.store_views(jert=True, cert=True), [slot for slot, _ in built])
    idx, firsts = [], []
    for e, (_, info) in enumerate(built):  # every window of every episode: negative and positive first steps
        for first in range(-(L - 1), info["length"]):
            idx.append(e)
            firsts.append(first)
    batch = _window(stored, jnp.asarray(idx, jnp.int32), jnp.asarray(firsts, jnp.int32), L)
    cert, jert = batch.cert, batch.jert
    got = np.asarray(jax.jit(views.cert_to_jert_index)(cert.step, cert.mask, jert.step, jert.mask))
    c_step, c_mask, j_step = np.asarray(cert.step), np.asarray(cert.mask), np.asarray(jert.step)
    checked = shifted = 0
    for b, (e, first) in enumerate(zip(idx, firsts)):
        info = built[e][1]
        counter, entry = 0, [0] * n
        for t in window_steps(info, first):
            for i in range(n):
                if info["mac_done"][t, i]:
                    k = entry[i]
                    assert c_mask[b, i, k] and c_step[b, i, k] == t, (b, i, k)
                    assert got[b, i, k] == counter, (b, first, i, k, got[b, i, k], counter)
                    assert j_step[b, counter] == t  # the joint entry it points at is at the same step
                    checked += 1
                    shifted += counter > 0
                    entry[i] += 1
            counter += bool(info["mac_done"][t].any())
        for i in range(n):
            assert not c_mask[b, i, entry[i]:].any()
            assert (got[b, i, entry[i]:] == 0).all()
    assert checked > 100 and shifted > 50  # many entries, most of them not at the window's first joint entry


# --- 2. MacDec-Q's hysteretic double-Q loss ---------------------------------------------------------------


def macdec_reference(net, params, target, cases, firsts, beta, gamma, n, next_action=None):
    """Per agent the mean over its Mac-CERT entries of w·(Q − y)², w = β² where Q > y, summed over agents.
    ``next_action(b, i, t, q_online_next)`` picks the bootstrap action (default: the online available argmax)."""
    squared = [[] for _ in range(n)]
    for b, ((_, info), first) in enumerate(zip(cases, firsts)):
        obs = info["obs_macro"]
        for i in range(n):
            entries = agent_entries(info, first, i)
            if not entries:
                continue
            xs = [obs[start, i] for _, start, _ in entries] + [obs[entries[-1][0] + 1, i]]
            q_online = agent_q_sequences(net, params, i, xs, n)
            q_target = agent_q_sequences(net, target, i, xs, n)
            for k, (t, start, tau) in enumerate(entries):
                if next_action is None:
                    a = available_argmax(q_online[k + 1], info["avail"][t + 1, i])
                else:
                    a = next_action(b, i, t, q_online[k + 1])
                boot = 0.0 if terminal_step(info, t) else gamma ** tau * float(q_target[k + 1][a])
                delta = float(q_online[k][info["mac"][t, i]]) - (returns_since(info, start, tau, gamma) + boot)
                squared[i].append((beta ** 2 if delta > 0 else 1.0) * delta ** 2)
    return sum(np.mean(s) for s in squared if s), squared


@pytest.fixture(scope="module")
def macdec_case():
    n = 2
    net = AgentDRQN(mlp=(6, 6), hidden=5, out=4)
    init = jax.jit(lambda key: decentralised.init_agent_drqn(net, key, n, 3))
    params, target = init(jax.random.key(0)), init(jax.random.key(1))
    specs = [(30, 24, "none", None), (31, 11, "terminated", [True, True]), (32, 16, "truncated", None),
             (33, 20, "terminated", [True, False]), (34, 9, "truncated", [False, True])]
    cases = [episode_slot(seed, length, end, last_done=done) for seed, length, end, done in specs]
    firsts = [-2, 7, 10, 16, 5]  # window 1 ends on the terminal step, window 3 holds one; window 0 starts at -2
    stored = store_all(windows.store_views(jert=False, cert=True), [slot for slot, _ in cases])
    batch = _window(stored, jnp.arange(len(cases)), jnp.asarray(firsts, jnp.int32), L)
    return net, params, target, cases, firsts, batch


@pytest.mark.parametrize("beta", [1.0, 0.3])
def test_macdec_q_loss_equals_a_step_by_step_reference(macdec_case, beta):
    net, params, target, cases, firsts, batch = macdec_case
    loss, metrics, view = jax.jit(decentralised.hysteretic_double_q_loss, static_argnums=0)(
        net, params, target, batch, beta)
    want, squared = macdec_reference(net, params, target, cases, firsts, beta, GAMMA, 2)
    counts = [len(s) for s in squared]
    np.testing.assert_allclose(float(loss), want, rtol=2e-5)
    assert round(float(metrics["cert_entries"]) * len(cases)) == sum(counts)
    np.testing.assert_array_equal(np.asarray(view.mask).sum((0, 2)), counts)
    # the fixture holds kept terminal steps (no bootstrap there)
    assert any(terminal_step(info, t) for (_, info), first in zip(cases, firsts) for i in range(2)
               for t, _, _ in agent_entries(info, first, i))
    if beta != 1.0:
        plain, _ = macdec_reference(net, params, target, cases, firsts, 1.0, GAMMA, 2)
        assert abs(plain - want) > 1e-3 * plain  # β matters on this batch
    # per agent a mean, then the sum (one net per agent): not n × the mean over all entries when counts differ
    assert counts[0] != counts[1]
    pooled = 2 * np.mean(squared[0] + squared[1])
    assert abs(pooled - want) > 1e-3 * want


# --- 3. Mac-Dec-MADDRQN: decentralised targets follow the centralised conditional argmax ---------------------


def maddrqn_reference(config, env, params, target, cases, firsts, episodes, dec_choice="centralised"):
    """(cen_loss, dec_loss) written out; ``dec_choice``: 'centralised' (agent i's component of the conditional
    argmax at the joint decision after its termination), or the plausible bugs 'own' (the agent's online
    argmax, MacDec-Q) and 'next_joint' (the component at the joint entry after that one)."""
    s, spec = config.algo, env.spec
    counts, n, gamma = spec.num_actions, spec.num_agents, spec.discount
    cen = DRQN(mlp=s.cen_mlp_sizes, hidden=s.cen_rnn_size, out=int(np.prod(counts)))
    dec = AgentDRQN(mlp=s.mlp_sizes, hidden=s.rnn_size, out=spec.max_actions)
    cen_sq, best = [], {}
    for b, ((_, info), first) in enumerate(zip(cases, firsts)):
        obs = info["obs_macro"]
        entries = joint_entries(info, first)
        if not entries:
            continue
        xs = [obs[start].reshape(-1) for _, start, _ in entries] + [obs[entries[-1][0] + 1].reshape(-1)]
        q_online = joint_q_sequences(cen, params["cen"], xs)
        q_target = joint_q_sequences(cen, target["cen"], xs)
        steps = [t for t, _, _ in entries]
        for k, (t, start, tau) in enumerate(entries):
            m = tuple(int(a) for a in info["mac"][t])
            a_star = brute_force_conditional_argmax(q_online[k + 1], info["avail"][t + 1], info["mac_done"][t],
                                                    info["mac"][t], counts)
            best[b, t] = a_star
            boot = 0.0 if terminal_step(info, t) else gamma ** tau * float(q_target[k + 1][np.ravel_multi_index(
                a_star, counts)])
            y = returns_since(info, start, tau, gamma) + boot
            cen_sq.append((float(q_online[k][np.ravel_multi_index(m, counts)]) - y) ** 2)
        if dec_choice == "next_joint":  # the joint entry after the aligned one (the last one: itself)
            for k, t in enumerate(steps):
                best[b, t, "next"] = best[b, steps[min(k + 1, len(steps) - 1)]]

    def next_action(b, i, t, q_next):
        if dec_choice == "own":
            return available_argmax(q_next, cases[b][1]["avail"][t + 1, i])
        return (best[b, t, "next"] if dec_choice == "next_joint" else best[b, t])[i]

    frac = np.clip((episodes - config.start_train_episodes) / s.hysteresis_episodes, 0.0, 1.0)
    beta = s.hysteresis_start + frac * (s.hysteresis_end - s.hysteresis_start)
    dec_loss, _ = macdec_reference(dec, params["dec"], target["dec"], cases, firsts, beta, gamma, n, next_action)
    return float(np.mean(cen_sq)), dec_loss, beta


@pytest.fixture(scope="module")
def maddrqn_case():
    config = scenario_config("boxpushing-6x6", "macdec_ddrqn", tiny=True)
    env = make_env(config)
    algo = make_algorithm(config, env)
    init = jax.jit(algo.init_params)
    params, target = init(jax.random.key(2)), init(jax.random.key(3))
    spec = env.spec
    shape = dict(obs_dim=spec.obs_dim, num_actions=spec.max_actions, state_dim=spec.state_dim, gamma=spec.discount)
    specs = [(40, 24, "none", None, 0.3), (41, 13, "terminated", [True, True], 0.4),
             (42, 18, "truncated", None, 0.5), (43, 21, "terminated", [False, True], 0.3)]
    cases = [episode_slot(seed, length, end, p=p, last_done=done, **shape) for seed, length, end, done, p in specs]
    firsts = [-3, 9, 4, 17]
    stored = store_all(algo.store, [slot for slot, _ in cases])
    batch = _window(stored, jnp.arange(len(cases)), jnp.asarray(firsts, jnp.int32), L)
    return config, env, algo, params, target, cases, firsts, batch


def test_maddrqn_decentralised_targets_take_the_centralised_argmax(maddrqn_case):
    config, env, algo, params, target, cases, firsts, batch = maddrqn_case
    episodes = 1000
    progress = Progress(episodes=jnp.int32(episodes), env_steps=jnp.int32(20_000), updates=jnp.int32(1500))
    loss, metrics = jax.jit(algo.loss)(params, target, batch, jax.random.key(0), progress)
    cen_loss, dec_loss, beta = maddrqn_reference(config, env, params, target, cases, firsts, episodes)
    assert 0.2 < beta < 0.4
    np.testing.assert_allclose(float(metrics["hysteresis"]), beta, rtol=1e-6)
    np.testing.assert_allclose(float(metrics["cen_loss"]), cen_loss, rtol=2e-5)
    np.testing.assert_allclose(float(metrics["dec_loss"]), dec_loss, rtol=2e-5)
    np.testing.assert_allclose(float(loss), cen_loss + dec_loss, rtol=2e-5)
    # the reference discriminates: MacDec-Q's own argmax, or the following joint entry, give other losses
    for wrong in ("own", "next_joint"):
        _, other, _ = maddrqn_reference(config, env, params, target, cases, firsts, episodes, wrong)
        assert abs(other - dec_loss) > 1e-4 * dec_loss, wrong


# --- 4. the trainer's schedule: train_every_steps, target_update_steps, Polyak ------------------------------


def _tiny_maccen(**values):
    base = dict(horizon=20, episodes=32, num_envs=4, train_every_steps=7, target_update_steps=100,
                eval_every_episodes=1000, eval_episodes=1)
    return scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(**{**base, **values})


def _leaves(tree):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(tree)]


def _equal(a, b):
    return all(np.array_equal(x, y) for x, y in zip(_leaves(a), _leaves(b)))


def _run_rounds(config, rounds):
    env = make_env(config)
    algo = make_algorithm(config, env)
    train = trainer.make_train(config, env, algo, rounds_per_chunk=1)
    chunk = jax.jit(train.train_chunk)
    states, rows = [jax.jit(train.init)(jax.random.key(7))], []
    for _ in range(rounds):
        state, metrics = chunk(states[-1])
        states.append(state)
        rows.append({k: np.asarray(v)[0] for k, v in metrics.items()})
    return algo, states, rows


def test_trainer_train_every_steps_and_hard_target_copies():
    config = _tiny_maccen()
    rounds = 8
    _, states, rows = _run_rounds(config, rounds)
    every, period, min_episodes = config.train_every_steps, config.target_update_steps, config.batch_size
    before, total, copies, kept = 0, 0, 0, 0
    for r, row in enumerate(rows):
        after = int(row["env_steps"])
        assert after == int(states[r + 1].env_steps) and after > before
        started = int(row["episodes"]) >= min_episodes  # the ring holds a batch (start_train_episodes = 0)
        want = after // every - before // every if started else 0
        assert int(row["round_updates"]) == want, (r, before, after)
        total += want
        assert int(row["updates"]) == total == int(states[r + 1].updates)
        if not started:
            assert np.isnan(row["loss"])
        new, old = states[r + 1], states[r]
        if after // period > before // period:  # a hard copy of this round's final params
            assert _equal(new.target_params, new.params), r
            copies += 1
        else:
            assert _equal(new.target_params, old.target_params), r
            if total:
                assert not _equal(new.target_params, new.params), r
                kept += 1
        before = after
    # the steps collected before the ring held a batch count for nothing
    assert rows[0]["round_updates"] == 0 and rows[0]["env_steps"] // every > 0
    assert copies >= 2 and kept >= 2  # both kinds of round happened after training started


def test_optax_incremental_update_is_the_polyak_step():
    rng = np.random.default_rng(0)
    tree = lambda: {"a": jnp.asarray(rng.normal(size=(3, 2)), jnp.float32),  # noqa: E731
                    "b": jnp.asarray(rng.normal(size=4), jnp.float32)}
    params, target = tree(), tree()
    new = optax.incremental_update(params, target, 0.1)
    for got, p, t in zip(_leaves(new), _leaves(params), _leaves(target)):
        np.testing.assert_allclose(got, 0.1 * p + 0.9 * t, rtol=1e-6, atol=1e-7)


def test_trainer_polyak_target_follows_each_gradient_step():
    config = _tiny_maccen(episodes=8, target_polyak=0.1, train_every_steps=0, updates_per_round=3)
    algo, states, rows = _run_rounds(config, 2)
    # round 1: 4 episodes < batch_size, no update, the target stays the initial copy
    assert int(rows[0]["round_updates"]) == 0 and _equal(states[1].target_params, states[0].target_params)
    assert _equal(states[1].params, states[0].params)
    # round 2: 3 gradient steps, each followed by t <- 0.9 t + 0.1 p
    before, after = states[1], states[2]
    assert int(rows[1]["round_updates"]) == 3 and int(after.updates) == 3
    assert not _equal(after.target_params, before.target_params)
    assert not _equal(after.target_params, after.params)
    # the recursion replayed: the round's update keys, batches from the ring after collection
    _, _, k_update, _ = jax.random.split(before.key, 4)
    update, sample = jax.jit(algo.update), jax.jit(algo.sample)
    params, target, opt_state = before.params, before.target_params, before.opt_state
    progress = Progress(episodes=before.episodes, env_steps=before.env_steps, updates=before.updates)
    for key in jax.random.split(k_update, 3):
        k_sample, k_loss = jax.random.split(key)
        batch = sample(after.ring, None, k_sample)
        params, opt_state, _ = update(params, target, opt_state, batch, k_loss, progress)
        target = jax.tree_util.tree_map(lambda t, p: 0.9 * t + 0.1 * p, target, params)
        progress = progress.replace(updates=progress.updates + 1)
    for got, want in zip(_leaves(after.params), _leaves(params)):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    for got, want in zip(_leaves(after.target_params), _leaves(target)):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    # and it is not a hard copy nor a single Polyak step per round
    one_step = jax.tree_util.tree_map(lambda t, p: 0.9 * t + 0.1 * p, before.target_params, after.params)
    assert max(np.abs(a - b).max() for a, b in zip(_leaves(one_step), _leaves(after.target_params))) > 1e-5


# --- 5. configuration errors ----------------------------------------------------------------------------------


def test_a_key_of_another_algorithm_names_its_owner():
    config = scenario_config("boxpushing-6x6", "maccen_ddrqn")
    with pytest.raises(ValueError, match="tomacvf") as err:
        config.override_strings(["overestimate_weight=0.5"])
    assert "maccen_ddrqn" in str(err.value)
    with pytest.raises(ValueError, match="tomacvf"):
        config.override(overestimate_weight=0.5)
    # a key two algorithms share is routed to the right block when it is this algorithm's own
    assert config.override_strings(["rnn_size=16"]).algo.rnn_size == 16


def test_an_unknown_algorithm_lists_the_valid_ones():
    for make in (lambda: scenario_config("boxpushing-6x6", "macdec_qq"),
                 lambda: scenario_config("boxpushing-6x6", "maccen_ddrqn").override(algorithm="macdec_qq"),
                 lambda: scenario_config("boxpushing-6x6").override_strings(["algorithm=macdec_qq"])):
        with pytest.raises(ValueError) as err:
            make()
        message = str(err.value)
        assert "macdec_qq" in message
        for name in REGISTRY:
            assert name in message, (name, message)


def test_check_joint_space_names_the_size_and_the_scenarios_that_fit():
    env = envs_jax.make("boxpushing-6x6")
    assert centralised.check_joint_space(env, 64, "maccen_ddrqn") == 64
    with pytest.raises(ValueError) as err:
        centralised.check_joint_space(env, 63, "maccen_ddrqn")
    message = str(err.value)
    assert "64" in message and "maccen_ddrqn" in message and "8 x 8" in message
    assert "none" in message.split("Within the limit:")[-1]
    with pytest.raises(ValueError) as err:
        centralised.check_joint_space(envs_jax.make("overcooked-A"), 100, "macdec_ddrqn")
    message = str(err.value)
    assert "2744" in message
    fits = message.split("Within the limit:")[-1]
    assert "boxpushing-6x6 (64)" in fits and "warehouse-A (96)" in fits and "overcooked" not in fits
    # the factories refuse it too
    config = scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(max_joint_actions=63)
    with pytest.raises(ValueError, match="64"):
        make_algorithm(config, make_env(config))
