"""Small array operations every layer uses (networks, targets, acting, losses): the bottom of the package, importing
nothing of jaxmac.

Per-agent values are ``f32[..., A]`` over an agent's padded macro-actions with an ``avail`` mask ``bool[..., A]``;
joint actions ``i32[..., n]``.
"""

from __future__ import annotations

import chex
import jax.numpy as jnp

MASK_VALUE = -1e9
"""Q-value given to unavailable actions by ``mask_unavailable`` (finite, so sums never give NaN)."""


def mask_unavailable(q: chex.Array, avail: chex.Array) -> chex.Array:
    """``q`` f32[..., A] with unavailable actions (``avail`` bool[..., A] False) set to ``MASK_VALUE``."""
    return jnp.where(avail, q, jnp.asarray(MASK_VALUE, q.dtype))


def masked_argmax(q: chex.Array, avail: chex.Array) -> chex.Array:
    """Greedy available action: i32[...] from ``q`` f32[..., A] and ``avail`` bool[..., A]."""
    return jnp.argmax(mask_unavailable(q, avail), axis=-1).astype(jnp.int32)


def gather_q(q: chex.Array, actions: chex.Array) -> chex.Array:
    """Q_i of a joint action: f32[..., n] from ``q`` f32[..., n, A] and ``actions`` i32[..., n].

    Negative actions (padding, ``mac = -1``) gather action 0; mask those entries in the loss.
    """
    a = jnp.clip(actions, 0, q.shape[-1] - 1)
    return jnp.take_along_axis(q, a[..., None], axis=-1)[..., 0]
