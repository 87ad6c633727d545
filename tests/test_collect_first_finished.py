"""The MacroMARL actor-critic runners' episode selection (collection='first_finished') against a plain-Python
emulation of their loop, and the episodes cut out of the env streams."""

from __future__ import annotations

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from jaxmac.collect import episode_returns, random_policy, run_episodes_first_finished, select_first_finished


def runner_reference(done: np.ndarray, num_episodes: int) -> list[tuple[int, int]]:
    """The original runner, written out: envs step in lock-step; after each step the envs are visited in index
    order, a finished episode is appended to a deque of length ``num_episodes`` and its env restarts; the loop
    ends after the step at which the count of finished episodes reaches ``num_episodes``. Returns the
    ``(env, start step)`` of the episodes left in the deque, oldest first."""
    num_envs, length = done.shape
    kept, count, start = deque(maxlen=num_episodes), 0, [0] * num_envs
    for t in range(length):
        if count >= num_episodes:
            break
        for i in range(num_envs):
            if done[i, t]:
                kept.append((i, start[i]))
                count += 1
                start[i] = t + 1
    return list(kept)


@pytest.mark.parametrize("num_envs,num_episodes,p", [(4, 4, 0.2), (5, 3, 0.3), (2, 6, 0.15), (8, 8, 0.6)])
def test_selection_matches_the_original_runner(num_envs, num_episodes, p):
    rng = np.random.default_rng(num_envs * 10 + num_episodes)
    select = jax.jit(select_first_finished, static_argnums=1)
    for _ in range(20):
        length = 12 * -(-num_episodes // num_envs)
        done = rng.random((num_envs, length)) < p
        done[:, 11::12] = True  # an env finishes an episode at least every 12 steps (the horizon)
        env_index, start = select(jnp.asarray(done), num_episodes)
        got = list(zip(np.asarray(env_index).tolist(), np.asarray(start).tolist()))
        assert got == runner_reference(done, num_episodes)


def test_first_finished_episodes_are_cut_whole_from_the_streams():
    env = envs_jax.make("boxpushing-6x6")
    init_carry, act = random_policy()
    collect = jax.jit(lambda k: run_episodes_first_finished(env, act, init_carry, None, k, 1.0, 16, 16))
    reset_ts, traj = collect(jax.random.key(3))
    assert np.all(np.asarray(reset_ts.t) == 0) and np.all(np.asarray(reset_ts.mac_done))
    done = np.asarray(traj.terminated | traj.truncated)
    stats = episode_returns(traj, env.spec.discount)
    lengths = np.asarray(stats["length"])
    for e in range(16):  # each cut episode ends exactly once, at its last counted step, and starts at t = 1
        first_done = int(np.argmax(done[e]))
        assert done[e].any() and first_done == lengths[e] - 1
        assert int(traj.t[e, 0]) == 1
