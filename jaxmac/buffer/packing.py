"""Packing: several short episodes back to back in one row of ``T`` positions, so that a network pass over a
batch costs its episodes' real lengths instead of ``B · T``.

An episode of length ``L`` occupies its ``L + 1`` rows (the bootstrap row included) from an ``offset`` in one packed
row. The plan is first-fit decreasing over the episodes sorted by length (``B`` packed rows always suffice), so it does
not depend on how many packed rows are then materialised: any ``P ≥ plan.rows_used`` holds it. Positions no episode
occupies are padding and each starts its own episode (``reset``), so nothing real reads them.

    plan = pack_plan(lengths, width=T)                    # lengths i32[B]
    layout = packed_layout(plan, P, T)                    # where every packed position reads from (once per P)
    packed = pack(x, layout)                              # x [B, T, ...] -> [P, T, ...]
    x_back = unpack(packed, plan)                         # [P, T, ...] -> [B, T, ...] (rows > L are zeros)
    reset = layout.reset                                  # bool[P, T]: the first row of every episode, and padding

Sequence models that reset their state at ``reset`` (the agents' GRUs) and attend only within the rows since the last
reset (ATPG) compute on a packed row exactly what they compute on each episode's own slot.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class PackPlan:
    row: chex.Array  # i32[B] the packed row holding episode b
    offset: chex.Array  # i32[B] the position of its row 0 there
    need: chex.Array  # i32[B] its rows: length + 1
    rows_used: chex.Array  # i32[] packed rows the plan fills (≤ B)


def pack_plan(lengths: chex.Array, width: int) -> PackPlan:
    """First-fit decreasing of episodes of ``lengths`` i32[B] (each needing ``length + 1 ≤ width`` positions) into rows
    of ``width`` positions."""
    need = jnp.asarray(lengths, jnp.int32) + 1
    b = need.shape[0]
    order = jnp.argsort(-need, stable=True)

    def place(fill, episode):
        fits = fill + need[episode] <= width
        row = jnp.argmax(fits).astype(jnp.int32)  # the first row with room (an empty one always has)
        return fill.at[row].add(need[episode]), (row, fill[row])

    _, (rows, offsets) = jax.lax.scan(place, jnp.zeros(b, jnp.int32), order)
    row = jnp.zeros(b, jnp.int32).at[order].set(rows)
    offset = jnp.zeros(b, jnp.int32).at[order].set(offsets)
    return PackPlan(row=row, offset=offset, need=need, rows_used=jnp.max(row) + 1)


@struct.dataclass
class PackedLayout:
    """For every packed position ``[P, T]``: the episode it holds, that episode's row there, and whether it is real."""

    episode: chex.Array  # i32[P, T]
    step: chex.Array  # i32[P, T]
    real: chex.Array  # bool[P, T]

    @property
    def reset(self) -> chex.Array:
        """bool[P, T]: positions that start an episode (its row 0) and padding positions (each its own)."""
        return (self.step == 0) | ~self.real


def packed_layout(plan: PackPlan, num_rows: int, width: int) -> PackedLayout:
    """The ``num_rows ≥ plan.rows_used`` packed rows of ``width`` positions that ``plan`` fills."""
    b = plan.row.shape[0]
    t = jnp.arange(width, dtype=jnp.int32)
    rows = jnp.broadcast_to(plan.row[:, None], (b, width))
    cols = plan.offset[:, None] + t[None, :]
    keep = t[None, :] < plan.need[:, None]
    rows = jnp.where(keep, rows, num_rows)  # out of range: dropped by the scatter
    episode = jnp.full((num_rows, width), b, jnp.int32)
    episode = episode.at[rows, cols].set(jnp.broadcast_to(jnp.arange(b, dtype=jnp.int32)[:, None], (b, width)),
                                         mode="drop")
    real = episode < b
    episode = jnp.minimum(episode, b - 1)
    step = jnp.where(real, jnp.arange(width, dtype=jnp.int32)[None, :] - plan.offset[episode], 0)
    return PackedLayout(episode=episode, step=step, real=real)


def pack(x: chex.Array, layout: PackedLayout) -> chex.Array:
    """``x`` [B, T, ...] -> [P, T, ...]; padding positions hold zeros."""
    out = x[layout.episode, layout.step]
    real = layout.real
    return jnp.where(real.reshape(real.shape + (1,) * (x.ndim - 2)), out, jnp.zeros((), x.dtype))


def unpack(y: chex.Array, plan: PackPlan) -> chex.Array:
    """``y`` [P, T, ...] -> [B, T, ...]: each episode's rows back in its own slot; rows past ``need`` are zeros."""
    width = y.shape[1]
    t = jnp.arange(width, dtype=jnp.int32)
    cols = jnp.minimum(plan.offset[:, None] + t[None, :], width - 1)
    out = y[plan.row[:, None], cols]
    keep = t[None, :] < plan.need[:, None]
    return jnp.where(keep.reshape(keep.shape + (1,) * (y.ndim - 2)), out, jnp.zeros((), y.dtype))
