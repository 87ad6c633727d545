"""Linear schedules over training episodes (exploration ε, the originals' hysteresis β, ToMacVF's
overestimate weight): one formula, so every learner ramps its knobs the same way."""

from __future__ import annotations

import chex
import jax.numpy as jnp


def linear_schedule(episodes: chex.Array, begin: int, duration: int, start: float, end: float) -> chex.Array:
    """``start`` until ``begin`` episodes, then linear to ``end`` over ``duration`` episodes, ``end`` after.

    Args:
      episodes: i32[] (or any shape) training episodes so far.
      begin, duration: python ints, episodes; a duration of 0 jumps to ``end`` at ``begin``.
      start, end: python floats.
    Returns:
      f32[] (shape of ``episodes``) the scheduled value.
    """
    frac = jnp.clip((episodes - begin) / max(duration, 1), 0.0, 1.0)
    return start + frac * (end - start)
