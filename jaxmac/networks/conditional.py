"""The conditional (To-Mac-IGM) greedy joint action (DECISIONS D9).

At a bootstrap row only the *free* agents (their macro-action just terminated) choose; busy agents
keep their running macro-action. Because the mixer is monotone in every Q_i for weights that do
not depend on the free agents' choices (D4, D6), taking each free agent's available argmax of
its Q_i (at τ = 0) maximises Q_tot over the free agents' joint actions with the busy ones pinned.
"""

from __future__ import annotations

import chex
import jax.numpy as jnp

from jaxmac.networks.agent import masked_argmax


def conditional_greedy(q: chex.Array, avail: chex.Array, free: chex.Array, running: chex.Array) -> chex.Array:
    """Joint action: free agents take their masked argmax, busy agents keep their macro-action.

    Args:
      q: f32[..., n, A] Q_i(ĥ, m, τ) for every macro-action m (free agents valued at τ = 0).
      avail: bool[..., n, A] available actions.
      free: bool[..., n] the agent chooses now.
      running: i32[..., n] the running macro-action of busy agents (ignored where free).
    Returns:
      i32[..., n] the joint macro-action.
    """
    return jnp.where(free, masked_argmax(q, avail), running).astype(jnp.int32)


def gather_q(q: chex.Array, actions: chex.Array) -> chex.Array:
    """Q_i of a joint action: f32[..., n] from ``q`` f32[..., n, A] and ``actions`` i32[..., n].

    Negative actions (padding, ``mac = -1``) gather action 0; mask those entries in the loss.
    """
    a = jnp.clip(actions, 0, q.shape[-1] - 1)
    return jnp.take_along_axis(q, a[..., None], axis=-1)[..., 0]
