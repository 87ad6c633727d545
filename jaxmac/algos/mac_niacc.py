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

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.algos.families import actor_critic as ac
from jaxmac.algos.families import centralised
from jaxmac.algos.base import Algorithm, clipped_adam, on_policy_source, per_part_optimizer, store_length
from jaxmac.config import TrainConfig


def make_mac_niacc(config: TrainConfig, env: MacroEnv) -> Algorithm:
    ac.check_on_policy(config, "mac_niacc")
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
