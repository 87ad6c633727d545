"""Index arithmetic shared by the episode writer and the views.

Two primitives, both fixed-shape and free of Python loops over time:

* ``pack(mask, k)``: left-pack the positions where ``mask`` is True into ``k`` slots
  (the JAX form of MacroMARL's ``tensor[mask]`` + ``pad_sequence`` squeeze), as an index
  view plus a validity mask;
* ``running_sum(x, reset)``: the running accumulator ``acc_t = x_t if reset_t else
  acc_{t-1} + x_t`` along the leading axis, computed with a parallel associative scan.
  Fed with ``x_t = γ^k_t r_t`` (``k_t`` = steps since the last reset) it is exactly the
  per-agent / joint discounted reward accumulator of the original runners.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp


def pack(mask: chex.Array, k: int) -> tuple[chex.Array, chex.Array]:
    """Left-pack the True positions of ``mask`` (in order) into ``k`` entries.

    Args:
      mask: bool[T].
      k: output length (static). Positions beyond the first ``k`` True ones are dropped.
    Returns:
      idx: i32[k] positions of the True entries in increasing order, 0 in the padding.
      valid: bool[k] which entries are real (a prefix).
    """
    (t,) = mask.shape
    slot = jnp.cumsum(mask) - 1  # destination of each True entry
    slot = jnp.where(mask, slot, k)  # False entries go out of range and are dropped
    idx = jnp.zeros((k,), jnp.int32).at[slot].set(jnp.arange(t, dtype=jnp.int32), mode="drop")
    valid = jnp.arange(k) < jnp.sum(mask)
    return idx, valid


def running_sum(x: chex.Array, reset: chex.Array) -> chex.Array:
    """Running sum of ``x`` along axis 0 that restarts wherever ``reset`` is True.

    Args:
      x: f32[T, ...].
      reset: bool[T, ...] (same shape): ``acc_t = x_t`` there, else ``acc_{t-1} + x_t``.
        Position 0 always starts a new sum.
    Returns:
      f32[T, ...] the accumulator after each position.
    """
    reset = reset.at[0].set(True)

    def combine(a, b):
        # (value, has_reset) pairs: a later reset discards everything before it.
        va, ra = a
        vb, rb = b
        return jnp.where(rb, vb, va + vb), ra | rb

    acc, _ = jax.lax.associative_scan(combine, (x, reset), axis=0)
    return acc


def discount_powers(gamma: float, k: chex.Array) -> chex.Array:
    """``γ^k`` as float32 for integer exponents ``k`` (any shape)."""
    return jnp.power(jnp.float32(gamma), jnp.asarray(k, jnp.float32))
