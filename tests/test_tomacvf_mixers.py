"""ToMacVF's other mixers (QPLEX, QTRAN) and the literal two-step update (``sequential_updates``, D8).

* The conditional target (D9) picks the joint action it claims: for QPLEX the argmax of the online Q_tot over the
  admissible joint actions (found by brute force over every joint action), for QTRAN the argmax of Σ_i Q_i; its value
  is the target mixer's at that action (QTRAN's Q_jt from a plain-NumPy forward written here).
* QTRAN's constraint errors against a plain-NumPy reference.
* ``sequential_updates`` equals a step on the micro-TD loss followed by a step on λ·macro-TD at the updated
  parameters (gradients from ``jax.grad`` of the loss metrics), and skips the second step when the batch holds no
  completed macro-action.
* ``--set mixer=qplex`` / ``mixer=qtran`` train end to end; settings that cannot be served are refused.
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from _learner_helpers import episode_slot, random_params

from jaxmac.algos.base import Progress
from jaxmac.algos.tomacvf import conditional_target, make_tomacvf
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.networks.mixers import Mixer, MixerConfig, init_mixer_params, mix_actions, qtran_penalties
from jaxmac.trainer import make_train

PROGRESS = Progress(episodes=jnp.int32(0), env_steps=jnp.int32(0), updates=jnp.int32(0))
ROWS = 6


def random_mixer(kind, n, actions, state_dim, seed):
    """(config, online weights, target weights) of a mixer with parameters moved away from their initialisation."""
    cfg = MixerConfig(num_agents=n, state_dim=state_dim, kind=kind, hyper_hidden=16, num_actions=actions)
    keys = jax.random.split(jax.random.key(seed), 5)
    cond = jax.random.normal(keys[4], (ROWS, state_dim))
    weights = []
    for k_init, k_noise in ((keys[0], keys[1]), (keys[2], keys[3])):
        params = init_mixer_params(cfg, k_init)
        leaves, tree = jax.tree_util.tree_flatten(params)
        noise = jax.random.split(k_noise, len(leaves))
        params = jax.tree_util.tree_unflatten(
            tree, [x + 0.3 * jax.random.normal(k, x.shape) for x, k in zip(leaves, noise)])
        weights.append((params, Mixer(cfg).apply(params, cond)[0]))
    return cfg, weights[0], weights[1], np.asarray(cond)


def random_rows(n, actions, seed):
    """Per-agent Q tables (online, target), available actions, free agents and running actions for ROWS rows; every
    row has a free agent and a busy one, every free agent an available action."""
    rng = np.random.default_rng(seed)
    q_online, q_target = (rng.normal(size=(ROWS, n, actions)).astype(np.float32) for _ in range(2))
    avail = rng.random((ROWS, n, actions)) < 0.6
    avail[np.arange(ROWS)[:, None], np.arange(n)[None], rng.integers(0, actions, (ROWS, n))] = True
    free = rng.random((ROWS, n)) < 0.5
    free[:, 0], free[:, 1] = True, False
    rng.shuffle(free.T)  # which agents are free differs per row pattern
    running = rng.integers(0, actions, (ROWS, n)).astype(np.int32)
    return q_online, q_target, avail, free, running


def admissible_joint(avail, free, running, joint):
    """bool[C, ROWS]: the candidate joint action keeps every busy agent on its running action and gives every free
    agent an available one."""
    c, n = joint.shape
    ok = np.ones((c, ROWS), bool)
    for i in range(n):
        a = joint[:, i][:, None]
        ok &= np.where(free[None, :, i], avail[np.arange(ROWS)[None], i, a], a == running[None, :, i])
    return ok


def admissible_table(avail, free, running):
    """The per-agent admissible sets, written out: avail for free agents, the running action for busy ones."""
    pinned = np.arange(avail.shape[-1])[None, None] == running[..., None]
    return np.where(free[..., None], avail, pinned)


def qtran_reference(params, cond, joint):
    """Q_jt f32[C, ROWS] and V_jt f32[ROWS] in plain NumPy from the QTRAN mixer's parameters."""
    p = jax.tree_util.tree_map(np.asarray, params["params"])
    relu = lambda x: np.maximum(x, 0.0)  # noqa: E731
    hidden_state = cond @ p["q_state"]["kernel"] + p["q_state"]["bias"]  # [ROWS, G]
    n = joint.shape[1]
    action_part = sum(p["q_actions"][i][joint[:, i]] for i in range(n))  # [C, G]
    h1 = relu(hidden_state[None] + action_part[:, None])
    q_jt = relu(h1 @ p["q_hidden_w"] + p["q_hidden_b"]) @ p["q_out_w"] + p["q_out_b"]
    v = relu(cond @ p["v"]["hidden"]["kernel"] + p["v"]["hidden"]["bias"]) @ p["v"]["out"]["kernel"] + p["v"]["out"]["bias"]
    return q_jt, v[:, 0]


@pytest.mark.parametrize("n,actions", [(2, 8), (3, 14)])  # Box Pushing, Overcooked
def test_qplex_conditional_target_is_the_argmax_of_q_tot_over_admissible_joint_actions(n, actions):
    cfg, (_, w_online), (_, w_target), _ = random_mixer("qplex", n, actions, 7, seed=n)
    q_online, q_target, avail, free, running = random_rows(n, actions, seed=n)
    value, joint = jax.jit(conditional_target)(q_online, q_target, w_target, avail, free, running)
    candidates = np.array(list(itertools.product(range(actions), repeat=n)), np.int32)  # [C, n]
    allowed = admissible_joint(avail, free, running, candidates)
    table = admissible_table(avail, free, running)
    q_tot = np.asarray(jax.jit(mix_actions)(w_online, q_online, jnp.asarray(candidates)[:, None], table))  # [C, ROWS]
    assert (allowed.sum(0) > 1).all()  # a real choice on every row
    gaps = []
    for r in range(ROWS):
        best = np.argmax(np.where(allowed[:, r], q_tot[:, r], -np.inf))
        np.testing.assert_array_equal(np.asarray(joint[r]), candidates[best])
        scores = np.sort(q_tot[allowed[:, r], r])
        gaps.append(scores[-1] - scores[-2])
    assert min(gaps) > 1e-4  # the argmax is not a tie
    # the value is the target mixer's Q_tot at that joint action
    expected = mix_actions(w_target, q_target, joint, table)
    np.testing.assert_allclose(np.asarray(value), np.asarray(expected), rtol=1e-6)


@pytest.mark.parametrize("n,actions", [(2, 8), (3, 14)])
def test_qtran_conditional_target_is_the_argmax_of_the_summed_utilities_valued_by_q_jt(n, actions):
    state_dim = 7
    cfg, _, (params_target, w_target), cond = random_mixer("qtran", n, actions, state_dim, seed=10 + n)
    q_online, q_target, avail, free, running = random_rows(n, actions, seed=10 + n)
    value, joint = jax.jit(conditional_target)(q_online, q_target, w_target, avail, free, running)
    candidates = np.array(list(itertools.product(range(actions), repeat=n)), np.int32)
    allowed = admissible_joint(avail, free, running, candidates)
    summed = q_online[np.arange(ROWS)[None, :, None], np.arange(n)[None, None], candidates[:, None, :]].sum(-1)
    q_jt, _ = qtran_reference(params_target, cond, candidates)
    for r in range(ROWS):
        best = np.argmax(np.where(allowed[:, r], summed[:, r], -np.inf))
        np.testing.assert_array_equal(np.asarray(joint[r]), candidates[best])
        np.testing.assert_allclose(float(value[r]), q_jt[best, r], rtol=1e-5, atol=1e-5)
    # Q_jt is not the sum: the target is QTRAN's rule, not Q_jt's own argmax
    assert not np.allclose(q_jt, summed, atol=1e-2)


def test_qtran_penalties_match_a_numpy_reference():
    n, actions, state_dim = 3, 5, 7
    _, (params, weights), _, cond = random_mixer("qtran", n, actions, state_dim, seed=3)
    rng = np.random.default_rng(3)
    q = rng.normal(size=(ROWS, n, actions)).astype(np.float32)
    taken, greedy = (rng.integers(0, actions, (ROWS, n)).astype(np.int32) for _ in range(2))
    opt, nopt = jax.jit(qtran_penalties)(weights, q, taken, greedy)
    for r in range(ROWS):
        q_jt, v = qtran_reference(params, cond[r:r + 1], np.stack([taken[r], greedy[r]]))
        sum_taken = sum(q[r, i, taken[r, i]] for i in range(n))
        sum_greedy = sum(q[r, i, greedy[r, i]] for i in range(n))
        np.testing.assert_allclose(float(opt[r]), sum_greedy - q_jt[1, 0] + v[0], rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(float(nopt[r]), min(sum_taken - q_jt[0, 0] + v[0], 0.0), rtol=1e-4, atol=1e-5)
    assert (np.asarray(nopt) < 0).any() and (np.asarray(opt) != 0).all()
    # Q_jt is held fixed: the constraint gradient reaches the utilities and V_jt, not Q_jt's own layers
    grads = jax.grad(lambda p: jnp.sum(qtran_penalties(Mixer(MixerConfig(
        num_agents=n, state_dim=state_dim, kind="qtran", hyper_hidden=16, num_actions=actions)).apply(
        p, jnp.asarray(cond))[0], q, taken, greedy)[0] ** 2))(params)["params"]
    assert all(float(jnp.abs(g).max()) == 0 for g in jax.tree_util.tree_leaves(
        {k: v for k, v in grads.items() if k != "v"}))
    assert float(jnp.abs(grads["v"]["out"]["kernel"]).max()) > 0


# --- the two-step update ---------------------------------------------------------------------------------------

def bp_config(**overrides):
    return scenario_config("boxpushing-6x6", tiny=True).override(horizon=20, **overrides)


@pytest.fixture(scope="module")
def bp_batch():
    slots = [episode_slot(s, length, end, obs_dim=5, num_actions=8, state_dim=18, gamma=0.98)[0]
             for s, (length, end) in enumerate([(20, "truncated"), (13, "terminated"), (17, "terminated"),
                                                (20, "truncated")])]
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *slots)


def test_sequential_updates_step_on_micro_then_on_macro_at_the_updated_parameters(bp_batch):
    lam = 0.7
    config = bp_config(sequential_updates=True, macro_loss_weight=lam)
    env = make_env(config)
    algorithm = make_tomacvf(config, env)
    params, target = random_params(algorithm.init_params, 0, 0.2), random_params(algorithm.init_params, 1, 0.2)
    opt_state = algorithm.optimizer.init(params)
    key = jax.random.key(0)
    update = jax.jit(algorithm.update)
    new_params, new_opt_state, metrics = update(params, target, opt_state, bp_batch, key, PROGRESS)

    def metric(name, scale=1.0):
        return lambda p: scale * algorithm.loss(p, target, bp_batch, key, PROGRESS)[1][name]

    def adam_step(objective, p, o):
        updates, o = algorithm.optimizer.update(jax.grad(objective)(p), o, p)
        return optax.apply_updates(p, updates), o

    p1, o1 = jax.jit(lambda p, o: adam_step(metric("micro_loss"), p, o))(params, opt_state)
    p2, _ = jax.jit(lambda p, o: adam_step(metric("macro_loss", lam), p, o))(p1, o1)
    for got, want, before in zip(*(jax.tree_util.tree_leaves(x) for x in (new_params, p2, p1))):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-6)
    moved = max(float(jnp.abs(a - b).max()) for a, b in zip(*(jax.tree_util.tree_leaves(x) for x in (p2, p1))))
    assert moved > 1e-4  # the macro step did something
    assert float(metrics["macro_loss"]) > 0 and float(metrics["grad_norm_macro"]) > 0
    np.testing.assert_allclose(float(metrics["macro_loss"]), float(metric("macro_loss")(p1)), rtol=1e-5)

    # no completed macro-action in the batch: only the micro step
    no_macro = bp_batch.replace(segments=bp_batch.segments.replace(valid=jnp.zeros_like(bp_batch.segments.valid)))
    only_micro, _, metrics = update(params, target, opt_state, no_macro, key, PROGRESS)
    p1_no_macro, _ = jax.jit(lambda p, o: adam_step(
        lambda q: algorithm.loss(q, target, no_macro, key, PROGRESS)[1]["micro_loss"], p, o))(params, opt_state)
    for got, want in zip(*(jax.tree_util.tree_leaves(x) for x in (only_micro, p1_no_macro))):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-6)
    assert float(metrics["macro_loss"]) == 0 and float(metrics["grad_norm_macro"]) == 0


@pytest.mark.parametrize("mixer", ["qplex", "qtran"])
def test_tomacvf_trains_end_to_end_with_qplex_and_qtran(mixer):
    config = bp_config(mixer=mixer, episodes=24, num_envs=8, batch_size=8, buffer_episodes=16,
                       eval_every_episodes=8, eval_episodes=2, target_update_episodes=16, eps_decay_episodes=8)
    env = make_env(config)
    trainer = make_train(config, env, make_tomacvf(config, env), rounds_per_chunk=3)
    state = jax.jit(trainer.init)(jax.random.key(1))
    before = jax.tree_util.tree_flatten_with_path(state.params)[0]
    state, metrics = jax.jit(trainer.train_chunk)(state)
    metrics = jax.device_get(metrics)
    assert np.isfinite(metrics["loss"]).all() and (metrics["loss"] > 0).all()
    assert (metrics["macro_loss"] > 0).any()
    if mixer == "qtran":
        assert (metrics["qtran_opt_loss"] > 0).all() and np.isfinite(metrics["qtran_nopt_loss"]).all()
    unchanged = [jax.tree_util.keystr(path) for (path, a), b in zip(before, jax.tree_util.tree_leaves(state.params))
                 if np.array_equal(a, b)]
    # every parameter (agent nets, ATPG, the mixer's) is trained, except ATPG's agent-attention query and key: with
    # two agents each attends to the only other one (α = 1 whatever the logits, D5), so they get no gradient
    assert sorted(unchanged) == ["['mixer']['params']['atpg']['agents']['key']['kernel']",
                                 "['mixer']['params']['atpg']['agents']['query']['kernel']"]


@pytest.mark.parametrize("overrides,message", [
    (dict(sequential_updates=True, buffer="mac_jert", obs_mode="macro"), "sequential_updates"),
    (dict(qtran_nopt_weight=0.5), "mixer='qtran'"),
    (dict(mixer="qatran"), "'qtran'"),
])
def test_settings_tomacvf_cannot_serve_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        bp_config(**overrides)
