"""Acting rules shared by the learners: the ε schedule and ε-greedy choices of the free agents.

Every rule returns the full joint action ``i32[n]``; busy agents re-send their running macro-action (the env
ignores it anyway, DECISIONS D17), free agents (``ts.mac_done``) choose.
"""

from __future__ import annotations

from collections.abc import Sequence

import chex
import jax
import jax.numpy as jnp

from envs_jax.policies import uniform_random_actions
from jaxmac.algos.targets import joint_conditional_argmax
from jaxmac.ops import masked_argmax
from jaxmac.schedules import linear_schedule


def epsilon_schedule(config, episodes: chex.Array) -> chex.Array:
    """Linear decay from ``eps_start`` to ``eps_end`` over ``eps_decay_episodes`` training episodes, starting
    after ``eps_decay_start`` episodes."""
    return linear_schedule(episodes, config.eps_decay_start, config.eps_decay_episodes, config.eps_start,
                           config.eps_end)


def epsilon_greedy(key: chex.PRNGKey, q: chex.Array, avail: chex.Array, free: chex.Array, running: chex.Array,
                   epsilon: chex.Array) -> chex.Array:
    """Per-agent ε-greedy among available actions for free agents; busy agents keep ``running``.

    Args:
      q: f32[n, A] each agent's values of its macro-actions.
      avail: bool[n, A]; free: bool[n]; running: i32[n]; epsilon: f32[].
    Returns:
      i32[n].
    """
    k_explore, k_random = jax.random.split(key)
    explore = jax.random.uniform(k_explore, free.shape) < epsilon
    chosen = jnp.where(explore, uniform_random_actions(k_random, avail), masked_argmax(q, avail))
    return jnp.where(free, chosen, running)


def joint_epsilon_greedy(key: chex.PRNGKey, q_joint: chex.Array, avail: chex.Array, free: chex.Array,
                         running: chex.Array, epsilon: chex.Array, action_counts: Sequence[int]) -> chex.Array:
    """Centralised conditional ε-greedy (MacCen-Q's controller): with probability ε every free agent takes a
    uniformly random available action, otherwise the conditional argmax of the joint table is taken; busy
    agents keep ``running`` either way.

    Args:
      q_joint: f32[|M_1|·…·|M_n|]; avail bool[n, A]; free bool[n]; running i32[n]; epsilon f32[].
    Returns:
      i32[n].
    """
    k_explore, k_random = jax.random.split(key)
    greedy = joint_conditional_argmax(q_joint, avail, free, running, action_counts)
    explore = jax.random.uniform(k_explore) < epsilon
    chosen = jnp.where(explore, uniform_random_actions(k_random, avail), greedy)
    return jnp.where(free, chosen, running)
