"""AVF (asynchronous value factorisation; Marchesini, Xiao, Amato; docs/baselines.md §1.7) on Mac-JERT.

Each agent has a recurrent Q_i (``networks.drqn.AgentDRQN``) stepping at every joint decision point on its own
frozen macro-observation; a mixer (VDN, QMIX or QPLEX) combines the utilities of the joint macro-action into
Q_tot, conditioned on the state at the decision row or, with ``macro_state`` (the "MS" variants), on the
concatenation of every agent's macro-state (the state when it chose its running macro-action). Loss, their
Eq. 13 — conditional double-Q on Q_tot::

    y = R^J + γ^{τ^J} Q_tot⁻(h′, s′, m*) · (1 − terminal),  m* = free agents' online argmax, busy agents pinned

(for QMIX/VDN the per-agent argmax maximises Q_tot exactly; for QPLEX it maximises it when every agent is free
— with agents pinned, λ(s, a) of the pinned agents depends on the free choices, and the per-agent argmax is
AVF's rule, not the exact conditional maximum). Update schemes for agents whose macro-action does not end at
the transition ("ongoing"): ``d0`` trains every utility, ``d1`` feeds ongoing utilities to the mixer without
gradient, ``d2`` replaces them by zero (their Q row is zeroed, so QPLEX's V_i is zero too). The target
networks follow by Polyak averaging (``target_polyak``). Acting: decentralised ε-greedy, each agent's GRU
stepping at joint decision points.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from envs_jax.validation import check_choice, check_positive
from jaxmac.algos.base import Algorithm, Learner, default_optimizer
from jaxmac.algos.families.decentralised import agents_step, agents_values, init_agent_drqn, sequence_q
from jaxmac.algos.families.drqn_settings import CEN_SCRIPT_VALUES, TINY_VALUES, DRQNSettings
from jaxmac.algos.targets import conditional_greedy
from jaxmac.buffer import windows
from jaxmac.config import TrainConfig
from jaxmac.losses import masked_mean, td_mse
from jaxmac.networks.drqn import AgentDRQN
from jaxmac.networks.mixers import Mixer, MixerConfig, init_mixer_params, mix_actions
from jaxmac.scenarios import SCENARIOS

MIXERS = ("qmix", "vdn", "qplex")


@dataclasses.dataclass(frozen=True)
class AVFSettings(DRQNSettings, algorithm="avf"):
    """AVF (docs/baselines.md §1.7): per-agent recurrent Q on Mac-JERT, mixed into Q_tot, conditional double-Q.

    ``scheme``: 'd0' trains every agent's utility at every joint transition; 'd1' gives agents whose
    macro-action is still running zero gradient (their utility enters Q_tot detached); 'd2' gives them zero
    utility in the mixer. ``macro_state``: the mixer is conditioned on the concatenation of every agent's
    macro-state (the env state when it selected its running macro-action; the "MS" variants) instead of the
    state at the joint decision point.
    """

    rnn_size: int = 64
    mlp_sizes: tuple[int, ...] = (64, 64)
    mixer: str = "qmix"
    scheme: str = "d0"
    macro_state: bool = True
    mixer_embed: int = 32
    hyper_hidden: int = 32

    def __post_init__(self):
        self._validate("avf")
        check_choice("avf", "mixer", self.mixer, MIXERS)
        check_choice("avf", "scheme", self.scheme, ("d0", "d1", "d2"))
        check_positive("avf", self, ("mixer_embed", "hyper_hidden"))


# AVF (docs/baselines.md §1.7): the value learners' schedule with AVF's own optimiser, buffer and target settings:
# lr 5e-4, batch 32, 2,500 episodes, Polyak ω = 0.995 after every step; windows as the value learners.
_AVF = dict(lr=5e-4, batch_size=32, buffer_episodes=2500, target_polyak=0.005)
SCENARIO_VALUES: dict[str, dict[str, Any]] = {
    name: dict(CEN_SCRIPT_VALUES[name], **_AVF, mlp_sizes=(64, 64),
               start_train_episodes=min(CEN_SCRIPT_VALUES[name]["start_train_episodes"], 2500),
               h_explore=True)  # AVF is not MacroMARL's runner: it keeps its recurrent state while exploring
    for name in SCENARIOS
}


def make_avf(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    n = spec.num_agents
    net = AgentDRQN(mlp=settings.mlp_sizes, hidden=settings.rnn_size, out=spec.max_actions)
    cond_dim = spec.state_dim * (n if settings.macro_state else 1)
    mixer_cfg = MixerConfig(num_agents=n, state_dim=cond_dim, kind=settings.mixer, embed=settings.mixer_embed,
                            hyper_hidden=settings.hyper_hidden, num_actions=spec.max_actions)
    mixer = Mixer(mixer_cfg)

    def init_params(key):
        k_agent, k_mixer = jax.random.split(key)
        return {"agent": init_agent_drqn(net, k_agent, n, spec.obs_dim), "mixer": init_mixer_params(mixer_cfg, k_mixer)}

    def step(params, carry, ts, key, epsilon, keep_history: bool):  # Mac-JERT history, as in training
        return agents_step(net, params["agent"], carry, ts, key, epsilon, keep_history, joint_history=True)

    def conditioning(state, macro_state):
        if settings.macro_state:
            return macro_state.reshape(macro_state.shape[:-2] + (-1,))
        return state

    def agent_q(params, obs):  # obs f32[B, L + 1, n, O] -> Q f32[B, L + 1, n, A] from a zero state
        return jnp.swapaxes(sequence_q(net, params, jnp.swapaxes(obs, 1, 2)), 1, 2)

    def loss(params, target_params, batch, key, progress):
        del key, progress
        view, obs = windows.jert_window(batch)  # leaves [B, L, ...], obs [B, L + 1, n, O]
        q = agent_q(params["agent"], obs)
        q_target = agent_q(target_params["agent"], obs)
        q_now = q[:, :-1]  # [B, L, n, A]
        ongoing = ~view.free_next[..., None]  # the agent's macro-action does not end at this transition
        if settings.scheme == "d1":
            q_now = jnp.where(ongoing, jax.lax.stop_gradient(q_now), q_now)
        elif settings.scheme == "d2":
            q_now = jnp.where(ongoing, 0.0, q_now)
        weights, _ = mixer.apply(params["mixer"], conditioning(view.state, view.macro_state))
        q_tot = mix_actions(weights, q_now, view.mac, view.avail)
        best = conditional_greedy(jax.lax.stop_gradient(q[:, 1:]), view.avail_next, view.free_next, view.next_mac)
        weights_next, _ = mixer.apply(target_params["mixer"], conditioning(view.state_next, view.macro_state_next))
        boot = mix_actions(weights_next, q_target[:, 1:], best, view.avail_next)
        y = jax.lax.stop_gradient(view.reward + view.discount * boot)
        value = td_mse(q_tot - y, view.mask)
        return value, {"q_tot_mean": masked_mean(q_tot, view.mask), "jert_entries": view.mask.sum() / view.mask.shape[0]}

    return Algorithm(
        name="avf", init_params=init_params,
        init_carry=lambda num_agents: jnp.zeros((num_agents, settings.rnn_size), jnp.float32),
        act=lambda p, c, ts, k, e: step(p, c, ts, k, e, True), loss=loss, optimizer=default_optimizer(config),
        behaviour_act=lambda p, c, ts, k, e, episodes: step(p, c, ts, k, e, settings.h_explore),
        store=windows.store_views(jert=True, cert=False),
        sample=windows.window_source(config.batch_size, settings.trace_len),
        values=lambda p, c, ts: agents_values(net, p["agent"], c, ts, True)[0])


LEARNER = Learner("avf", AVFSettings, make_avf, SCENARIO_VALUES, dict(TINY_VALUES, mixer_embed=8, hyper_hidden=8),
                  "AVF: per-agent recurrent Q on Mac-JERT mixed by VDN/QMIX/QPLEX, conditional double-Q, Polyak target")
