"""Conditional greedy actions for bootstrap targets (docs/baselines.md §0 fact 2, DECISIONS D9).

At a joint decision point only the *free* agents (their macro-action just ended) choose; agents still
executing are pinned to their running macro-action. Two forms:

* factored values (ToMacVF, AVF, MacDec-Q): ``conditional_greedy`` — each free agent takes its available
  argmax, busy agents keep their action. Exact for mixers that are monotone in every Q_i with weights that do
  not depend on the free agents' choices (QMIX/VDN with ToMacVF's ATPG, D4, D6).
* a joint Q table over the joint macro-action space (Mac-Cen-DDRQN, Mac-Dec-MADDRQN): ``joint_conditional_argmax``
  — one masked argmax over the table reshaped to ``[|M_1|, …, |M_n|]`` with busy agents' axes restricted to
  their running action and every axis to the available actions.

Joint indices are row-major over the *true* per-agent action counts (``np.ravel_multi_index``, as the
originals): ``j = ((a_1 · |M_2| + a_2) · |M_3| + a_3) …``.
"""

from __future__ import annotations

from collections.abc import Sequence

import chex
import jax.numpy as jnp
import numpy as np

from jaxmac.ops import MASK_VALUE, masked_argmax


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


def admissible_actions(avail: chex.Array, free: chex.Array, running: chex.Array) -> chex.Array:
    """bool[..., n, A]: the macro-actions agent i may take at a row — its available ones when it is free, only its
    running one when it is busy (To-Mac-IGM's conditional action set, D9).

    Args as ``conditional_greedy``. Rows whose busy agent has no running action (``running < 0``: padding beyond an
    episode's end) keep ``avail`` so that a max over the set is defined; such rows are masked out of every loss.
    """
    pinned = (jnp.arange(avail.shape[-1]) == running[..., None]) | ((running[..., None] < 0) & avail)
    return jnp.where(free[..., None], avail, pinned)


def joint_action_count(action_counts: Sequence[int]) -> int:
    """|M_1| · … · |M_n|."""
    return int(np.prod(action_counts))


def ravel_joint(actions: chex.Array, action_counts: Sequence[int]) -> chex.Array:
    """i32[...] joint index of per-agent actions i32[..., n] (negative entries give index 0: mask them)."""
    a = jnp.clip(actions, 0, jnp.asarray(action_counts) - 1)
    strides = np.cumprod((list(action_counts[1:]) + [1])[::-1])[::-1].astype(np.int32)
    return jnp.sum(a * strides, axis=-1).astype(jnp.int32)


def unravel_joint(index: chex.Array, action_counts: Sequence[int]) -> chex.Array:
    """i32[..., n] per-agent actions of joint indices i32[...] (inverse of ``ravel_joint``)."""
    strides = np.cumprod((list(action_counts[1:]) + [1])[::-1])[::-1].astype(np.int32)
    return ((index[..., None] // strides) % np.asarray(action_counts, np.int32)).astype(jnp.int32)


def joint_mask(avail: chex.Array, free: chex.Array, running: chex.Array, action_counts: Sequence[int]) -> chex.Array:
    """bool[..., |M_1|·…·|M_n|]: joint actions whose free agents pick available actions and whose busy agents
    keep their running action.

    Args:
      avail: bool[..., n, A] (padded; agent i uses its first ``action_counts[i]`` entries).
      free: bool[..., n].
      running: i32[..., n] running macro-action of busy agents.
    """
    n = len(action_counts)
    mask = None
    for i, a_i in enumerate(action_counts):  # static, n ≤ 4: builds one broadcast product, no runtime loop
        allowed = jnp.where(free[..., i, None], avail[..., i, :a_i], jnp.arange(a_i) == running[..., i, None])
        shape = allowed.shape[:-1] + (1,) * i + (a_i,) + (1,) * (n - 1 - i)
        allowed = allowed.reshape(shape)
        mask = allowed if mask is None else jnp.logical_and(mask, allowed)
    return mask.reshape(mask.shape[:-n] + (-1,))


def joint_conditional_argmax(q_joint: chex.Array, avail: chex.Array, free: chex.Array, running: chex.Array,
                             action_counts: Sequence[int]) -> chex.Array:
    """Conditional argmax over a joint Q table: i32[..., n] per-agent actions.

    Args:
      q_joint: f32[..., |M_1|·…·|M_n|].
      avail, free, running: as in ``joint_mask``.
    """
    masked = jnp.where(joint_mask(avail, free, running, action_counts), q_joint, MASK_VALUE)
    return unravel_joint(jnp.argmax(masked, axis=-1).astype(jnp.int32), action_counts)
