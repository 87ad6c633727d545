"""Helpers shared by the learner tests (actor-critics, ToMacVF, length buckets): synthetic episode slots, random
parameters of a network's structure, and a frequency check for sampled actions."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from _buffer_fixtures import config_for, synthetic_rollout

from jaxmac.buffer import episode

H, GAMMA = 20, 0.9

_write = jax.jit(episode.write_episode, static_argnums=0)


def episode_slot(seed, length, end, n=2, p=0.35, last_done=None, h=H, obs_dim=3, num_actions=4, state_dim=2,
                 gamma=GAMMA):
    """A synthetic episode slot and its raw per-step arrays; ``last_done`` forces the termination pattern of the
    episode's last step."""
    rng = np.random.default_rng(seed)
    mac_done = rng.random((h, n)) < p
    if last_done is not None:
        mac_done[length - 1] = last_done
    reward = rng.normal(size=h).astype(np.float32)
    reset_ts, traj, info = synthetic_rollout(mac_done, reward, length, end=end, obs_dim=obs_dim,
                                             num_actions=num_actions, state_dim=state_dim, seed=seed)
    cfg = config_for(h, n, gamma, obs_dim=obs_dim, num_actions=num_actions, state_dim=state_dim)
    info.update(mac_done=mac_done, reward=reward, length=length, end=end, n=n)
    return _write(cfg, reset_ts, traj), info



def random_params(init, seed, scale=0.4):
    """Parameters of ``init``'s structure drawn from N(0, scale²) (no initialiser compiled: only shapes traced)."""
    shapes = jax.eval_shape(init, jax.random.key(0))
    leaves, tree = jax.tree_util.tree_flatten(shapes)
    rng = np.random.default_rng(seed)
    return jax.tree_util.tree_unflatten(
        tree, [jnp.asarray(scale * rng.normal(size=x.shape), x.dtype) for x in leaves])



def assert_frequencies(samples, probs, label):
    """Empirical frequencies of ``samples`` (ints) within 5 standard errors of ``probs`` in every cell, and no
    sample outside the support."""
    count = len(samples)
    freq = np.bincount(samples, minlength=len(probs)) / count
    assert (freq[probs == 0] == 0).all(), label
    tol = 5 * np.sqrt(probs * (1 - probs) / count) + 2.0 / count
    bad = np.nonzero(np.abs(freq - probs) > tol)[0]
    assert not len(bad), (label, bad, freq[bad], probs[bad])

