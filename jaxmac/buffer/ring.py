"""A FIFO ring of ``N`` episode slots (DECISIONS D0, D7), in the style of flashbax.

Pure functions over a ``RingState`` pytree with fixed shapes; the fill level is a traced
integer, so ``add``/``sample`` jit once and can be vmapped over seeds. Donate the state::

    ring = ring_lib.init(config, capacity)                  # or init(example_slot, capacity)
    add = jax.jit(ring_lib.add, donate_argnums=0)
    ring = add(ring, slots)                                 # one slot or a batch [E, ...]
    batch, idx = ring_lib.sample(ring, key, batch_size)     # EpisodeSlot with leaves [B, ...]

Slots are written in order ``0, 1, …, N-1, 0, …`` (the oldest is overwritten first), so the
filled slots are always ``[0, count)``. Sampling is uniform over them, with replacement;
call it only when ``can_sample`` (else the indices point at empty slots).
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.validation import is_integer
from jaxmac.buffer.episode import EpisodeSlot, SlotConfig, empty_slot


@struct.dataclass
class RingState:
    """``N`` slots plus bookkeeping."""

    slots: EpisodeSlot  # leaves [N, ...]
    episode_id: chex.Array  # i32[N] insertion number of the episode in each slot (-1: empty)
    write_pos: chex.Array  # i32[] next slot to write (= the oldest once full)
    count: chex.Array  # i32[] filled slots, ≤ N
    added: chex.Array  # i32[] episodes added so far

    @property
    def capacity(self) -> int:
        return self.episode_id.shape[-1]


def init(example: EpisodeSlot | SlotConfig, capacity: int) -> RingState:
    """An empty ring of ``capacity`` slots shaped like ``example`` (a slot or its config)."""
    if not is_integer(capacity) or capacity < 1:
        raise ValueError(f"ring.init: capacity={capacity!r} must be a positive integer")
    if isinstance(example, SlotConfig):
        example = empty_slot(example)
    if isinstance(example, EpisodeSlot):
        if example.reward.ndim != 1:
            raise ValueError("ring.init: example must be a SlotConfig or one unbatched EpisodeSlot")
        blank = empty_slot(example.config)
    elif jax.tree_util.tree_leaves(example):  # per-episode data derived from slots (e.g. stored views)
        blank = jax.tree_util.tree_map(jnp.zeros_like, example)
    else:
        raise ValueError("ring.init: example must be a SlotConfig, an unbatched EpisodeSlot or a pytree of arrays")
    slots = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (capacity,) + x.shape), blank)
    return RingState(
        slots=slots,
        episode_id=jnp.full((capacity,), -1, jnp.int32),
        write_pos=jnp.zeros((), jnp.int32),
        count=jnp.zeros((), jnp.int32),
        added=jnp.zeros((), jnp.int32),
    )


def add(ring: RingState, slot: EpisodeSlot) -> RingState:
    """Insert one slot (leaves ``[H, ...]``) or a batch of ``E ≤ N`` slots (``[E, H, ...]``),
    overwriting the oldest. The batch keeps its order (entry 0 is the oldest of the batch).
    A ring made from another pytree takes items of that structure, one or a batch ``[E, ...]``."""
    if isinstance(ring.slots, EpisodeSlot):
        if not isinstance(slot, EpisodeSlot):
            raise ValueError(f"ring.add: expected an EpisodeSlot, got {type(slot).__name__}")
        if slot.config != ring.slots.config:
            raise ValueError(f"ring.add: slot config {slot.config} differs from the ring's {ring.slots.config}")
        if slot.reward.ndim == 1:
            slot = jax.tree_util.tree_map(lambda x: x[None], slot)
        elif slot.reward.ndim != 2:
            raise ValueError(
                f"ring.add: slot leaves must be [H, ...] or [E, H, ...]; reward has shape {slot.reward.shape}"
            )
        e = slot.reward.shape[0]
    else:
        if jax.tree_util.tree_structure(slot) != jax.tree_util.tree_structure(ring.slots):
            raise ValueError(f"ring.add: item structure {jax.tree_util.tree_structure(slot)} differs from the ring's")
        first, stored = jax.tree_util.tree_leaves(slot)[0], jax.tree_util.tree_leaves(ring.slots)[0]
        if first.ndim == stored.ndim - 1:
            slot = jax.tree_util.tree_map(lambda x: x[None], slot)
        e = jax.tree_util.tree_leaves(slot)[0].shape[0]
    n = ring.capacity
    if e > n:
        raise ValueError(f"ring.add: batch of E={e} slots exceeds the capacity N={n}; add at most N at once")
    pos = (ring.write_pos + jnp.arange(e, dtype=jnp.int32)) % n
    slots = jax.tree_util.tree_map(lambda buf, new: buf.at[pos].set(new.astype(buf.dtype)), ring.slots, slot)
    return RingState(
        slots=slots,
        episode_id=ring.episode_id.at[pos].set(ring.added + jnp.arange(e, dtype=jnp.int32)),
        write_pos=(ring.write_pos + e) % n,
        count=jnp.minimum(ring.count + e, n),
        added=ring.added + e,
    )


def can_sample(ring: RingState, batch_size: int) -> chex.Array:
    """bool[]: at least ``batch_size`` episodes are stored."""
    return ring.count >= batch_size


def sample(ring: RingState, key: chex.PRNGKey, batch_size: int) -> tuple[EpisodeSlot, chex.Array]:
    """``batch_size`` slots drawn uniformly with replacement from the filled ones.

    Returns:
      batch: EpisodeSlot with leaves ``[B, ...]`` (feed it to ``jaxmac.buffer.views``).
      idx: i32[B] the ring positions drawn.
    """
    if not is_integer(batch_size) or batch_size < 1:
        raise ValueError(f"ring.sample: batch_size={batch_size!r} must be a positive integer")
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(ring.count, 1), dtype=jnp.int32)
    return jax.tree_util.tree_map(lambda x: x[idx], ring.slots), idx
