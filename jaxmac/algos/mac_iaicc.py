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

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.algos.families import actor_critic as ac
from jaxmac.algos.base import Algorithm, clipped_adam, on_policy_source, per_part_optimizer, store_length
from jaxmac.config import TrainConfig


def make_mac_iaicc(config: TrainConfig, env: MacroEnv) -> Algorithm:
    ac.check_on_policy(config, "mac_iaicc")
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
