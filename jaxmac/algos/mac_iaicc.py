"""Mac-IAICC (MacroMARL's main actor-critic learner; docs/baselines.md §1.6): independent actors, individual centralised
critics.

Each agent i has an actor π_i(m_i | h_i) over its own Mac-CERT history and its own critic V_i, trained on its own
macro-actions with n-step macro returns (``jaxmac.algos.families.actor_critic``)::

    G_k = R_{i,k} + γ^{τ_{i,k}} V_i⁻(after macro-action k)   (n = 1; more steps by ``n_step``),   A_k = G_k − V_i(k)

* ``critic='history'`` (Overcooked, Warehouse): V_i's GRU runs over the joint macro-observations at every joint
  decision point (Mac-JERT); macro-action k is scored at the joint entry where it started, and bootstraps from the
  joint history right after the entry where it ended.
* ``critic='state'`` (the Box Pushing scripts' ``MacIAISC``): V_i(s) an MLP of the global state where macro-action
  k was chosen; the bootstrap is V_i⁻ of the state after it ended.

On-policy: each round's ``num_envs`` episodes give one critic step, then one actor step with advantages from the
updated critic; the target critics are hard copies every ``target_update_episodes``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.algos.base import (
    Algorithm,
    Learner,
    clipped_adam,
    per_part_optimizer,
)
from jaxmac.algos.families import actor_critic as ac
from jaxmac.algos.families.actor_critic_settings import TINY_VALUES, IndependentActorsSettings, script_values
from jaxmac.buffer.sources import on_policy_source, store_length
from jaxmac.config import TrainConfig


@dataclasses.dataclass(frozen=True)
class MacIAICCSettings(IndependentActorsSettings, algorithm="mac_iaicc"):
    """Mac-IAICC (docs/baselines.md §1.6): per-agent actors, an individual centralised critic V_i per agent."""

    def __post_init__(self):
        self._validate("mac_iaicc")


# mac_iaicc.sh's rows (docs/hyperparameters.md; Box Pushing: the state critic, MacIAISC)
_OC_CRITIC = (128, 64)  # the Overcooked scripts' critic MLP
SCENARIO_VALUES = script_values({
    "boxpushing-6x6": dict(lr=3e-4, critic_lr=3e-3, num_envs=32, target_update_episodes=128, n_step=0, eps_end=0.01,
                           eps_decay_episodes=4000, episodes=40_000),
    "boxpushing-8x8": dict(lr=3e-4, critic_lr=3e-3, num_envs=32, target_update_episodes=64, n_step=0, eps_end=0.01,
                           eps_decay_episodes=4000, episodes=40_000),
    "boxpushing-10x10": dict(lr=3e-4, critic_lr=3e-3, num_envs=32, target_update_episodes=64, n_step=0, eps_end=0.01,
                             eps_decay_episodes=6000, episodes=40_000),
    "boxpushing-12x12": dict(lr=3e-4, critic_lr=3e-3, num_envs=48, target_update_episodes=144, n_step=0,
                             eps_end=0.01, eps_decay_episodes=6000, episodes=40_000),
    "boxpushing-14x14": dict(lr=5e-4, critic_lr=3e-3, num_envs=48, target_update_episodes=0, n_step=0, eps_end=0.01,
                             eps_decay_episodes=8000, episodes=40_000),  # the script: 48
    "overcooked-A": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=32, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=100_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "overcooked-B": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=32, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=120_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "overcooked-C": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=32, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=100_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "warehouse-A": dict(lr=5e-4, critic_lr=5e-4, num_envs=4, target_update_episodes=32, n_step=5, eps_end=0.05,
                        eps_decay_episodes=10_000, episodes=40_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-B": dict(lr=5e-4, critic_lr=5e-4, num_envs=4, target_update_episodes=32, n_step=5, eps_end=0.05,
                        eps_decay_episodes=10_000, episodes=40_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-C": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=64, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=80_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-D": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=64, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=80_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-E": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=64, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=100_000, actor_rnn_size=32, critic_rnn_size=64),
}, boxpushing=dict(critic="state"))


def make_mac_iaicc(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    n = spec.num_agents
    actors = ac.AgentActors.make(settings, spec)
    history = settings.critic == "history"
    critic, init_critic = ac.centralised_critic(settings, spec, per_agent=True)

    def init_params(key):
        k_actor, k_critic = jax.random.split(key)
        return {"actor": actors.init(k_actor), "critic": init_critic(k_critic)}

    def joint_values(critic_params, batch):  # every agent's critic over the joint history: f32[E, n, H + 1]
        x = ac.joint_history(batch.jert)  # [E, T, n·O]
        e, steps = x.shape[:2]
        x = jnp.broadcast_to(x[:, :, None, :], (e, steps, n, x.shape[-1]))
        reset = jnp.broadcast_to(jnp.arange(steps) == 0, (e, steps))
        v, _ = critic.apply(critic_params, x, reset, jnp.zeros((e, n, settings.critic_rnn_size)))
        return jnp.swapaxes(v[..., 0], 1, 2)

    def state_values(critic_params, states):  # f32[E, n, K, S] -> f32[E, n, K] (agents on axis -2 for the net)
        return jnp.swapaxes(critic.apply(critic_params, jnp.swapaxes(states, 1, 2))[..., 0], 1, 2)

    def critic_values(critic_params, batch):  # V_i at agent i's macro-actions: f32[E, n, K]
        if history:
            return jnp.take_along_axis(joint_values(critic_params, batch), batch.start_joint, -1)
        return state_values(critic_params, batch.cert_state)

    def critic_targets(target_critic, batch):
        cert = batch.cert
        if history:
            boot = jnp.take_along_axis(joint_values(target_critic, batch), batch.end_joint + 1, -1)
        else:
            boot = state_values(target_critic, batch.cert_state_next)
        return ac.macro_returns(cert.reward, cert.discount, boot, cert.mask, settings.n_step), cert.mask

    def actor_loss(actor_params, batch, advantage, epsilon):
        return actors.loss(actor_params, batch.cert, advantage, epsilon)

    optimizers = {"actor": clipped_adam(config.lr, config.grad_clip),
                  "critic": clipped_adam(settings.critic_lr, config.grad_clip)}
    prepare = ac.prepare_on_policy(cert=True, jert=history, cert_states=not history, alignment=history)
    return Algorithm(
        name="mac_iaicc", init_params=init_params, init_carry=actors.init_carry, act=actors.act, loss=None,
        optimizer=per_part_optimizer(optimizers),
        update=ac.critic_then_actor_update(critic_targets, critic_values, actor_loss, optimizers, config),
        store=store_length, sample=on_policy_source(prepare), greedy_act=actors.greedy_act)


LEARNER = Learner("mac_iaicc", MacIAICCSettings, make_mac_iaicc, SCENARIO_VALUES, TINY_VALUES,
                  "Mac-IAICC: per-agent actors, individual centralised critics V_i (history or state), on-policy")
