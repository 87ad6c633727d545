"""Length buckets: run a computation on the shortest static prefix that holds every real entry.

Fixed shapes make an update pay for the horizon ``H`` whatever the episodes' real lengths (a Box Pushing
batch of 32 episodes fills at most ~20 of the 100 Mac-CERT entries). Masks are prefixes, so cutting every
sequence to a static length ``L`` ≥ the longest real one changes nothing but the cost. ``run_bucketed``
compiles the computation once per size and picks the smallest size that fits at run time (``lax.switch``).

Under ``jax.vmap`` a switch on a batched index would run every branch; the trainer therefore vmaps its seeds
with ``axis_name=SEED_AXIS`` (``Trainer.seeds_chunk``) and the index is the maximum over seeds, which is not
batched: all seeds of a program take the branch the longest of them needs.
"""

from __future__ import annotations

import functools
from typing import Callable

import chex
import jax
import jax.numpy as jnp

from envs_jax.validation import is_integer
from jaxmac.seeds import across_seeds


def bucket_sizes(full: int, count: int) -> tuple[int, ...]:
    """``count`` static lengths, halving from ``full``: ``bucket_sizes(100, 3) == (25, 50, 100)``; 1 = ``(full,)``."""
    if not is_integer(count) or count < 1:
        raise ValueError(f"length_buckets={count!r} must be a positive integer (1 = always the full length)")
    sizes = {max(1, -(-full // 2**k)) for k in range(count)}
    return tuple(sorted(sizes))


def packed_row_sizes(batch: int, count: int) -> tuple[int, ...]:
    """The packed-row counts a packed update may run on: ``bucket_sizes(batch, count)`` and, between two of them,
    one and a half times the smaller (``packed_row_sizes(128, 4) == (16, 24, 32, 48, 64, 96, 128)``). Halving alone
    wastes up to half of the rows (33 needed, 64 run); the steps in between cut that to a third, for one more
    compiled update per size."""
    halving = bucket_sizes(batch, count)
    between = {s + s // 2 for s in halving[:-1] if s >= 2 and s + s // 2 < batch}
    return tuple(sorted(set(halving) | between))


def run_bucketed(fn: Callable, sizes: tuple[int, ...], need: chex.Array, *args):
    """``fn(size, *args)`` for the smallest ``size`` in ``sizes`` that is ≥ ``need`` (the largest over seeds).

    ``sizes`` ascending, its last the full length (``need`` never exceeds it). With one size this is a plain call.
    """
    if len(sizes) == 1:
        return fn(sizes[0], *args)
    need = across_seeds(jax.lax.pmax, jnp.asarray(need, jnp.int32))
    index = jnp.minimum(jnp.searchsorted(jnp.asarray(sizes, jnp.int32), need), len(sizes) - 1)
    return jax.lax.switch(index, [functools.partial(fn, s) for s in sizes], *args)


def length_bucketed(update: Callable, buckets: int, full: Callable, need: Callable) -> Callable:
    """A learner's ``update(params, target_params, opt_state, batch, key, progress)`` run on ``batch.prefix(size)``,
    the shortest of ``bucket_sizes(full(batch), buckets)`` that holds ``need(batch)`` (i32[], the longest real
    sequence; the maximum over seeds); ``buckets = 1`` returns ``update`` itself (the full-length reference path).
    ``full(batch)`` is the static full length."""
    bucket_sizes(1, buckets)  # validate now, not at tracing
    if buckets == 1:
        return update

    def bucketed(params, target_params, opt_state, batch, key, progress):
        return run_bucketed(lambda size: update(params, target_params, opt_state, batch.prefix(size), key, progress),
                            bucket_sizes(full(batch), buckets), need(batch))

    return bucketed
