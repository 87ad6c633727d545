"""Simple policies for rollouts, tests and benchmarks."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp


def uniform_random_actions(key: chex.PRNGKey, avail_actions: chex.Array) -> chex.Array:
    """A uniformly random *available* action per agent.

    ``avail_actions``: bool[..., A] (any leading batch shape, e.g. ``[n]`` or ``[B, n]``);
    returns i32[...]. One uniform draw per agent picks the k-th available action, which is
    much cheaper on CPU than a Gumbel/categorical draw over all actions. Rows without any
    available action are a caller error (the result is then 0).
    """
    count = avail_actions.sum(-1)
    u = jax.random.uniform(key, count.shape)
    k = jnp.minimum(jnp.floor(u * count).astype(jnp.int32), count - 1)  # k-th available, 0-based
    rank = jnp.cumsum(avail_actions, -1) - 1  # rank of each available action
    hit = avail_actions & (rank == k[..., None])
    return jnp.argmax(hit, -1).astype(jnp.int32)
