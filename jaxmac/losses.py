"""Losses shared by the learners (written for arrays of any shape with a mask; no batch bookkeeping)."""

from __future__ import annotations

import chex
import jax.numpy as jnp


def td_mse(delta: chex.Array, mask: chex.Array, overestimate_weight: float | chex.Array = 1.0) -> chex.Array:
    """Mean over ``mask`` of ``w · delta²`` with ``delta = Q − y`` (prediction minus target).

    ``w = overestimate_weight`` where ``delta > 0`` (the prediction is above its target) and 1 elsewhere.
    1 (the default) is plain MSE; ToMacVF's optimistic weighting passes its ``overestimate_weight``; the
    originals' hysteresis ``δ ← max(β δ, δ)`` on ``δ = y − Q`` is ``overestimate_weight = β²``. The weight may
    be a traced scalar (a scheduled β). The mean divides by the number of entries with a positive mask.

    Args:
      delta: f32[...] TD errors.
      mask: bool/f32[...] (same shape) which entries count.
      overestimate_weight: python float or f32[] in (0, 1].
    Returns:
      f32[] the loss.
    """
    mask = mask.astype(jnp.float32)
    if not (isinstance(overestimate_weight, (int, float)) and overestimate_weight == 1.0):
        mask = mask * jnp.where(delta > 0, overestimate_weight, 1.0)
    return jnp.sum(mask * delta**2) / jnp.maximum((mask > 0).sum(), 1.0)


def masked_mean(x: chex.Array, mask: chex.Array) -> chex.Array:
    """Mean of ``x`` over the entries where ``mask`` is set (0 when none is)."""
    mask = mask.astype(x.dtype)
    return jnp.sum(x * mask) / jnp.maximum(mask.sum(), 1)
