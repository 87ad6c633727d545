"""Mac-NIACC ("naive" Mac-IACC; docs/baselines.md §1.5): independent actors, one joint centralised critic.

One critic V over joint decision points (Mac-JERT) is trained with joint n-step macro returns; agent i's
macro-action k takes the *joint* advantage of the joint entry at which it ended::

    A^J_j = G^J_j − V(j),   A_{i,k} = A^J_{j(i,k)}   (j(i,k): the Mac-JERT entry at agent i's termination)

which spans only the last joint step of its macro-action (hence "naive"; Mac-IAICC's individual critics score the
whole macro-action). ``critic='history'``: V's GRU reads the joint macro-observations; ``critic='state'`` (the Box
Pushing scripts' ``NaiveMacIASC``): V(s) an MLP of the state at the joint decision point. Actors, acting and the
on-policy critic-then-actor update as Mac-IAICC (``jaxmac.algos.families.actor_critic``).
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
from jaxmac.algos.families import centralised
from jaxmac.algos.families.actor_critic_settings import TINY_VALUES, IndependentActorsSettings, script_values
from jaxmac.buffer.sources import on_policy_source, store_length
from jaxmac.config import TrainConfig


@dataclasses.dataclass(frozen=True)
class MacNIACCSettings(IndependentActorsSettings, algorithm="mac_niacc"):
    """Mac-NIACC (docs/baselines.md §1.5): per-agent actors, one joint critic, the joint ("naive") advantage."""

    def __post_init__(self):
        self._validate("mac_niacc")


# mac_naive_iacc.sh's rows (docs/hyperparameters.md; Box Pushing: the state critic, NaiveMacIASC)
_OC_CRITIC = (128, 64)  # the Overcooked scripts' critic MLP
SCENARIO_VALUES = script_values({
    "boxpushing-6x6": dict(lr=3e-4, critic_lr=3e-3, num_envs=32, target_update_episodes=128, n_step=0, eps_end=0.01,
                           eps_decay_episodes=4000, episodes=40_000),
    "boxpushing-8x8": dict(lr=5e-4, critic_lr=1e-3, num_envs=32, target_update_episodes=128, n_step=0, eps_end=0.01,
                           eps_decay_episodes=4000, episodes=40_000),
    "boxpushing-10x10": dict(lr=5e-4, critic_lr=1e-3, num_envs=32, target_update_episodes=128, n_step=0,
                             eps_end=0.01, eps_decay_episodes=6000, episodes=40_000),
    "boxpushing-12x12": dict(lr=5e-4, critic_lr=5e-4, num_envs=48, target_update_episodes=0, n_step=0, eps_end=0.01,
                             eps_decay_episodes=6000, episodes=40_000),  # the script: 48
    "boxpushing-14x14": dict(lr=5e-4, critic_lr=5e-4, num_envs=32, target_update_episodes=128, n_step=0,
                             eps_end=0.01, eps_decay_episodes=8000, episodes=40_000),
    "overcooked-A": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=16, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=100_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "overcooked-B": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=16, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=120_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "overcooked-C": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=16, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=100_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "warehouse-A": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=32, n_step=3, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=40_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-B": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=32, n_step=3, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=40_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-C": dict(lr=3e-4, critic_lr=3e-3, num_envs=16, target_update_episodes=64, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=80_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-D": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=64, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=80_000, actor_rnn_size=32, critic_rnn_size=64),
    "warehouse-E": dict(lr=5e-4, critic_lr=5e-4, num_envs=4, target_update_episodes=32, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=100_000, actor_rnn_size=32, critic_rnn_size=64),
}, boxpushing=dict(critic="state"))


def make_mac_niacc(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    actors = ac.AgentActors.make(settings, spec)
    history = settings.critic == "history"
    critic, init_critic = ac.centralised_critic(settings, spec, per_agent=False)

    def init_params(key):
        k_actor, k_critic = jax.random.split(key)
        return {"actor": actors.init(k_actor), "critic": init_critic(k_critic)}

    def values_and_next(critic_params, jert):  # V at each joint entry and after it: f32[E, 1, H] each
        if history:
            obs = ac.joint_history(jert)  # [E, H + 1, n·O]
            v = centralised.sequence_q(critic, critic_params, obs.reshape(obs.shape[:2] + (1, -1)))[..., 0]
            return v[:, None, :-1], v[:, None, 1:]
        return (critic.apply(critic_params, jert.state)[..., 0][:, None],
                critic.apply(critic_params, jert.state_next)[..., 0][:, None])

    def critic_values(critic_params, batch):
        return values_and_next(critic_params, batch.jert)[0]

    def critic_targets(target_critic, batch):
        jert = batch.jert
        boot = values_and_next(target_critic, jert)[1][:, 0]
        returns = ac.macro_returns(jert.reward, jert.discount, boot, jert.mask, settings.n_step)
        return returns[:, None], jert.mask[:, None]

    def actor_loss(actor_params, batch, advantage, epsilon):  # advantage f32[E, 1, H] at the joint entries
        joint = jnp.broadcast_to(advantage, (advantage.shape[0], spec.num_agents, advantage.shape[-1]))
        return actors.loss(actor_params, batch.cert, jnp.take_along_axis(joint, batch.end_joint, -1), epsilon)

    optimizers = {"actor": clipped_adam(config.lr, config.grad_clip),
                  "critic": clipped_adam(settings.critic_lr, config.grad_clip)}
    prepare = ac.prepare_on_policy(cert=True, jert=True, alignment=True)
    return Algorithm(
        name="mac_niacc", init_params=init_params, init_carry=actors.init_carry, act=actors.act, loss=None,
        optimizer=per_part_optimizer(optimizers),
        update=ac.critic_then_actor_update(critic_targets, critic_values, actor_loss, optimizers, config),
        store=store_length, sample=on_policy_source(prepare), greedy_act=actors.greedy_act)


LEARNER = Learner("mac_niacc", MacNIACCSettings, make_mac_niacc, SCENARIO_VALUES, TINY_VALUES,
                  "Mac-NIACC: per-agent actors, one joint critic (history or state), the joint advantage, on-policy")
