"""The macro-action actor-critics (jaxmac.algos.families.actor_critic, Mac-IAICC, Mac-NIACC, Mac-CAC) against plain-Python references
written here (tests/_ac_references.py): n-step macro returns rebuilt from raw per-step arrays with the original
learners' rule, the Mac-CERT → Mac-JERT alignment, the ε-mixed policy, conditional and per-agent sampling, the
critic-then-actor order, one full update of every learner with nets stepped one entry at a time, and config errors."""

from __future__ import annotations

import dataclasses
import types

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from _ac_references import (agent_sequence, allowed_joint, joint_index, joint_start_index, jitted_apply,
                            log_pi_epsilon, original_n_step_returns, restricted, shared_input_sequence,
                            single_sequence, squeezed_entries)
from _learner_helpers import GAMMA, assert_frequencies, episode_slot, random_params
from _value_references import stack

from envs_jax.core import TimeStep
from jaxmac.algos.families import actor_critic as ac
from jaxmac.algos.registry import make_algorithm
from jaxmac.algos.base import Progress, per_part_optimizer
from jaxmac.scenarios import SCENARIOS
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.algos.families.decentralised import init_agent_drqn
from jaxmac.ops import MASK_VALUE
from jaxmac.networks.drqn import DRQN, AgentDRQN, AgentStateCritic, StateCritic

def entries_of(info, gamma, agent=None):
    return squeezed_entries(info["mac_done"], info["reward"], info["t_m"], info["length"], info["end"], gamma, agent)


# --- 1. n-step macro returns -------------------------------------------------------------------------------------


_PREPARED = {}


def prepared(n):
    """Synthetic episodes of ``n`` agents (every kind of ending, sequences shorter and longer than n-step windows,
    dense and sparse terminations) and their on-policy views with the Mac-CERT → Mac-JERT alignment (memoised:
    one compiled writer and one compiled view function per n, shared by the return and alignment tests)."""
    if n not in _PREPARED:
        specs = [(1, 20, "none", 0.3, None), (2, 13, "terminated", 0.4, [True] * n), (3, 17, "truncated", 0.35, None),
                 (4, 9, "terminated", 0.5, [True] + [False] * (n - 1)), (5, 3, "truncated", 0.3, None),
                 (6, 20, "terminated", 0.25, [False] * (n - 1) + [True]), (7, 6, "terminated", 0.2, [True] * n),
                 (8, 20, "truncated", 0.7, None)]
        cases = [episode_slot(100 * n + seed, length, end, n=n, p=p, last_done=done)
                 for seed, length, end, p, done in specs]
        prepare = ac.prepare_on_policy(cert=True, jert=True, alignment=True)
        _PREPARED[n] = cases, jax.jit(prepare)(stack([s for s, _ in cases]))
    return _PREPARED[n]


_returns = jax.jit(ac.macro_returns, static_argnums=4)


@pytest.mark.parametrize("n_step", [1, 3, 5])
@pytest.mark.parametrize("kind", ["cert", "jert"])
def test_macro_returns_equal_the_original_n_step_rule(kind, n_step):
    cases, batch = prepared(2)
    view = batch.cert if kind == "cert" else batch.jert
    rng = np.random.default_rng(10 * n_step + (kind == "jert"))
    boot = rng.normal(size=view.reward.shape).astype(np.float32)  # junk on padding too: it must be ignored
    mask = np.asarray(view.mask)
    junk = lambda x: np.where(mask, x, rng.normal(size=mask.shape)).astype(np.float32)  # noqa: E731
    got = np.asarray(_returns(junk(view.reward), junk(view.discount), jnp.asarray(boot), view.mask, n_step))
    short = terminal = truncated = long = 0
    for e, (_, info) in enumerate(cases):
        groups = [(i, entries_of(info, GAMMA, i)) for i in range(info["n"])] if kind == "cert" else \
            [(None, entries_of(info, GAMMA))]
        for i, entries in groups:
            g, b = (got[e, i], boot[e, i]) if kind == "cert" else (got[e], boot[e])
            count = len(entries)
            want = original_n_step_returns(entries, [float(x) for x in b[:count]], GAMMA, n_step)
            np.testing.assert_allclose(g[:count], want, rtol=2e-5, atol=2e-5, err_msg=f"episode {e} agent {i}")
            assert (g[count:] == 0).all()
            if count:
                short += count < n_step
                long += count > n_step
                terminal += entries[-1]["terminal"]
                truncated += not entries[-1]["terminal"]
    # the cases cover sequences shorter than n, longer ones, and both kinds of ending
    assert long >= 3 and terminal >= 2 and truncated >= 2
    if n_step == 5:
        assert short >= 1


def test_macro_returns_rejects_a_bad_n_step():
    x = jnp.zeros((2, 4))
    for bad in (0, -1, 2.0, True):
        with pytest.raises(ValueError, match="n_step"):
            ac.macro_returns(x, x, x, x > 0, bad)


# --- 2. Mac-CERT → Mac-JERT alignment of the on-policy batch -----------------------------------------------------


@pytest.mark.parametrize("n", [2, 3])
def test_prepare_on_policy_alignment_equals_a_running_index(n):
    cases, batch = prepared(n)
    start_joint, end_joint = np.asarray(batch.start_joint), np.asarray(batch.end_joint)
    mask = np.asarray(batch.cert.mask)
    checked = spanning = 0
    for e, (_, info) in enumerate(cases):
        counter, started, k = 0, [0] * n, [0] * n  # joint entries so far; where each agent's macro-action started
        for t in range(info["length"]):
            for i in range(n):
                if info["mac_done"][t, i]:
                    assert mask[e, i, k[i]]
                    assert end_joint[e, i, k[i]] == counter, (e, i, k[i], t)
                    assert start_joint[e, i, k[i]] == started[i], (e, i, k[i], t)
                    spanning += counter > started[i]
                    checked += 1
                    k[i] += 1
            if info["mac_done"][t].any():
                counter += 1
                for i in range(n):
                    if info["mac_done"][t, i]:
                        started[i] = counter
        for i in range(n):
            assert not mask[e, i, k[i]:].any()
            assert (start_joint[e, i, k[i]:] == 0).all() and (end_joint[e, i, k[i]:] == 0).all()
    assert checked > 40 and spanning > 10  # many macro-actions spanning several joint entries


# --- 3. the ε-mixed policy -------------------------------------------------------------------------------------


@pytest.mark.parametrize("epsilon", [0.0, 0.3, 1.0])
def test_epsilon_mixed_log_probs_equal_numpy(epsilon):
    counts, width, batch = (6, 6, 7, 3), 7, 4
    rng = np.random.default_rng(int(epsilon * 10))
    real = ac.real_action_mask(counts, width)
    for i, c in enumerate(counts):
        for a in range(width):
            assert real[i, a] == (a < c)
    logits = (3.0 * rng.normal(size=(batch, len(counts), width))).astype(np.float32)
    logits[:, ~real] = 50.0  # padding logits are large: they must be ignored
    fn = jax.jit(ac.epsilon_mixed_log_probs)
    got = np.asarray(fn(jnp.asarray(logits), real, epsilon))
    weights = rng.normal(size=logits.shape)
    want_grad = np.zeros(logits.shape)
    for b in range(batch):
        for i, c in enumerate(counts):
            want = log_pi_epsilon(logits[b, i], c, epsilon)
            if epsilon == 0.0:
                np.testing.assert_allclose(got[b, i, :c], want, rtol=1e-5, atol=1e-5)
            else:  # log of a probability at least ε/c: tight everywhere
                np.testing.assert_allclose(got[b, i, :c], want, rtol=1e-5, atol=1e-6)
            assert (got[b, i, c:] == MASK_VALUE).all()
            np.testing.assert_allclose(np.exp(got[b, i, :c].astype(np.float64)).sum(), 1.0, rtol=1e-5)
            # d/dx_j Σ_a w_a log π_ε(a) = Σ_a w_a (1 − ε) π_a (δ_aj − π_j) / π_ε(a)
            x = logits[b, i, :c].astype(np.float64)
            pi = np.exp(x - x.max())
            pi /= pi.sum()
            pe = np.exp(want)
            for j in range(c):
                want_grad[b, i, j] = sum(weights[b, i, a] * (1 - epsilon) * pi[a] * ((a == j) - pi[j]) / pe[a]
                                         for a in range(c))
    loss = lambda x: jnp.sum(jnp.where(real, fn(x, real, epsilon), 0.0) * weights)  # noqa: E731
    grad = np.asarray(jax.jit(jax.grad(loss))(jnp.asarray(logits)))
    assert np.isfinite(grad).all()
    np.testing.assert_allclose(grad, want_grad, rtol=1e-4, atol=1e-4)


# --- 4. sampling -----------------------------------------------------------------------------------------------


def sharpen(params, factor):
    """Scale the output layer so that the logits spread over several units (sampling tests then discriminate)."""
    return jax.tree_util.tree_map_with_path(
        lambda path, x: x * factor if any(getattr(p, "key", None) == "fc4" for p in path) else x, params)


def time_step(rng, counts, width, obs_dim, free, t):
    n = len(counts)
    avail = rng.random((n, width)) < 0.5
    for i, c in enumerate(counts):
        avail[i, rng.integers(0, c)] = True
        avail[i, c:] = True  # padding marked available: only an agent's own actions may be chosen
    running = np.array([rng.integers(0, c) for c in counts], np.int32)
    obs = rng.integers(0, 3, (n, obs_dim)).astype(np.float32)
    return TimeStep(obs_macro=jnp.asarray(obs), obs_real=jnp.asarray(obs), mac_done=jnp.asarray(free),
                    avail_actions=jnp.asarray(avail), mac=jnp.asarray(running), t_m=jnp.zeros(n, jnp.int32),
                    state=jnp.zeros(2), reward=jnp.float32(0), terminated=jnp.bool_(False),
                    truncated=jnp.bool_(False), t=jnp.int32(t))


SAMPLES, OBS = 20_000, 3


@pytest.fixture(scope="module", params=[(8, 8), (6, 6, 7)], ids=["8x8", "6x6x7"])
def joint_actor(request):
    counts = request.param
    n, joint = len(counts), int(np.prod(counts))
    net = DRQN(mlp=(8, 8), hidden=8, out=joint)
    params = sharpen(random_params(lambda k: net.init(k, jnp.zeros((1, n * OBS)), jnp.zeros((1,), bool),
                                                      jnp.zeros((8,))), 0), 3.0)

    @jax.jit
    def sample(carry, ts, keys, epsilon):
        return jax.vmap(lambda k: ac.joint_actor_step(net, params, carry, ts, k, epsilon, counts))(keys)

    return counts, net, params, sample


def test_joint_actor_step_samples_the_restricted_mixture(joint_actor):
    counts, net, params, sample = joint_actor
    n, width = len(counts), max(counts)
    rng = np.random.default_rng(len(counts))
    keys = jax.random.split(jax.random.key(3), SAMPLES)
    free_patterns = [[True] * n, [True] + [False] * (n - 1), [False] + [True] * (n - 1), [False] * n]
    for case, free in enumerate(free_patterns):
        for t, epsilon in ((7, 0.3), (0, 0.3), (4, 1.0)):
            free = np.asarray(free)
            ts = time_step(rng, counts, width, OBS, free, t)
            carry = jnp.asarray(rng.normal(size=8), jnp.float32)
            carries, actions = sample(carry, ts, keys, epsilon)
            actions, carries = np.asarray(actions), np.asarray(carries)
            running, avail = np.asarray(ts.mac), np.asarray(ts.avail_actions)
            assert (actions[:, ~free] == running[~free]).all()  # busy agents keep their macro-action
            for i in np.nonzero(free)[0]:
                assert avail[i, actions[:, i]].all() and (actions[:, i] < counts[i]).all()
            # the reference: the net from the (reset at t = 0) carry, π_ε over all joint actions, restricted
            start = np.zeros(8, np.float32) if t == 0 else np.asarray(carry)
            logits, new_carry = jitted_apply(net)(params, np.asarray(ts.obs_macro).reshape(1, -1),
                                                  jnp.zeros((1,), bool), jnp.asarray(start))
            want_carry = np.asarray(new_carry) if free.any() else start
            np.testing.assert_allclose(carries, np.broadcast_to(want_carry, carries.shape), rtol=1e-5, atol=1e-6)
            if not free.any():
                continue
            joint = np.exp(log_pi_epsilon(np.asarray(logits[0]), len(np.asarray(logits[0])), epsilon))
            probs = restricted(joint, allowed_joint(avail, free, running, counts))
            assert (probs > 0).sum() > 1
            assert_frequencies(np.ravel_multi_index(actions.T, counts), probs, (counts, case, t, epsilon))


@pytest.fixture(scope="module")
def agent_actors():
    counts, width = (6, 6, 7), 7
    n = len(counts)
    net = AgentDRQN(mlp=(8, 8), hidden=8, out=width)
    params = sharpen(random_params(lambda k: init_agent_drqn(net, k, n, OBS), 1), 3.0)
    real = ac.real_action_mask(counts, width)

    @jax.jit
    def sample(carry, ts, keys, epsilon):
        return jax.vmap(lambda k: ac.actors_step(net, params, carry, ts, k, epsilon, real))(keys)

    return counts, net, params, sample


def test_actors_step_busy_agents_resend_and_free_agents_sample_their_mixture(agent_actors):
    counts, net, params, sample = agent_actors
    n, width = len(counts), max(counts)
    rng = np.random.default_rng(5)
    keys = jax.random.split(jax.random.key(4), SAMPLES)
    for free in ([True, False, True], [False, True, False], [True, True, True], [False, False, False]):
        for t, epsilon in ((6, 0.3), (0, 0.3), (3, 1.0)):
            free = np.asarray(free)
            ts = time_step(rng, counts, width, OBS, free, t)
            carry = jnp.asarray(rng.normal(size=(n, 8)), jnp.float32)
            carries, actions = sample(carry, ts, keys, epsilon)
            actions, carries = np.asarray(actions), np.asarray(carries)
            running, avail = np.asarray(ts.mac), np.asarray(ts.avail_actions)
            assert (actions[:, ~free] == running[~free]).all()
            start = np.zeros((n, 8), np.float32) if t == 0 else np.asarray(carry)
            logits, new_carry = jitted_apply(net)(params, np.asarray(ts.obs_macro)[None], jnp.zeros((1,), bool),
                                                  jnp.asarray(start))
            for i in range(n):  # the carry steps only for free agents (and restarts at t = 0)
                want = np.asarray(new_carry[i]) if free[i] else start[i]
                np.testing.assert_allclose(carries[:, i], np.broadcast_to(want, carries[:, i].shape), rtol=1e-5,
                                           atol=1e-6)
            if free.any():  # a busy agent's state is left as it was
                assert not np.allclose(np.asarray(new_carry)[free], start[free])
            for i in np.nonzero(free)[0]:
                c = counts[i]
                allowed = avail[i, :c]
                assert (actions[:, i] < c).all() and allowed[actions[:, i]].all()
                mixture = np.exp(log_pi_epsilon(np.asarray(logits[0, i]), c, epsilon))
                probs = restricted(mixture, allowed)
                if epsilon == 1.0:  # uniform over the available actions
                    np.testing.assert_allclose(probs, allowed / allowed.sum(), atol=1e-12)
                assert_frequencies(actions[:, i], probs, (tuple(free), t, epsilon, i))
            if free.sum() >= 2:  # free agents choose independently
                i, j = np.nonzero(free)[0][:2]
                pair = actions[:, i] * width + actions[:, j]
                marg = np.outer(np.bincount(actions[:, i], minlength=width), np.bincount(actions[:, j],
                                                                                     minlength=width)) / SAMPLES
                assert_frequencies(pair, (marg / SAMPLES).ravel(), "independence")


# --- 5. critic, then actor with the updated critic ----------------------------------------------------------


def test_the_actor_sees_the_advantage_of_the_updated_critic():
    rng = np.random.default_rng(0)
    b, g, length = 3, 2, 6
    x = rng.normal(size=(b, g, length)).astype(np.float32)
    x_next = rng.normal(size=(b, g, length)).astype(np.float32)
    reward = rng.normal(size=(b, g, length)).astype(np.float32)
    mask = rng.random((b, g, length)) < 0.7
    mask[:, 1, 4:] = False  # groups with different entry counts
    batch = dict(x=x, x_next=x_next, reward=reward, mask=mask)

    def critic_targets(target, batch):  # a one-step target from the target critic
        return batch["reward"] + 0.9 * target["w"] * batch["x_next"], batch["mask"]

    def critic_values(critic, batch):
        return critic["w"] * batch["x"]

    def actor_loss(actor, batch, advantage, epsilon):
        return jnp.sum(actor["theta"] * advantage), {"seen_advantage": advantage, "seen_epsilon": epsilon}

    lr_actor, lr_critic = 0.05, 0.1
    optimizers = {"actor": optax.sgd(lr_actor), "critic": optax.sgd(lr_critic)}
    tx = per_part_optimizer(optimizers)
    config = types.SimpleNamespace(eps_start=1.0, eps_end=0.1, eps_decay_episodes=10, eps_decay_start=2, length_buckets=1)
    update = jax.jit(ac.critic_then_actor_update(critic_targets, critic_values, actor_loss, optimizers, config))
    w, w_target = 0.7, -0.4
    theta = rng.normal(size=(b, g, length)).astype(np.float32)
    params = {"actor": {"theta": jnp.asarray(theta)}, "critic": {"w": jnp.float32(w)}}
    target = {"actor": {"theta": jnp.zeros((b, g, length))}, "critic": {"w": jnp.float32(w_target)}}
    progress = Progress(episodes=jnp.int32(5), env_steps=jnp.int32(0), updates=jnp.int32(0))
    new, opt_state, metrics = update(params, target, tx.init(params), batch, jax.random.key(0), progress)

    # by hand: L(w) = Σ_groups mean over the group's entries of (w x − y)², one SGD step, A = y − w' x
    y = reward.astype(np.float64) + 0.9 * w_target * x_next
    loss = grad = 0.0
    for group in range(g):
        sel = mask[:, group]
        err = w * x[:, group][sel] - y[:, group][sel]
        loss += np.mean(err ** 2)
        grad += np.mean(2 * err * x[:, group][sel])
    w_new = w - lr_critic * grad
    advantage = np.where(mask, y - w_new * x, 0.0)
    stale = np.where(mask, y - w * x, 0.0)
    assert np.abs(advantage - stale).max() > 0.05  # the two critics give visibly different advantages
    np.testing.assert_allclose(float(metrics["critic_loss"]), loss, rtol=1e-5)
    np.testing.assert_allclose(float(new["critic"]["w"]), w_new, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(metrics["seen_advantage"]), advantage, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(float(metrics["actor_loss"]), np.sum(theta * advantage), rtol=1e-5, atol=1e-5)
    eps = 1.0 + np.clip((5 - 2) / 10, 0, 1) * (0.1 - 1.0)
    np.testing.assert_allclose(float(metrics["seen_epsilon"]), eps, rtol=1e-6)
    # the actor's step: θ − lr ∂(Σ θ A)/∂θ = θ − lr A (the advantage is not differentiated)
    np.testing.assert_allclose(np.asarray(new["actor"]["theta"]), theta - lr_actor * advantage, rtol=1e-5, atol=1e-6)
    assert set(opt_state) == {"actor", "critic"}


# --- 6. one full update of every learner against step-by-step references --------------------------------------

E, EPISODES = 3, 8  # episodes per update; episodes trained so far (ε mid-schedule)


@pytest.fixture(scope="module")
def learner_cases():
    spec = make_env(scenario_config("boxpushing-6x6", "mac_iaicc", tiny=True)).spec
    shape = dict(h=16, obs_dim=spec.obs_dim, num_actions=spec.max_actions, state_dim=spec.state_dim,
                 gamma=spec.discount)
    specs = [(70, 16, "truncated", 0.3, [False, True]), (71, 11, "terminated", 0.4, [True, False]),
             (72, 13, "terminated", 0.35, [True, True])]
    return [episode_slot(seed, length, end, p=p, last_done=done, **shape) for seed, length, end, p, done in specs]


@pytest.fixture(scope="module")
def learner_batch(learner_cases):
    """The episodes' slots and every view an on-policy learner may read (each learner gets the fields its own
    ``sample`` fills: one compiled view function for the five learners)."""
    slots = stack([s for s, _ in learner_cases])
    everything = ac.prepare_on_policy(cert=True, jert=True, cert_states=True, alignment=True)
    return slots, jax.jit(everything)(slots)


_RUNS = {}


def run_update(cases, learner_batch, algorithm, critic, n_step):
    """One update of the learner on the cases (memoised); the actors' loss also reports the advantages it got."""
    name = (algorithm, critic, n_step)
    if name in _RUNS:
        return _RUNS[name]
    values = dict(num_envs=E, batch_size=E, n_step=n_step)
    if critic is not None:
        values["critic"] = critic
    config = scenario_config("boxpushing-6x6", algorithm, tiny=True).override(**values)
    env = make_env(config)
    original = ac.AgentActors.loss

    def loss_reporting_advantage(self, actor_params, cert, advantage, epsilon):
        value, metrics = original(self, actor_params, cert, advantage, epsilon)
        return value, dict(metrics, seen_advantage=advantage)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(ac.AgentActors, "loss", loss_reporting_advantage)
        algo = make_algorithm(config, env)
        params, target = random_params(algo.init_params, 10), random_params(algo.init_params, 11)
        opt_state = algo.optimizer.init(params)
        slots, everything = learner_batch
        own = jax.eval_shape(algo.sample, None, slots, jax.random.key(0))  # what the learner's data source fills
        fields = {f.name for f in dataclasses.fields(ac.OnPolicyBatch)}
        batch = everything.replace(**{f: None for f in fields if getattr(own, f) is None})
        assert jax.tree_util.tree_structure(batch) == jax.tree_util.tree_structure(own)
        for got, want in zip(jax.tree_util.tree_leaves(batch), jax.tree_util.tree_leaves(own)):
            assert got.shape == want.shape and got.dtype == want.dtype
        progress = Progress(episodes=jnp.int32(EPISODES), env_steps=jnp.int32(100), updates=jnp.int32(1))
        new, _, metrics = jax.jit(algo.update)(params, target, opt_state, batch, jax.random.key(1), progress)
    _RUNS[name] = (config, env, params, target, new, metrics)
    return _RUNS[name]


class Reference:
    """A learner's loss written out: macro transitions from the raw per-step arrays, nets stepped one entry at a
    time, the original n-step rule, and (for the critic step) the same critic values as a differentiable function
    of the critic's parameters."""

    def __init__(self, config, env, cases):
        self.config, self.s, self.spec, self.cases = config, config.algo, env.spec, cases
        self.algorithm, self.gamma, self.n = config.algorithm, env.spec.discount, env.spec.num_agents
        s, spec = self.s, self.spec
        self.history = self.algorithm == "mac_cac" or s.critic == "history"
        self.individual = self.algorithm == "mac_iaicc"  # one critic per agent, on the agent's own entries
        if self.algorithm == "mac_iaicc":
            self.critic = AgentDRQN(mlp=s.critic_mlp_sizes, hidden=s.critic_rnn_size, out=1) if self.history else \
                AgentStateCritic(mlp=s.critic_mlp_sizes, mid=s.critic_mid_size)
        else:
            self.critic = DRQN(mlp=s.critic_mlp_sizes, hidden=s.critic_rnn_size, out=1) if self.history else \
                StateCritic(mlp=s.critic_mlp_sizes, mid=s.critic_mid_size)
        if self.algorithm == "mac_cac":
            self.actor = DRQN(mlp=s.actor_mlp_sizes, hidden=s.actor_rnn_size, out=int(np.prod(spec.num_actions)))
        else:
            self.actor = AgentDRQN(mlp=s.actor_mlp_sizes, hidden=s.actor_rnn_size, out=spec.max_actions)
        self.joint = [entries_of(info, self.gamma) for _, info in cases]
        self.agents = [[entries_of(info, self.gamma, i) for i in range(self.n)] for _, info in cases]
        c = config
        self.epsilon = c.eps_start + np.clip((EPISODES - c.eps_decay_start) / c.eps_decay_episodes, 0, 1) * (
            c.eps_end - c.eps_start)

    def groups(self):
        """(episode, group, entries): the critic groups' sequences (an agent's Mac-CERT, or the Mac-JERT)."""
        for e in range(len(self.cases)):
            if self.individual:
                for i in range(self.n):
                    yield e, i, self.agents[e][i]
            else:
                yield e, 0, self.joint[e]

    def joint_inputs(self, e):
        """The joint macro-observations at the Mac-JERT entries, then the one after the last entry."""
        obs = self.cases[e][1]["obs_macro"]
        joint = self.joint[e]
        return [obs[j["start"]].ravel() for j in joint] + [obs[joint[-1]["step"] + 1].ravel()]

    def values(self, critic_params):
        """{(e, group): (V at each entry, value after each entry)} with the nets stepped one entry at a time."""
        out = {}
        apply = jitted_apply(self.critic)
        for e, group, entries in self.groups():
            info = self.cases[e][1]
            if self.history:
                if self.individual:
                    v = [x[group, 0] for x in shared_input_sequence(self.critic, critic_params, self.joint_inputs(e),
                                                                    self.n)]
                    at = [v[joint_start_index(self.joint[e], en["start"])] for en in entries]
                    after = [v[joint_index(self.joint[e], en["step"]) + 1] for en in entries]
                else:
                    v = [x[0] for x in single_sequence(self.critic, critic_params, self.joint_inputs(e))]
                    at, after = v[:-1], v[1:]
            else:
                def state_value(row, info=info, group=group):
                    state = info["state"][row]
                    if not self.individual:
                        return float(apply(critic_params, state[None])[0, 0])
                    x = np.zeros((1, self.n, len(state)), np.float32)
                    x[0, group] = state
                    return float(apply(critic_params, x)[0, group, 0])
                at = [state_value(en["start"]) for en in entries]
                after = [state_value(en["step"] + 1) for en in entries]
            out[e, group] = (np.asarray(at), np.asarray(after))
        return out

    def returns(self, target_params):
        boot = self.values(target_params)
        return {key: np.asarray(original_n_step_returns(entries, list(boot[key][1]), self.gamma, self.s.n_step))
                for key, entries in ((k[:2], k[2]) for k in self.groups())}

    def critic_loss(self, critic_params, returns):
        v = self.values(critic_params)
        per_group = {}
        for (e, group), g in returns.items():
            per_group.setdefault(group, []).extend(list((g - v[e, group][0]) ** 2))
        return sum(np.mean(x) for x in per_group.values())

    def advantages(self, critic_params, returns):
        v = self.values(critic_params)
        return {key: g - v[key][0] for key, g in returns.items()}

    def actor_loss(self, actor_params, advantage):
        info = lambda e: self.cases[e][1]  # noqa: E731
        if self.algorithm == "mac_cac":
            counts, terms = self.spec.num_actions, []
            for e, joint in enumerate(self.joint):
                logits = single_sequence(self.actor, actor_params, self.joint_inputs(e)[:-1])
                for j, en in enumerate(joint):
                    taken = np.ravel_multi_index(tuple(info(e)["mac"][en["step"]]), counts)
                    log_pi = log_pi_epsilon(logits[j], len(logits[j]), self.epsilon)[taken]
                    terms.append(self.gamma ** en["step"] * log_pi * advantage[e, 0][j])
            return -np.sum(terms) / len(terms)
        total = 0.0
        for i in range(self.n):
            terms = []
            for e in range(len(self.cases)):
                entries = self.agents[e][i]
                obs = info(e)["obs_macro"]
                logits = agent_sequence(self.actor, actor_params, i, [obs[en["start"], i] for en in entries], self.n)
                for k, en in enumerate(entries):
                    log_pi = log_pi_epsilon(logits[k], self.spec.num_actions[i], self.epsilon)
                    a = self.agent_advantage(advantage, e, i, k)
                    terms.append(self.gamma ** en["step"] * log_pi[info(e)["mac"][en["step"], i]] * a)
            total += -np.sum(terms) / len(terms)
        return total

    def agent_advantage(self, advantage, e, i, k):
        """Mac-IAICC: the agent's own; Mac-NIACC: the joint advantage of the Mac-JERT entry where it ended."""
        if self.individual:
            return advantage[e, i][k]
        return advantage[e, 0][joint_index(self.joint[e], self.agents[e][i][k]["step"])]

    # --- the critic step, differentiable (the same values as ``values``, nets over whole sequences) ---------------

    def critic_step(self, critic_params, returns):
        """The critic after one Adam step (the scripts' optimiser: no clipping) on the reference loss, whose values
        are those of ``values`` with each net run over whole (zero-padded, causal) sequences."""
        assert self.config.grad_clip == 0
        rows, weights, targets = [], [], []
        counts = {}
        for e, group, entries in self.groups():
            counts[group] = counts.get(group, 0) + len(entries)
        for e, group, entries in self.groups():
            for k, en in enumerate(entries):
                if self.history:  # (episode, joint entry where the macro-action started, critic group)
                    j = joint_start_index(self.joint[e], en["start"]) if self.individual else k
                    rows.append((e, j, group))
                else:  # (the state at the start, critic group)
                    rows.append((self.cases[e][1]["state"][en["start"]], group))
                weights.append(1.0 / counts[group])
                targets.append(returns[e, group][k])
        weights, targets = np.asarray(weights, np.float32), np.asarray(targets, np.float32)
        group = np.asarray([r[-1] for r in rows])
        if self.history:
            inputs = [np.stack(self.joint_inputs(e)) for e in range(len(self.cases))]
            x = np.zeros((len(inputs), max(len(i) for i in inputs), inputs[0].shape[1]), np.float32)
            for e, i in enumerate(inputs):
                x[e, :len(i)] = i
            episode_idx, entry_idx = np.asarray([r[0] for r in rows]), np.asarray([r[1] for r in rows])
        else:
            states = np.stack([r[0] for r in rows])
        n, hidden = self.n, self.s.critic_rnn_size

        def values(p):
            if self.history and self.individual:
                xs = jnp.broadcast_to(x[:, :, None, :], (x.shape[0], x.shape[1], n, x.shape[2]))
                v, _ = self.critic.apply(p, xs, jnp.zeros(x.shape[:2], bool), jnp.zeros((x.shape[0], n, hidden)))
                return v[episode_idx, entry_idx, group, 0]
            if self.history:
                v, _ = self.critic.apply(p, x, jnp.zeros(x.shape[:2], bool), jnp.zeros((x.shape[0], hidden)))
                return v[episode_idx, entry_idx, 0]
            if self.individual:
                xs = np.zeros((len(rows), n, states.shape[1]), np.float32)
                xs[np.arange(len(rows)), group] = states
                return self.critic.apply(p, xs)[np.arange(len(rows)), group, 0]
            return self.critic.apply(p, states)[:, 0]

        loss = lambda p: jnp.sum(weights * (targets - values(p)) ** 2)  # noqa: E731
        value, grads = jax.jit(jax.value_and_grad(loss))(critic_params)
        adam = optax.adam(self.s.critic_lr)
        updates, _ = adam.update(grads, adam.init(critic_params), critic_params)
        return optax.apply_updates(critic_params, updates), grads, float(value)


LEARNERS = [("mac_iaicc", "state", 1), ("mac_iaicc", "history", 3), ("mac_niacc", "state", 3),
            ("mac_niacc", "history", 2), ("mac_cac", None, 3)]


def _leaves(tree):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(tree)]


@pytest.mark.parametrize("algorithm,critic,n_step", LEARNERS,
                         ids=[f"{a}-{c or 'history'}-n{n}" for a, c, n in LEARNERS])
def test_one_update_equals_a_step_by_step_reference(learner_cases, learner_batch, algorithm, critic, n_step):
    config, env, params, target, new, metrics = run_update(learner_cases, learner_batch, algorithm, critic, n_step)
    ref = Reference(config, env, learner_cases)
    assert 0.2 < ref.epsilon < 0.9
    returns = ref.returns(target["critic"])
    # the critic's loss, on the old critic with targets from the target critic
    critic_loss = ref.critic_loss(params["critic"], returns)
    np.testing.assert_allclose(float(metrics["critic_loss"]), critic_loss, rtol=2e-5)
    assert abs(ref.critic_loss(params["critic"], ref.returns(params["critic"])) - critic_loss) > 1e-3 * critic_loss
    # the critic took one Adam step (lr = critic_lr) down that loss: Adam's first step moves every parameter by
    # about critic_lr against its gradient, and the loss decreases
    lr = ref.s.critic_lr
    steps = np.concatenate([np.abs(a - b).ravel() for a, b in zip(_leaves(new["critic"]), _leaves(params["critic"]))])
    assert steps.max() <= lr * 1.001 and np.mean(steps > 0.5 * lr) > 0.9, (steps.max() / lr, np.mean(steps > 0.5 * lr))
    assert ref.critic_loss(new["critic"], returns) < critic_loss
    if (algorithm, critic) == ("mac_iaicc", "history"):  # and exactly so (one learner: the check compiles a grad)
        want_critic, grads, whole_sequences = ref.critic_step(params["critic"], returns)
        np.testing.assert_allclose(whole_sequences, critic_loss, rtol=2e-5)  # the two forms of the reference agree
        for got, want, old, g in zip(_leaves(new["critic"]), _leaves(want_critic), _leaves(params["critic"]),
                                     _leaves(grads)):
            steady = np.abs(g) > 1e-6  # where |g| ~ Adam's ε the step's size depends on rounding
            np.testing.assert_allclose((got - old)[steady], (want - old)[steady], rtol=1e-3, atol=1e-3 * lr)
            assert np.mean(steady) > 0.9
    # the actor's loss with advantages from the updated critic
    advantage = ref.advantages(new["critic"], returns)
    actor_loss = ref.actor_loss(params["actor"], advantage)
    np.testing.assert_allclose(float(metrics["actor_loss"]), actor_loss, rtol=2e-5, atol=1e-6)
    stale = ref.actor_loss(params["actor"], ref.advantages(params["critic"], returns))
    assert abs(stale - actor_loss) > 1e-3 * abs(actor_loss)  # the old critic would give another loss
    # the metrics that summarise the same quantities
    values = ref.values(params["critic"])
    np.testing.assert_allclose(float(metrics["return_mean"]), np.mean(np.concatenate(list(returns.values()))),
                               rtol=2e-5, atol=1e-6)
    np.testing.assert_allclose(float(metrics["value_mean"]), np.mean(np.concatenate([v[0] for v in values.values()])),
                               rtol=2e-5, atol=1e-6)
    # the actor moved, the actor's per-entry advantages (independent actors) are the reference's
    assert any(not np.array_equal(a, b) for a, b in zip(_leaves(new["actor"]), _leaves(params["actor"])))
    if algorithm != "mac_cac":
        seen = np.asarray(metrics["seen_advantage"])
        for e in range(E):
            for i in range(ref.n):
                for k in range(len(ref.agents[e][i])):
                    np.testing.assert_allclose(seen[e, i, k], ref.agent_advantage(advantage, e, i, k), rtol=2e-5,
                                               atol=2e-6)


def test_mac_niacc_naive_advantage_is_the_joint_advantage_at_the_termination(learner_cases, learner_batch):
    """Agent i's k-th macro-action gets the joint advantage of the Mac-JERT entry where it ended (not where it
    started, nor its own macro-action's return)."""
    config, env, params, target, new, metrics = run_update(learner_cases, learner_batch, "mac_niacc", "history", 2)
    ref = Reference(config, env, learner_cases)
    joint_advantage = ref.advantages(new["critic"], ref.returns(target["critic"]))
    seen = np.asarray(metrics["seen_advantage"])
    differs = 0
    for e in range(E):
        for i in range(ref.n):
            for k, en in enumerate(ref.agents[e][i]):
                at_end = joint_advantage[e, 0][joint_index(ref.joint[e], en["step"])]
                at_start = joint_advantage[e, 0][joint_start_index(ref.joint[e], en["start"])]
                np.testing.assert_allclose(seen[e, i, k], at_end, rtol=2e-5, atol=2e-6)
                differs += abs(at_end - at_start) > 1e-3
    assert differs >= 5  # many macro-actions span several joint entries


# --- 7. configuration -------------------------------------------------------------------------------------------


def test_on_policy_configs_refuse_replay_settings_naming_the_values():
    """The actor-critics' settings blocks refuse, when the configuration is made (before any tracing), shared settings
    that would train off-policy."""
    base = scenario_config("boxpushing-6x6", "mac_iaicc", tiny=True)
    with pytest.raises(ValueError) as err:
        base.override(batch_size=base.num_envs // 2)
    message = str(err.value)
    assert "mac_iaicc" in message and f"batch_size={base.num_envs // 2}" in message
    assert f"num_envs={base.num_envs}" in message
    niacc = scenario_config("boxpushing-6x6", "mac_niacc", tiny=True)
    for name, value in (("train_every_steps", 5), ("start_train_episodes", 3), ("target_update_steps", 100),
                        ("target_polyak", 0.5)):
        with pytest.raises(ValueError) as err:
            niacc.override(**{name: value})
        assert f"{name}={value}" in str(err.value) and "mac_niacc" in str(err.value), str(err.value)
    for algorithm in ("mac_iaicc", "mac_niacc", "mac_cac"):  # every actor-critic, from a string --set too
        config = scenario_config("boxpushing-6x6", algorithm, tiny=True)
        for wrong in ([f"batch_size={config.num_envs // 2}"], ["train_every_steps=5"]):
            with pytest.raises(ValueError, match=algorithm):
                config.override_strings(wrong)


@pytest.mark.parametrize("algorithm", ["mac_iaicc", "mac_niacc", "mac_cac"])
def test_every_scenario_gives_an_on_policy_config(algorithm):
    for scenario in SCENARIOS:
        for tiny in (False, True):
            config = scenario_config(scenario, algorithm, tiny=tiny)
            config.algo.check_config(config)  # valid: made without an error, and checked again here
            assert config.batch_size == config.num_envs and config.updates_per_round == 1
            assert config.eps_start == 1.0 and config.eps_end < 1.0 and config.algo.n_step >= 1
            if algorithm != "mac_cac":
                want = "state" if scenario.startswith("boxpushing") else "history"
                assert config.algo.critic == want, (scenario, config.algo.critic)
    for scenario in ("boxpushing-6x6", "overcooked-A", "warehouse-E"):
        config = scenario_config(scenario, algorithm)
        env = make_env(config)
        algo = make_algorithm(config, env)
        shapes = jax.eval_shape(algo.init_params, jax.random.key(0))
        assert set(shapes) == {"actor", "critic"}
