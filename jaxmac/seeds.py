"""The seed axis of a training program: seeds are ``vmap``-ped with ``axis_name=SEED_AXIS``, and what every seed must
decide alike (evaluate this round? train yet? which length bucket?) is reduced over that axis. A bottom-layer module.
"""

from __future__ import annotations

from collections.abc import Callable

import chex
import jax
import jax.numpy as jnp

SEED_AXIS = "seeds"  # the name of the vmapped seed axis of a training program


def across_seeds(reduce: Callable, x: chex.Array) -> chex.Array:
    """``reduce`` (``jax.lax.pmax``, ``pmin``, ...) of ``x`` over the seeds vmapped with ``SEED_AXIS``; ``x``
    itself outside such a vmap (one seed, or seeds vmapped without the name: then the result stays batched)."""
    try:
        return reduce(x, SEED_AXIS)
    except NameError:  # unbound axis name: not under the seeds' vmap
        return x


def any_seed(flag: chex.Array) -> chex.Array:
    """bool[]: ``flag`` of any seed (``across_seeds`` for a boolean); for decisions every seed shares."""
    return across_seeds(jax.lax.pmax, jnp.asarray(flag, jnp.int32)) > 0
