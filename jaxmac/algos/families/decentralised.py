"""Pieces of the decentralised recurrent Q learners (MacDec-Q, the decentralised half of Mac-Dec-MADDRQN).

Each agent has its own DRQN (``networks.drqn.AgentDRQN``) over its own frozen macro-observations at its own
decision points (Mac-CERT, docs/baselines.md §1.1), trained with the hysteretic double-Q target::

    y_i = R_i + γ^{τ_i} Q_i⁻(h′_i, a′_i) · (1 − terminal),   δ = y_i − Q_i(h_i, m_i),   δ ← max(β δ, δ)

where ``a′_i`` is the online net's available argmax (MacDec-Q) or supplied by the caller (Mac-Dec-MADDRQN's
component of the centralised argmax). The loss is each agent's mean δ² over its entries, summed over agents
(the original trains one net per agent).
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

from jaxmac.algos.acting import epsilon_greedy
from jaxmac.buffer import windows
from jaxmac.losses import masked_mean, td_mse
from jaxmac.networks.drqn import AgentDRQN
from jaxmac.ops import gather_q, masked_argmax
from jaxmac.schedules import linear_schedule


def init_agent_drqn(net: AgentDRQN, key: chex.PRNGKey, num_agents: int, obs_dim: int):
    x = jnp.zeros((1, num_agents, obs_dim))
    return net.init(key, x, jnp.zeros((1,), bool), jnp.zeros((num_agents, net.hidden)))


def sequence_q(net: AgentDRQN, params, obs: chex.Array) -> chex.Array:
    """Every agent's net over its own squeezed sequence ``obs`` f32[B, n, T, O] from a zero state: f32[B, n, T, A]."""
    b, n, steps = obs.shape[:3]
    x = jnp.swapaxes(obs, 1, 2).astype(jnp.float32)  # [B, T, n, O]: agents on axis -2
    reset = jnp.broadcast_to(jnp.arange(steps) == 0, (b, steps))
    q, _ = net.apply(params, x, reset, jnp.zeros((b, n, net.hidden)))
    return jnp.swapaxes(q, 1, 2)


def hysteretic_double_q_loss(net: AgentDRQN, params, target_params, batch: windows.WindowBatch, beta,
                             next_actions=None):
    """Hysteretic double-Q on each agent's Mac-CERT entries of a batch of windows.

    Args:
      beta: f32[] hysteresis β in (0, 1] (1 = plain MSE).
      next_actions: ``view -> i32[B, n, L]``, the action valued at each entry's bootstrap given the cropped
        ``CertView``; None = each agent's online argmax.
    Returns:
      (loss, metrics, view) with ``view`` the cropped ``CertView`` (leaves [B, n, L, ...]).
    """
    view, obs = windows.cert_window(batch)
    q = sequence_q(net, params, obs)  # [B, n, L + 1, A]
    q_target = sequence_q(net, target_params, obs)
    q_taken = gather_q(q[:, :, :-1], view.mac)
    if next_actions is None:
        chosen = masked_argmax(jax.lax.stop_gradient(q[:, :, 1:]), view.avail_next)
    else:
        chosen = next_actions(view)
    boot = gather_q(q_target[:, :, 1:], chosen)
    y = jax.lax.stop_gradient(view.reward + view.discount * boot)
    # δ = y − Q scaled by β where negative  ==  (Q − y)² weighted by β² where Q is above y
    per_agent = jax.vmap(lambda d, m: td_mse(d, m, beta**2), in_axes=1)(q_taken - y, view.mask)
    loss = per_agent.sum()
    metrics = {"dec_loss": loss, "dec_q_mean": masked_mean(q_taken, view.mask), "hysteresis": beta,
               "cert_entries": view.mask.sum() / view.mask.shape[0]}
    return loss, metrics, view


def agents_values(net: AgentDRQN, params, carry, ts, keep_history: bool):
    """Every agent's Q f32[n, A] at one primitive step (from its history when ``keep_history``, else from a zero
    state; a new episode starts from zero) and the GRU state after it, f32[n, h] (``agents_step`` decides whom it
    steps)."""
    carry = jnp.where(ts.t == 0, jnp.zeros_like(carry), carry)
    start = carry if keep_history else jnp.zeros_like(carry)
    x = jnp.asarray(ts.obs_macro, jnp.float32)[None]  # [1, n, O]
    q, new_carry = net.apply(params, x, jnp.zeros((1,), bool), start)
    return q[0], new_carry


def agents_step(net: AgentDRQN, params, carry, ts, key, epsilon, keep_history: bool, joint_history: bool = False):
    """Decentralised ε-greedy at one primitive step: each free agent chooses from its own net; an agent's GRU steps
    only at its own decisions (Mac-CERT history), or with ``joint_history`` at every joint decision point (Mac-JERT
    history, AVF), and only with ``keep_history`` (else each decision is valued from a zero state).
    ``carry`` f32[n, h]. Returns ``(carry, actions i32[n])``."""
    q, new_carry = agents_values(net, params, carry, ts, keep_history)
    carry = jnp.where(ts.t == 0, jnp.zeros_like(carry), carry)
    actions = epsilon_greedy(key, q, ts.avail_actions, ts.mac_done, ts.mac, epsilon)
    if keep_history:
        steps = jnp.any(ts.mac_done) if joint_history else ts.mac_done[:, None]
        carry = jnp.where(steps, new_carry, carry)
    return carry, actions


def hysteresis(settings, config, episodes: chex.Array) -> chex.Array:
    """β linear from ``hysteresis_start`` to ``hysteresis_end`` over ``hysteresis_episodes`` episodes after
    ``start_train_episodes`` (the originals' ``dynamic_h``)."""
    return linear_schedule(episodes, config.start_train_episodes, settings.hysteresis_episodes,
                           settings.hysteresis_start, settings.hysteresis_end)
