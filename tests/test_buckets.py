"""Length buckets and the decisions the seeds share (jaxmac.buckets): the update on the shortest prefix computes
what the full-length update computes; under ``Trainer.seeds_chunk`` a shared decision runs one branch, not both; the
first-finished collection that stops early returns the episodes of a full-length run of the same streams."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _value_references import stack
from _learner_helpers import episode_slot, random_params

import envs_jax
from envs_jax.wrappers import AutoReset
from jaxmac.algos.families import actor_critic as ac
from jaxmac.algos.registry import make_algorithm
from jaxmac.algos.base import Progress
from jaxmac.buckets import bucket_sizes, packed_row_sizes, run_bucketed
from jaxmac.seeds import SEED_AXIS, any_seed
from jaxmac.collect import random_policy, run_episodes_first_finished, select_first_finished
from jaxmac.config import make_env
from jaxmac.presets import scenario_config


def test_bucket_sizes_halve_from_the_full_length_and_refuse_bad_counts():
    assert bucket_sizes(100, 1) == (100,)
    assert bucket_sizes(100, 4) == (13, 25, 50, 100)
    assert bucket_sizes(3, 5) == (1, 2, 3)  # sizes collapse, never below one entry
    assert packed_row_sizes(128, 4) == (16, 24, 32, 48, 64, 96, 128)
    assert packed_row_sizes(32, 4) == (4, 6, 8, 12, 16, 24, 32)
    assert packed_row_sizes(8, 1) == (8,) and packed_row_sizes(3, 3) == (1, 2, 3)
    for bad in (0, -1, 2.0, True):
        with pytest.raises(ValueError, match="length_buckets"):
            bucket_sizes(100, bad)


def test_config_refuses_buckets_for_a_learner_without_them():
    with pytest.raises(ValueError) as err:
        scenario_config("boxpushing-6x6", "maccen_ddrqn", tiny=True).override(length_buckets=3)
    assert "length_buckets=3" in str(err.value) and "'maccen_ddrqn'" in str(err.value) and "mac_iaicc" in str(err.value)
    assert "tomacvf" in str(err.value)
    with pytest.raises(ValueError, match="length_buckets=0"):
        scenario_config("boxpushing-6x6", "mac_iaicc", tiny=True).override(length_buckets=0)


def test_run_bucketed_picks_the_smallest_size_over_all_seeds_in_one_branch():
    sizes = (2, 4, 8)

    def f(x, need):  # the prefix sum; which size ran is visible in the result's second part
        return run_bucketed(lambda size, x: (x[:size].sum(), jnp.int32(size)), sizes, need, x)

    x = jnp.arange(16.0).reshape(2, 8)
    total, size = jax.jit(jax.vmap(f, axis_name=SEED_AXIS))(x, jnp.array([1, 3]))  # seed 1 needs 3 → size 4 for both
    np.testing.assert_array_equal(np.asarray(size), [4, 4])
    np.testing.assert_allclose(np.asarray(total), [0 + 1 + 2 + 3, 8 + 9 + 10 + 11])
    jaxpr = str(jax.make_jaxpr(jax.vmap(f, axis_name=SEED_AXIS))(x, jnp.array([1, 3])))
    assert "cond[" in jaxpr  # one branch runs (with a batched index vmap turns the switch into a select of all)
    # one seed (no seeds axis): its own need
    assert int(jax.jit(f)(x[0], jnp.int32(5))[1]) == 8
    assert int(jax.jit(f)(x[0], jnp.int32(2))[1]) == 2


def test_any_seed_is_the_flag_of_any_seed_and_unbatched():
    flags = jnp.array([False, True, False])
    out = jax.vmap(lambda f: any_seed(f), axis_name=SEED_AXIS)(flags)
    np.testing.assert_array_equal(np.asarray(out), [True, True, True])
    assert bool(any_seed(jnp.bool_(False))) is False and bool(any_seed(True)) is True


# --- the bucketed update equals the full-length update -----------------------------------------------------------

LEARNERS = [("mac_iaicc", "state"), ("mac_iaicc", "history"), ("mac_niacc", "history"), ("mac_cac", None)]


@pytest.fixture(scope="module")
def short_batch():
    """Three short episodes in 16-row slots (every sequence fits in 8 entries), every view an on-policy learner reads."""
    spec = make_env(scenario_config("boxpushing-6x6", "mac_iaicc", tiny=True)).spec
    shape = dict(h=16, obs_dim=spec.obs_dim, num_actions=spec.max_actions, state_dim=spec.state_dim,
                 gamma=spec.discount)
    cases = [episode_slot(seed, length, end, p=0.5, last_done=done, **shape)
             for seed, length, end, done in ((80, 7, "terminated", [True, True]), (81, 5, "truncated", None),
                                              (82, 8, "terminated", [True, False]))]
    slots = stack([s for s, _ in cases])
    return slots, jax.jit(ac.prepare_on_policy(cert=True, jert=True, cert_states=True, alignment=True))(slots)


@pytest.mark.parametrize("algorithm,critic", LEARNERS, ids=[f"{a}-{c or 'history'}" for a, c in LEARNERS])
def test_the_bucketed_update_equals_the_full_length_update(short_batch, algorithm, critic):
    slots, everything = short_batch
    assert 4 < int(everything.entries()) <= 8  # the bucket of 8 holds the batch, that of 4 does not
    results = []
    for buckets in (1, 3):  # (16,) and (4, 8, 16)
        values = dict(num_envs=3, batch_size=3, n_step=2, length_buckets=buckets)
        if critic is not None:
            values["critic"] = critic
        config = scenario_config("boxpushing-6x6", algorithm, tiny=True).override(**values)
        algo = make_algorithm(config, make_env(config))
        own = jax.eval_shape(algo.sample, None, slots, jax.random.key(0))
        batch = everything.replace(**{f.name: None for f in dataclasses.fields(ac.OnPolicyBatch)
                                      if getattr(own, f.name) is None})
        params, target = random_params(algo.init_params, 20), random_params(algo.init_params, 21)
        progress = Progress(episodes=jnp.int32(8), env_steps=jnp.int32(60), updates=jnp.int32(1))
        update = jax.jit(algo.update)
        new, _, metrics = update(params, target, algo.optimizer.init(params), batch, jax.random.key(1), progress)
        results.append((new, metrics, update.lower(params, target, algo.optimizer.init(params), batch,
                                                   jax.random.key(1), progress).as_text()))
    (full, full_metrics, _), (cut, cut_metrics, text) = results
    assert "stablehlo.case" in text  # the bucketed program switches between sizes
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(cut)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
    assert set(full_metrics) == set(cut_metrics)
    for name in full_metrics:
        np.testing.assert_allclose(np.asarray(full_metrics[name]), np.asarray(cut_metrics[name]), rtol=1e-5,
                                   atol=1e-6, err_msg=name)


# --- ToMacVF: the update on the sampled episodes' shortest prefix ------------------------------------------------

TOMACVF_CASES = [("boxpushing-6x6", "mac_jert"), ("overcooked-A", "mac_sjert")]  # each buffer, 2 and 3 agents


@pytest.mark.parametrize("scenario,buffer", TOMACVF_CASES, ids=[f"{s}-{b}" for s, b in TOMACVF_CASES])
def test_tomacvf_loss_gradients_and_update_on_the_prefix_equal_the_full_length(scenario, buffer):
    """Box Pushing (2 agents) and Overcooked-A (3 agents), Mac-SJERT and Mac-JERT, terminated and truncated episodes
    of at most 8 steps in 16-row slots: the loss, its gradients and the bucketed update equal the full-length ones."""
    values = dict(horizon=16, n_step=2, batch_size=3, macro_loss_weight=0.6)
    if buffer == "mac_jert":
        values.update(buffer="mac_jert", obs_mode="macro")
    config = scenario_config(scenario, "tomacvf", tiny=True).override(**values)
    env = make_env(config)
    spec = env.spec
    shape = dict(h=16, n=spec.num_agents, obs_dim=spec.obs_dim, num_actions=spec.max_actions,
                 state_dim=spec.state_dim, gamma=spec.discount)
    done = lambda first: [first] + [False] * (spec.num_agents - 1)  # noqa: E731
    slots = stack([episode_slot(seed, length, end, p=0.5, last_done=last, **shape)[0]
                   for seed, length, end, last in ((90, 7, "terminated", done(True)), (91, 8, "truncated", None),
                                                    (92, 5, "terminated", done(False)))])
    cut = slots.prefix(8)
    assert cut.mac.shape[1] == 8 and cut.state.shape[1] == 9 and cut.config.horizon == 8
    assert int(slots.segments.valid.sum()) == int(cut.segments.valid.sum()) > 0

    algo = make_algorithm(config, env)
    params, target = random_params(algo.init_params, 30, 0.3), random_params(algo.init_params, 31, 0.3)
    progress = Progress(episodes=jnp.int32(8), env_steps=jnp.int32(60), updates=jnp.int32(1))
    grad = jax.jit(jax.value_and_grad(lambda p, b: algo.loss(p, target, b, jax.random.key(1), progress), has_aux=True))
    (loss_full, metrics_full), g_full = grad(params, slots)
    (loss_cut, metrics_cut), g_cut = grad(params, cut)
    np.testing.assert_allclose(float(loss_cut), float(loss_full), rtol=1e-5)
    assert float(loss_full) > 0
    for name in metrics_full:
        np.testing.assert_allclose(np.asarray(metrics_cut[name]), np.asarray(metrics_full[name]), rtol=1e-5,
                                   atol=1e-6, err_msg=name)
    # float32 round-off: sums of terms in the thousands that cancel (one element of 3,904 differed by 4.5e-4
    # relative, 2e-6 of the leaf's largest entry, on a one-core run); a missed or extra row changes them by far more
    for a, b in zip(jax.tree_util.tree_leaves(g_full), jax.tree_util.tree_leaves(g_cut)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-4, atol=1e-5 * max(1.0, float(jnp.abs(a).max())))

    bucketed = make_algorithm(config.override(length_buckets=2), env)  # sizes (8, 16): the batch takes 8
    args = (params, target, algo.optimizer.init(params), slots, jax.random.key(1), progress)
    update = jax.jit(bucketed.update)
    assert "stablehlo.case" in update.lower(*args).as_text()
    new_full, _, m_full = jax.jit(algo.update)(*args)
    new_cut, _, m_cut = update(*args)
    # Adam's first step is ≈ lr·sign(g): where a gradient entry is ~0 (the gradients were compared above) its
    # round-off can move that entry's step by a good part of lr, so the parameters are compared to half of lr
    for a, b in zip(jax.tree_util.tree_leaves(new_full), jax.tree_util.tree_leaves(new_cut)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=0.5 * config.lr)
    np.testing.assert_allclose(float(m_cut["grad_norm"]), float(m_full["grad_norm"]), rtol=1e-5)


def test_a_prefix_shorter_than_the_horizon_is_refused_beyond_it():
    slot, _ = episode_slot(1, 5, "terminated", h=16)
    with pytest.raises(ValueError, match="rows=17"):
        slot.prefix(17)


# --- the early-stopping first-finished collection --------------------------------------------------------------


def full_length_streams(env, act, init_carry, key, epsilon, num_envs, num_episodes):
    """The streams of ``run_episodes_first_finished`` run for their whole bound (no early stop), written as a plain
    per-env ``lax.scan`` with the same keys: the reference the early-stopping loop must agree with."""
    auto, horizon = AutoReset(env), env.spec.horizon
    length = horizon * -(-num_episodes // num_envs)

    def stream(key):
        key_reset, key_steps = jax.random.split(key)
        state, first = auto.reset(key_reset)

        def body(carry, key):
            state, policy_carry = carry
            k_act, k_step = jax.random.split(key)
            policy_carry, actions = act(None, policy_carry, state.timestep, k_act, epsilon)
            state, ts = auto.step(k_step, state, actions)
            return (state, policy_carry), (ts, state.timestep)

        _, (traj, nxt) = jax.lax.scan(body, (state, init_carry(env.spec.num_agents)), jax.random.split(key_steps, length))
        return traj, jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b[:-1]]), first, nxt)

    return jax.vmap(stream)(jax.random.split(key, num_envs))


@pytest.mark.parametrize("num_envs,num_episodes", [(8, 8), (4, 10), (16, 3)])
def test_early_stopping_collection_returns_the_episodes_of_the_full_streams(num_envs, num_episodes):
    env = envs_jax.make("boxpushing-6x6")
    init_carry, act = random_policy()
    key = jax.random.key(num_envs + num_episodes)
    reset_ts, traj = jax.jit(lambda k: run_episodes_first_finished(env, act, init_carry, None, k, 1.0, num_envs,
                                                                   num_episodes))(key)
    full, acted_from = jax.jit(lambda k: full_length_streams(env, act, init_carry, k, 1.0, num_envs,
                                                             num_episodes))(key)
    env_index, start = select_first_finished(full.terminated | full.truncated, num_episodes)
    done = np.asarray(traj.terminated | traj.truncated)
    full_done = np.asarray(full.terminated | full.truncated)
    for e, (i, s) in enumerate(zip(np.asarray(env_index), np.asarray(start))):
        length = int(np.argmax(full_done[i, s:])) + 1  # through its last step, where the episode ends
        assert done[e, length - 1] and not done[e, :length - 1].any()
        for got, want in zip(jax.tree_util.tree_leaves(traj), jax.tree_util.tree_leaves(full)):
            np.testing.assert_array_equal(np.asarray(got)[e, :length], np.asarray(want)[i, s:s + length])
        for got, want in zip(jax.tree_util.tree_leaves(reset_ts), jax.tree_util.tree_leaves(acted_from)):
            np.testing.assert_array_equal(np.asarray(got)[e], np.asarray(want)[i, s])
