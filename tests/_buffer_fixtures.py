"""Synthetic rollouts and plain-Python references shared by the tests/test_buffer_*.py files.

``synthetic_rollout`` builds the (reset TimeStep, stacked TimeSteps) pair a real env would
emit for a given termination pattern, following the envs_jax.core contract: ``t_m`` counts
steps since the agent was last free, ``obs_macro`` is refreshed only where ``mac_done``.
"""

from __future__ import annotations

import numpy as np

from envs_jax.core import TimeStep
from jaxmac.buffer.episode import ObsCodec, SlotConfig


def derive_t_m(mac_done: np.ndarray) -> np.ndarray:
    """t_m[t] = 0 if the agent was free before step t (t = 0 or mac_done[t-1]), else t_m[t-1]+1."""
    h, n = mac_done.shape
    t_m = np.zeros((h, n), np.int32)
    for t in range(1, h):
        t_m[t] = np.where(mac_done[t - 1], 0, t_m[t - 1] + 1)
    return t_m


def synthetic_rollout(
    mac_done, reward, length, end="terminated", obs_dim=3, num_actions=4, state_dim=2, seed=0, obs_real=None
):
    """A rollout of ``H = len(reward)`` steps whose episode lasts ``length`` steps.

    ``end`` is 'terminated' or 'truncated' (flag set at step ``length - 1``) or 'none'
    (the slot ends first). Entries after the episode are random junk that must be masked.
    Returns (reset_ts, traj, info) with info holding the clean per-row arrays.
    """
    rng = np.random.default_rng(seed)
    mac_done = np.asarray(mac_done, bool)
    h, n = mac_done.shape
    t_m = derive_t_m(mac_done)
    mac = np.zeros((h, n), np.int32)
    for t in range(h):
        fresh = rng.integers(0, num_actions, n)
        mac[t] = np.where(t_m[t] == 0, fresh, mac[t - 1] if t else fresh)
    if obs_real is None:
        obs_real = rng.integers(0, 5, (h + 1, n, obs_dim)).astype(np.float32)
    obs_macro = obs_real.copy()
    for r in range(1, h + 1):
        obs_macro[r] = np.where(mac_done[r - 1][:, None], obs_real[r], obs_macro[r - 1])
    state = rng.normal(size=(h + 1, state_dim)).astype(np.float32)
    avail = rng.random((h + 1, n, num_actions)) < 0.7
    terminated = np.zeros(h, bool)
    truncated = np.zeros(h, bool)
    if end == "terminated":
        terminated[length - 1] = True
    elif end == "truncated":
        truncated[length - 1] = True
    # junk after the end: flags and rewards that a buggy writer would pick up
    terminated[length:] = rng.random(h - length) < 0.5
    truncated[length:] = rng.random(h - length) < 0.5

    reset_ts = TimeStep(
        obs_macro=obs_macro[0], obs_real=obs_real[0], mac_done=np.ones(n, bool), avail_actions=avail[0],
        mac=np.full(n, -1, np.int32), t_m=np.zeros(n, np.int32), state=state[0],
        reward=np.float32(0), terminated=np.bool_(False), truncated=np.bool_(False), t=np.int32(0),
    )
    traj = TimeStep(
        obs_macro=obs_macro[1:], obs_real=obs_real[1:], mac_done=mac_done, avail_actions=avail[1:],
        mac=mac, t_m=t_m, state=state[1:], reward=np.asarray(reward, np.float32),
        terminated=terminated, truncated=truncated, t=np.arange(1, h + 1, dtype=np.int32),
    )
    info = dict(obs_real=obs_real, obs_macro=obs_macro, state=state, avail=avail, mac=mac, t_m=t_m)
    return reset_ts, traj, info


def config_for(h, n, gamma, obs_dim=3, num_actions=4, state_dim=2, **kw):
    return SlotConfig(horizon=h, num_agents=n, obs_dim=obs_dim, num_actions=num_actions, state_dim=state_dim,
                      discount=gamma, obs=kw.pop("obs", ObsCodec("float32")), **kw)


def reference_accumulators(mac_done, reward, length, gamma):
    """MacroMARL's per-step running accumulators, written out as a plain loop.

    Returns per step t < length: joint (acc_J, k_J) and per agent (acc_i, k_i), where the
    joint accumulator resets when any agent's macro-action ended on the previous step and
    agent i's when its own did.
    """
    n = mac_done.shape[1]
    joint, agents = [], []
    acc_j, k_j = 0.0, 0
    acc, k = [0.0] * n, [0] * n
    for t in range(length):
        r = float(reward[t])
        if t == 0 or mac_done[t - 1].any():
            acc_j, k_j = r, 1
        else:
            k_j += 1
            acc_j += gamma ** (k_j - 1) * r
        for i in range(n):
            if t == 0 or mac_done[t - 1, i]:
                acc[i], k[i] = r, 1
            else:
                k[i] += 1
                acc[i] += gamma ** (k[i] - 1) * r
        joint.append((acc_j, k_j))
        agents.append([(acc[i], k[i]) for i in range(n)])
    return joint, agents
