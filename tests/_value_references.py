"""Plain-Python references shared by the value-baseline tests (tests/test_value_baselines*.py, tests/test_avf.py)."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np


def stack(items):
    """Stack a list of pytrees along a new leading axis."""
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *items)


def brute_force_conditional_argmax(q, avail, free, running, counts):
    """Exhaustive search over every joint action with busy agents pinned and unavailable actions excluded."""
    best, best_value = None, -np.inf
    for joint in itertools.product(*[range(c) for c in counts]):
        if any(not free[i] and joint[i] != running[i] for i in range(len(counts))):
            continue
        if any(free[i] and not avail[i, joint[i]] for i in range(len(counts))):
            continue
        index = np.ravel_multi_index(joint, counts)
        if q[index] > best_value:
            best, best_value = joint, q[index]
    return best


def available_argmax(q, avail):
    """The greedy available action of one agent's Q row."""
    return int(np.argmax(np.where(avail, q, -np.inf)))


def step_by_step(step, params, xs, carry):
    """Q of a recurrent net run one decision at a time: ``step(params, x, carry) -> (q [1, ...], carry)``."""
    out = []
    for x in xs:
        q, carry = step(params, jnp.asarray(x, jnp.float32), carry)
        out.append(np.asarray(q[0]))
    return out
