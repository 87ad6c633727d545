"""Values of ToMacVF's losses (``sjert_loss``, ``jert_loss`` via ``algo.loss``) against slow references.

The batch is six synthetic Box Pushing 6×6 episodes (2 agents, H = 12, γ = 0.9) with every kind of ending
(termination with and without a macro-action ending on the terminal step, truncation, the slot's end) and
per-agent termination patterns, so macro-actions of the two agents overlap and end at different steps.
Online and target parameters are independent random draws, so online/target mix-ups change the values.

The references rebuild everything from the *raw* per-step arrays of each episode (``mac_done``, ``mac``,
``reward``, ``terminated``/``truncated``, ``avail``, observations, states) with explicit loops over episodes,
steps and agents, without ``jaxmac.buffer.views``, ``slot_inputs``/``jert_sequence`` or ``jaxmac.algos.targets``:

* the network inputs of every row (observation, time, the macro-action in force before the row and its
  progress, the progress τ of the action each agent executes from the row: 0 where it is free);
* the agent Q values by stepping ``TemporalAgentNet`` one row at a time (``method="step"``, as acting does),
  checked against its sequence apply, and the mixer weights by applying ``Mixer`` to the same rows; mixing
  (QMIX: ``w2 · ELU(Σ_i Q_i W1[i] + b1) + b2``) is redone in NumPy;
* micro-TD (D11): at every valid step t, ``Σ_{k<m} γ^k r_{t+k} + γ^m Q̄_tot(t+m)`` with ``m = min(n, L − t)``, no
  bootstrap when the episode terminated within the m steps (or was truncated, with ``bootstrap_time_limit`` off);
* macro-TD (D10): per agent and per completed macro-action (ended by ``mac_done`` or by termination), Q_tot at
  its first row with the joint action executed there, target ``R_m + γ^τ Q̄_tot(end + 1)`` (no bootstrap at the
  last step as for micro-TD);
* Mac-JERT (D16): the joint decision points (steps where any macro-action ended), the GRU and mixer run over the
  squeezed rows (frozen macro-observations), target ``R^J + γ^τ Q̄_tot(next decision row)``;
* Q̄_tot (D9): free agents take the online argmax over their available actions, busy agents keep their running
  macro-action; the value is the target network's Q mixed with the target mixer's weights;
* the losses (D8): ``mean w·δ_micro² + λ · mean w·δ_macro²`` with ``w = overestimate_weight`` where δ = Q − y > 0.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _buffer_fixtures import synthetic_rollout
from _learner_helpers import random_params

from jaxmac.algos.registry import make_algorithm
from jaxmac.algos.base import Progress
from jaxmac.algos.tomacvf import network_configs
from jaxmac.buffer.episode import SlotConfig, write_episode
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.networks import Mixer, NetInputs, TemporalAgentNet

H, GAMMA = 12, 0.9
BASE = scenario_config("boxpushing-6x6", tiny=True).override(horizon=H)
PROGRESS = Progress(episodes=jnp.int32(0), env_steps=jnp.int32(0), updates=jnp.int32(0))

# (seed, length, ending, mac_done forced on the last step)
EPISODES = [
    (11, 9, "terminated", (True, False)),  # one agent's macro-action ends with the episode, the other is cut
    (12, 10, "truncated", (False, False)),  # both macro-actions cut by the time limit: no macro transition
    (13, H, "none", None),  # the slot ends first: bootstrap from row H
    (14, 5, "terminated", (True, True)),
    (15, 7, "truncated", (False, True)),
    (16, 8, "terminated", (False, False)),  # termination with no macro-action reporting its end
]

SJERT_CASES = {
    "one_step": dict(n_step=1, macro_loss_weight=0.37),
    "three_step_optimistic": dict(n_step=3, macro_loss_weight=2.5, overestimate_weight=0.6),
    "time_limit_terminal": dict(n_step=3, macro_loss_weight=0.37, bootstrap_time_limit=False),
}


# --------------------------------------------------------------------------------------------------------------
# episodes and parameters


@dataclasses.dataclass
class RawEpisode:
    """The per-step arrays of one rollout as the environment emitted them (junk after the episode's end)."""

    obs_real: np.ndarray  # [H+1, n, O]
    obs_macro: np.ndarray  # [H+1, n, O]
    state: np.ndarray  # [H+1, S]
    avail: np.ndarray  # bool[H+1, n, A]
    mac: np.ndarray  # i32[H, n]
    mac_done: np.ndarray  # bool[H, n]
    t_m: np.ndarray  # i32[H, n]
    reward: np.ndarray  # f32[H]
    terminated: np.ndarray  # bool[H]
    truncated: np.ndarray  # bool[H]


def synthetic_episode(spec, seed, length, end, last_done, p=0.35):
    rng = np.random.default_rng(seed)
    n = spec.num_agents
    mac_done = rng.random((H, n)) < p
    if last_done is not None:
        mac_done[length - 1] = last_done
    reward = rng.normal(size=H).astype(np.float32)
    reset_ts, traj, info = synthetic_rollout(mac_done, reward, length, end=end, obs_dim=spec.obs_dim,
                                             num_actions=spec.max_actions, state_dim=spec.state_dim, seed=seed)
    avail = info["avail"]
    for r, i in zip(*np.nonzero(~avail.any(-1))):  # every free agent has at least one action
        avail[r, i, rng.integers(0, spec.max_actions)] = True
    reset_ts = reset_ts.replace(avail_actions=avail[0])
    traj = traj.replace(avail_actions=avail[1:])
    raw = RawEpisode(obs_real=info["obs_real"], obs_macro=info["obs_macro"], state=info["state"], avail=avail,
                     mac=info["mac"], mac_done=mac_done, t_m=info["t_m"], reward=reward,
                     terminated=np.asarray(traj.terminated), truncated=np.asarray(traj.truncated))
    return reset_ts, traj, raw


@pytest.fixture(scope="module")
def env():
    return make_env(BASE)


@pytest.fixture(scope="module")
def episodes(env):
    """(batch EpisodeSlot [B, ...], list of RawEpisode)."""
    cfg = SlotConfig.from_spec(env.spec, horizon=H, discount=GAMMA)
    write = jax.jit(write_episode, static_argnums=0)
    slots, raws = [], []
    for seed, length, end, last_done in EPISODES:
        reset_ts, traj, raw = synthetic_episode(env.spec, seed, length, end, last_done)
        slots.append(write(cfg, reset_ts, traj))
        raws.append(raw)
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *slots), raws


@pytest.fixture(scope="module")
def params(env):
    """(online, target): independent random draws."""
    algo = make_algorithm(BASE, env)
    return random_params(algo.init_params, 1), random_params(algo.init_params, 2)


@pytest.fixture(scope="module")
def nets(env):
    agent_cfg, mixer_cfg = network_configs(BASE, env)
    return Networks(TemporalAgentNet(agent_cfg), Mixer(mixer_cfg), agent_cfg.hidden)


# --------------------------------------------------------------------------------------------------------------
# references


def episode_end(raw):
    """(L, terminated): the episode lasts until the first step flagged terminated or truncated (or the slot end)."""
    for t in range(H):
        if raw.terminated[t] or raw.truncated[t]:
            return t + 1, bool(raw.terminated[t])
    return H, False


def last_target_is_terminal(raw, settings):
    """Whether the target at the episode's last step has no bootstrap: after termination, and after a time-limit
    truncation when ``bootstrap_time_limit`` is off (not at the slot's end, which is no time limit here)."""
    length, terminated = episode_end(raw)
    return terminated or (bool(raw.truncated[length - 1]) and not settings.bootstrap_time_limit)


def is_free(raw, row, i):
    """Agent i chooses at ``row``: the start, or its macro-action ended on the previous step."""
    return row == 0 or bool(raw.mac_done[row - 1, i])


def progress(raw, row, i):
    """τ of the macro-action agent i executes from ``row`` on: primitive steps since it chose (0 where free)."""
    tau = 0
    for r in range(1, row + 1):
        tau = 0 if raw.mac_done[r - 1, i] else tau + 1
    return tau


def row_inputs(raw, rows, obs):
    """Per-row network inputs (dicts of NumPy arrays) of the slot rows ``rows``, read from the raw arrays."""
    n = raw.mac.shape[1]
    out = []
    for k, r in enumerate(rows):
        out.append(dict(
            obs=obs[r].astype(np.float32), t=np.int32(r), prev_t=np.int32(r - 1),
            prev_mac=(raw.mac[r - 1] if r > 0 else np.full(n, -1)).astype(np.int32),
            prev_t_m=(raw.t_m[r - 1] if r > 0 else np.zeros(n)).astype(np.int32),
            reset=np.bool_(k == 0), tau=np.array([progress(raw, r, i) for i in range(n)], np.int32),
            state=raw.state[r].astype(np.float32)))
    return out


class Networks:
    """Q values and mixer weights of a sequence of rows, the agent GRU stepped one row at a time."""

    def __init__(self, net, mixer, hidden):
        self.net, self.mixer, self.hidden = net, mixer, hidden
        self.step = jax.jit(lambda p, x, c, tau: net.apply(p, x, c, tau, method="step"))
        self.max_step_vs_sequence = 0.0
        self._memo = {}

    def __call__(self, params, rows, memo_key=None):
        """-> (q f64[T, n, A], weights dict of f64 arrays [T, ...]); ``memo_key`` names a (params, rows) pair
        already evaluated (the loss cases share their episodes and parameters)."""
        if memo_key is not None and memo_key in self._memo:
            return self._memo[memo_key]
        fields = ("obs", "t", "prev_t", "prev_mac", "prev_t_m", "reset")
        n = rows[0]["prev_mac"].shape[0]
        carry = jnp.zeros((n, self.hidden), jnp.float32)
        qs = []
        for row in rows:
            q, carry = self.step(params["agent"], NetInputs(**{f: jnp.asarray(row[f]) for f in fields}), carry,
                                 jnp.asarray(row["tau"]))
            qs.append(np.asarray(q, np.float64))
        q_step = np.stack(qs)
        seq = NetInputs(**{f: jnp.asarray(np.stack([row[f] for row in rows])) for f in fields})
        tau = jnp.asarray(np.stack([row["tau"] for row in rows]))
        q_seq, _, _ = self.net.apply(params["agent"], seq, jnp.zeros((n, self.hidden), jnp.float32), tau)
        np.testing.assert_allclose(q_step, np.asarray(q_seq), rtol=1e-5, atol=1e-6)
        self.max_step_vs_sequence = max(self.max_step_vs_sequence, float(np.abs(q_step - np.asarray(q_seq)).max()))
        weights, _ = self.mixer.apply(params["mixer"], jnp.asarray(np.stack([row["state"] for row in rows])), seq)
        w = {k: np.asarray(getattr(weights, k), np.float64) for k in ("w1", "b1", "w2", "b2")}
        if memo_key is not None:
            self._memo[memo_key] = q_step, w
        return q_step, w


def mix_np(w, k, q_joint):
    """QMIX at entry k: w2 · ELU(Σ_i Q_i W1[i] + b1) + b2, with an explicit sum over agents."""
    pre = w["b1"][k].copy()
    for i, q_i in enumerate(q_joint):
        pre = pre + q_i * w["w1"][k][i]
    hidden = np.where(pre > 0, pre, np.expm1(np.minimum(pre, 0)))
    return float(np.sum(hidden * w["w2"][k]) + w["b2"][k])


def greedy(q_row, avail_row):
    """First best available action (ties to the lowest index, as argmax)."""
    best = None
    for a in range(len(q_row)):
        if avail_row[a] and (best is None or q_row[a] > q_row[best]):
            best = a
    return best


@dataclasses.dataclass
class Stats:
    """What the reference saw, to assert that the checked cases are not trivial."""

    free_choices: int = 0  # free agents at bootstrap rows
    busy_pinned: int = 0  # busy agents at bootstrap rows
    online_target_disagree: int = 0  # free agents whose online and target argmaxes differ
    avail_matters: int = 0  # free agents whose unmasked argmax is unavailable
    min_gap: float = np.inf  # smallest margin of an online argmax (guards against near ties)
    terminal_targets: int = 0
    bootstrapped_targets: int = 0


def conditional_target(raw, row, entry, q_on, q_tg, w_tg, stats):
    """Q̄_tot at slot row ``row`` (entry ``entry`` of the evaluated sequence): D9's conditional double-Q."""
    n = raw.mac.shape[1]
    joint = []
    for i in range(n):
        if is_free(raw, row, i):
            a = greedy(q_on[entry, i], raw.avail[row, i])
            stats.free_choices += 1
            stats.online_target_disagree += a != greedy(q_tg[entry, i], raw.avail[row, i])
            stats.avail_matters += not raw.avail[row, i, int(np.argmax(q_on[entry, i]))]
            others = [q_on[entry, i, b] for b in range(len(q_on[entry, i])) if raw.avail[row, i, b] and b != a]
            if others:
                stats.min_gap = min(stats.min_gap, q_on[entry, i, a] - max(others))
            joint.append(a)
        else:
            stats.busy_pinned += 1
            joint.append(int(raw.mac[row - 1, i]))
    stats.bootstrapped_targets += 1
    return mix_np(w_tg, entry, [q_tg[entry, i, joint[i]] for i in range(n)])


def td_mean(deltas, weight):
    total = 0.0
    for d in deltas:
        total += (weight if d > 0 else 1.0) * d * d
    return total / max(len(deltas), 1)


def discounted_sum(reward, start, count, gamma):
    total = 0.0
    for k in range(count):
        total += gamma ** k * float(reward[start + k])
    return total


def reference_sjert(raws, nets, online, target, settings, gamma):
    """Micro- and macro-TD of ToMacVF on Mac-SJERT: (micro_loss, macro_loss, mean Q_tot, counts, stats)."""
    stats = Stats()
    micro, macro, q_tots = [], [], []
    for b, raw in enumerate(raws):
        length, terminated = episode_end(raw)
        terminal_end = last_target_is_terminal(raw, settings)
        n = raw.mac.shape[1]
        rows = row_inputs(raw, range(length + 1), raw.obs_real if settings.obs_mode == "real" else raw.obs_macro)
        q, w = nets(online, rows, ("online", "sjert", settings.obs_mode, b))
        q_tg, w_tg = nets(target, rows, ("target", "sjert", settings.obs_mode, b))

        def q_tot(row):  # Q_tot at a row with the joint macro-action executed during that step
            return mix_np(w, row, [q[row, i, raw.mac[row, i]] for i in range(n)])

        for t in range(length):  # micro-TD, n-step
            m = min(settings.n_step, length - t)
            y = discounted_sum(raw.reward, t, m, gamma)
            if terminal_end and t + m == length:
                stats.terminal_targets += 1
            else:
                y += gamma ** m * conditional_target(raw, t + m, t + m, q, q_tg, w_tg, stats)
            q_tots.append(q_tot(t))
            micro.append(q_tot(t) - y)

        for i in range(n):  # macro-TD, one transition per completed macro-action of agent i
            start = 0
            for t in range(length):
                if is_free(raw, t, i):
                    start = t
                ends_with_episode = terminated and t == length - 1
                if not (raw.mac_done[t, i] or ends_with_episode):
                    continue
                duration = t - start + 1
                y = discounted_sum(raw.reward, start, duration, gamma)
                if terminal_end and t == length - 1:  # a cut macro-action (above) makes no transition
                    stats.terminal_targets += 1
                else:
                    y += gamma ** duration * conditional_target(raw, t + 1, t + 1, q, q_tg, w_tg, stats)
                macro.append(q_tot(start) - y)
    weight = settings.overestimate_weight
    return (td_mean(micro, weight), td_mean(macro, weight), float(np.mean(q_tots)),
            dict(micro=len(micro), macro=len(macro)), stats)


def reference_jert(raws, nets, online, target, settings, gamma):
    """The Mac-JERT ablation's TD loss: (loss, mean Q_tot, transitions, stats)."""
    stats = Stats()
    deltas, q_tots = [], []
    for raw in raws:
        length, _ = episode_end(raw)
        terminal_end = last_target_is_terminal(raw, settings)
        n = raw.mac.shape[1]
        kept = [t for t in range(length) if raw.mac_done[t].any()]  # joint decision points end here
        decision_rows = [0] + [t + 1 for t in kept]  # entry k: where transition k starts; k + 1: its bootstrap
        rows = row_inputs(raw, decision_rows, raw.obs_macro)
        q, w = nets(online, rows)
        q_tg, w_tg = nets(target, rows)
        for k, step in enumerate(kept):
            start = decision_rows[k]
            tau = step - start + 1
            y = discounted_sum(raw.reward, start, tau, gamma)
            if terminal_end and step == length - 1:
                stats.terminal_targets += 1
            else:
                y += gamma ** tau * conditional_target(raw, step + 1, k + 1, q, q_tg, w_tg, stats)
            value = mix_np(w, k, [q[k, i, raw.mac[start, i]] for i in range(n)])
            q_tots.append(value)
            deltas.append(value - y)
    return td_mean(deltas, settings.overestimate_weight), float(np.mean(q_tots)), len(deltas), stats


def assert_nontrivial(stats):
    assert stats.free_choices > 0 and stats.busy_pinned > 0, stats
    assert stats.online_target_disagree > 0, "online and target argmaxes never differ: a swap would go unseen"
    assert stats.avail_matters > 0, "availability never changes an argmax"
    assert stats.min_gap > 1e-4, f"near tie in an online argmax ({stats.min_gap}): pick other seeds"
    assert stats.terminal_targets > 0 and stats.bootstrapped_targets > 0, stats


def loss_of(config, env, batch, online, target):
    algo = make_algorithm(config, env)
    loss, metrics = jax.jit(algo.loss)(online, target, batch, jax.random.key(0), PROGRESS)
    return float(loss), {k: float(v) for k, v in metrics.items()}


# --------------------------------------------------------------------------------------------------------------
# tests


def test_batch_has_every_ending_and_overlapping_macro_actions(episodes):
    """The episodes include termination (with and without a macro-action ending on the terminal step),
    truncation with running and finished macro-actions, the slot's end, and agents whose macro-actions end at
    different steps; the written slots agree with the raw lengths."""
    batch, raws = episodes
    ends = [episode_end(raw) for raw in raws]
    assert any(term for _, term in ends) and any(not term and length < H for length, term in ends)
    assert any(length == H and not raws[b].truncated[H - 1] for b, (length, _) in enumerate(ends))
    np.testing.assert_array_equal(np.asarray(batch.length), [length for length, _ in ends])
    np.testing.assert_array_equal(np.asarray(batch.terminated).any(1), [term for _, term in ends])
    last_done = [raw.mac_done[length - 1] for raw, (length, _) in zip(raws, ends)]
    assert any(term and not done.any() for (_, term), done in zip(ends, last_done))
    assert any(term and done.any() and not done.all() for (_, term), done in zip(ends, last_done))
    assert any(not term and not done.all() for (_, term), done in zip(ends, last_done))
    staggered = sum(int((raw.mac_done[:length, 0] != raw.mac_done[:length, 1]).sum())
                    for raw, (length, _) in zip(raws, ends))
    assert staggered >= 10  # macro-actions of the two agents end at different steps: they overlap
    assert max(progress(raw, t, i) for raw, (length, _) in zip(raws, ends) for t in range(length) for i in range(2)) >= 3


def test_stepping_the_agent_net_row_by_row_equals_its_sequence_apply(episodes, nets, params):
    """The reference's stepped Q values (``method="step"``, as acting) equal the sequence apply the loss uses."""
    _, raws = episodes
    for b, raw in enumerate(raws):
        rows = row_inputs(raw, range(episode_end(raw)[0] + 1), raw.obs_real)
        nets(params[0], rows, ("online", "sjert", "real", b))  # asserts step == sequence inside
    assert nets.max_step_vs_sequence < 1e-5


@pytest.mark.parametrize("case", list(SJERT_CASES))
def test_sjert_loss_matches_the_reference(case, env, episodes, nets, params):
    """Mac-SJERT: ``micro_loss``, ``macro_loss``, ``loss = micro + λ·macro`` (λ ≠ 1) and ``q_tot_mean`` equal the
    loop references, for one-step micro-TD and for 3-step micro-TD with optimistic weighting."""
    config = BASE.override(**SJERT_CASES[case])
    batch, raws = episodes
    online, target = params
    micro, macro, q_tot_mean, counts, stats = reference_sjert(raws, nets, online, target, config.algo, GAMMA)
    assert_nontrivial(stats)
    assert counts["macro"] >= 10 and macro > 0

    loss, metrics = loss_of(config, env, batch, online, target)
    np.testing.assert_allclose(metrics["micro_loss"], micro, rtol=1e-5)
    np.testing.assert_allclose(metrics["macro_loss"], macro, rtol=1e-5)
    np.testing.assert_allclose(metrics["q_tot_mean"], q_tot_mean, rtol=1e-5, atol=1e-6)
    lam = config.algo.macro_loss_weight
    assert lam != 1.0
    np.testing.assert_allclose(loss, micro + lam * macro, rtol=1e-5)
    if not config.algo.bootstrap_time_limit:  # the batch's truncations change both targets
        bootstrapped = reference_sjert(raws, nets, online, target, BASE.override(**(SJERT_CASES[case] | dict(
            bootstrap_time_limit=True))).algo, GAMMA)
        assert abs(bootstrapped[0] - micro) > 1e-3 * micro and abs(bootstrapped[1] - macro) > 1e-3 * macro


@pytest.mark.parametrize("episodes_so_far, weight", [(50, 0.2), (300, 0.6), (900, 1.0)])
def test_annealed_overestimate_weight_is_the_scheduled_constant(episodes_so_far, weight, env, episodes, nets, params):
    """``overestimate_weight`` annealed from 0.2 to 1 over episodes 100–500: at 50 episodes the losses are the
    reference's with the constant weight 0.2, at 300 with 0.6 (half way), at 900 with plain MSE (1); the weight
    in force is logged as a metric."""
    batch, raws = episodes
    online, target = params
    annealed = BASE.override(n_step=3, macro_loss_weight=2.5, overestimate_weight=0.2, overestimate_weight_end=1.0,
                             overestimate_anneal_start=100, overestimate_anneal_episodes=400)
    constant = BASE.override(n_step=3, macro_loss_weight=2.5, overestimate_weight=weight)
    micro, macro, _, _, _ = reference_sjert(raws, nets, online, target, constant.algo, GAMMA)
    algo = make_algorithm(annealed, env)
    progress = PROGRESS.replace(episodes=jnp.int32(episodes_so_far))
    loss, metrics = jax.jit(algo.loss)(online, target, batch, jax.random.key(0), progress)
    np.testing.assert_allclose(float(metrics["overestimate_weight"]), weight, rtol=1e-6)
    np.testing.assert_allclose(float(metrics["micro_loss"]), micro, rtol=1e-5)
    np.testing.assert_allclose(float(metrics["macro_loss"]), macro, rtol=1e-5)
    np.testing.assert_allclose(float(loss), micro + 2.5 * macro, rtol=1e-5)


@pytest.mark.parametrize("bootstrap_time_limit", [True, False])
def test_mac_jert_loss_matches_the_reference(bootstrap_time_limit, env, episodes, nets, params):
    """The Mac-JERT ablation (``buffer="mac_jert"``): the single TD loss over the squeezed joint decision points
    (GRU and mixer on the squeezed rows) equals the loop reference, bootstrapping at the time limit or not;
    ``macro_loss`` is 0."""
    config = BASE.override(buffer="mac_jert", obs_mode="macro", overestimate_weight=0.7, macro_loss_weight=0.37,
                           bootstrap_time_limit=bootstrap_time_limit)
    batch, raws = episodes
    online, target = params
    expected, q_tot_mean, count, stats = reference_jert(raws, nets, online, target, config.algo, GAMMA)
    assert_nontrivial(stats)
    assert count >= 10

    loss, metrics = loss_of(config, env, batch, online, target)
    np.testing.assert_allclose(loss, expected, rtol=1e-5)
    np.testing.assert_allclose(metrics["micro_loss"], expected, rtol=1e-5)
    assert metrics["macro_loss"] == 0.0
    np.testing.assert_allclose(metrics["q_tot_mean"], q_tot_mean, rtol=1e-5, atol=1e-6)
