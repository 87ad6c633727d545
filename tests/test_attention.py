"""ATPG's blocked causal attention against a slow plain-NumPy reference (values) and against the autodiff of the
dense masked softmax it replaces (gradients), with packed segments and windows."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmac.networks.atpg import causal_attention, query_blocks


def reference_attention(q, k, v, segment, window):
    """Row by row in plain NumPy: each row's softmax over the earlier rows of its own segment (and window)."""
    out = np.zeros_like(q)
    lead = q.shape[:-2]
    for idx in itertools.product(*map(range, lead)):
        seg = segment[idx[: segment.ndim - 1]]
        for t in range(q.shape[-2]):
            keys = [s for s in range(t + 1) if seg[s] == seg[t] and (window == 0 or t - s < window)]
            logits = np.array([q[idx + (t,)] @ k[idx + (s,)] for s in keys]) / np.sqrt(q.shape[-1])
            p = np.exp(logits - logits.max())
            out[idx + (t,)] = (p / p.sum()) @ v[idx][keys]
    return out


def dense_attention(q, k, v, segment, window):
    """The dense formulation (every pair of rows, masked): what autodiff differentiates as the reference."""
    t = np.arange(q.shape[-2])
    lag = t[:, None] - t[None, :]
    allowed = (lag >= 0) & ((window == 0) | (lag < window))
    allowed = allowed & (segment[..., :, None] == segment[..., None, :])
    logits = q @ jnp.swapaxes(k, -1, -2) / np.sqrt(q.shape[-1])
    return jax.nn.softmax(jnp.where(allowed, logits, -jnp.inf), axis=-1) @ v


def inputs(seed, lead=(2,), length=11, dim=4):
    rng = np.random.default_rng(seed)
    q, k, v = (rng.normal(size=lead + (length, dim)).astype(np.float32) for _ in range(3))
    resets = rng.random(lead + (length,)) < 0.25
    resets[..., 0] = True
    return q, k, v, np.cumsum(resets, axis=-1).astype(np.int32)


@pytest.mark.parametrize("seed,window", [(0, 0), (1, 0), (2, 3), (3, 1)])
def test_values_equal_the_row_by_row_reference(seed, window):
    q, k, v, segment = inputs(seed)
    out = causal_attention(q, k, v, segment, jnp.int32(window))
    np.testing.assert_allclose(np.asarray(out), reference_attention(q, k, v, segment, window), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("seed,window", [(4, 0), (5, 2)])
def test_gradients_equal_those_of_the_dense_masked_softmax(seed, window):
    q, k, v, segment = inputs(seed, lead=(2, 3), length=13)
    cotangent = np.random.default_rng(seed + 100).normal(size=q.shape).astype(np.float32)

    def loss(fn):
        return lambda q, k, v: jnp.sum(fn(q, k, v, segment, jnp.int32(window)) * cotangent)

    got = jax.jit(jax.grad(loss(causal_attention), argnums=(0, 1, 2)))(q, k, v)
    want = jax.grad(loss(dense_attention), argnums=(0, 1, 2))(q, k, v)
    for g, w in zip(got, want):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-4, atol=1e-5)


def test_query_blocks_cover_every_row_once():
    for length in (1, 2, 11, 201):
        blocks = query_blocks(length)
        assert [a for a, _ in blocks] == [0] + [b for _, b in blocks[:-1]] and blocks[-1][1] == length
    assert query_blocks(10) == [(0, 5), (5, 10)] and query_blocks(9, 3) == [(0, 3), (3, 6), (6, 9)]
