"""Uniform-random rollouts in the shape ``episode.write_episode`` expects (tests, benchmarks)."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp


def random_actions(key: chex.PRNGKey, avail: chex.Array) -> chex.Array:
    """One available action per agent, uniformly. avail: bool[n, A] → i32[n]."""
    logits = jnp.where(avail, 0.0, -jnp.inf)
    return jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)


def random_episode(env, key: chex.PRNGKey, num_steps: int | None = None):
    """Reset ``env`` and take ``num_steps`` (default: its horizon) uniformly random steps.

    No auto-reset: steps after the episode ends keep stepping the finished state and are
    masked by the writer. Returns ``(reset_ts, traj)`` with ``traj`` leaves ``[num_steps, ...]``.
    """
    num_steps = env.spec.horizon if num_steps is None else num_steps
    key_reset, key_steps = jax.random.split(key)
    state, reset_ts = env.reset(key_reset)

    def body(carry, k):
        state, ts = carry
        k_act, k_step = jax.random.split(k)
        state, ts = env.step(k_step, state, random_actions(k_act, ts.avail_actions))
        return (state, ts), ts

    _, traj = jax.lax.scan(body, (state, reset_ts), jax.random.split(key_steps, num_steps))
    return reset_ts, traj
