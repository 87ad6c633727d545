"""The value-based baselines' shared parts against brute force and plain-Python references written here:
the joint conditional argmax, trace_len windows, the Mac-Cen-DDRQN loss, and tiny end-to-end training."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _buffer_fixtures import config_for, synthetic_rollout
from _value_references import brute_force_conditional_argmax, stack, step_by_step

from jaxmac.algos import targets
from jaxmac.algos.families import centralised
from jaxmac.buffer import episode, windows
from jaxmac.buffer import ring as ring_lib
from jaxmac.networks.drqn import DRQN

# --- the joint conditional argmax ---------------------------------------------------------------------


@pytest.mark.parametrize("counts", [(8, 8), (14, 14, 14), (6, 6, 6, 7)], ids=["boxpushing", "overcooked", "warehouse-E"])
def test_joint_conditional_argmax_equals_exhaustive_search(counts):
    rng = np.random.default_rng(len(counts))
    n, a_max, samples = len(counts), max(counts), 6
    q = rng.normal(size=(samples, int(np.prod(counts)))).astype(np.float32)
    avail = rng.random((samples, n, a_max)) < 0.6
    for i, c in enumerate(counts):
        avail[:, i, c:] = False  # padding beyond agent i's own actions
        avail[:, i, rng.integers(0, c)] = True  # at least one available action
    free = rng.random((samples, n)) < 0.5
    free[0] = True
    free[1] = False
    running = np.stack([rng.integers(0, c, samples) for c in counts], -1).astype(np.int32)
    got = np.asarray(jax.jit(targets.joint_conditional_argmax, static_argnums=4)(q, avail, free, running, counts))
    for s in range(samples):
        want = brute_force_conditional_argmax(q[s], avail[s], free[s], running[s], counts)
        assert tuple(got[s]) == want, (s, got[s], want)


def test_ravel_and_unravel_joint_match_numpy():
    counts = (6, 6, 6, 7)
    joint = np.array(list(itertools.product(*[range(c) for c in counts])), np.int32)
    index = np.asarray(targets.ravel_joint(jnp.asarray(joint), counts))
    np.testing.assert_array_equal(index, np.ravel_multi_index(joint.T, counts))
    np.testing.assert_array_equal(np.asarray(targets.unravel_joint(jnp.asarray(index), counts)), joint)


# --- trace_len windows ----------------------------------------------------------------------------------

H, N, GAMMA, L = 24, 2, 0.9, 5


def episode_slot(seed, length, end="truncated"):
    rng = np.random.default_rng(seed)
    mac_done = rng.random((H, N)) < 0.35
    reward = rng.normal(size=H).astype(np.float32)
    reset_ts, traj, info = synthetic_rollout(mac_done, reward, length, end=end, seed=seed)
    slot = episode.write_episode(config_for(H, N, GAMMA), reset_ts, traj)
    return slot, mac_done, reward, info


def reference_windows(mac_done, reward, length, obs_macro, trace_len):
    """MacroMARL's trace_len windows, written out: per-step records (running joint accumulator, the joint
    observation before and after the step), trace_len − 1 empty records in front, every window cache[i:i+L],
    squeezed to the records where some agent's macro-action ended."""
    records, acc, k = [], 0.0, 0
    for t in range(length):
        if t == 0 or mac_done[t - 1].any():
            acc, k = float(reward[t]), 1
        else:
            k += 1
            acc += GAMMA ** (k - 1) * float(reward[t])
        records.append(dict(step=t, reward=acc, tau=k, obs=obs_macro[t], obs_next=obs_macro[t + 1],
                            kept=bool(mac_done[t].any())))
    cache = [None] * (trace_len - 1) + records
    out = {}
    for i in range(len(cache)):
        window = cache[i:i + trace_len]
        out[i - (trace_len - 1)] = [r for r in window if r is not None and r["kept"]]
    return out


@pytest.mark.parametrize("seed,length", [(0, 24), (1, 13), (2, 3)])
def test_jert_window_equals_the_originals_squeezed_window(seed, length):
    slot, mac_done, reward, info = episode_slot(seed, length)
    reference = reference_windows(mac_done, reward, length, info["obs_macro"], L)
    assert len(reference) == length + L - 1
    firsts = jnp.asarray(sorted(reference), jnp.int32)

    @jax.jit
    def window(slot, firsts):
        stored = stack([windows.store_views(jert=True, cert=False)(slot)])
        return windows.jert_window(windows.window_views(stored, jnp.zeros_like(firsts), firsts, L))

    view, obs = window(slot, firsts)
    for b, first in enumerate(sorted(reference)):
        want = reference[first]
        count = int(view.mask[b].sum())
        assert count == len(want)
        assert not view.mask[b, count:].any()  # a prefix
        for k, rec in enumerate(want):
            assert int(view.step[b, k]) == rec["step"]
            np.testing.assert_allclose(float(view.reward[b, k]), rec["reward"], rtol=1e-5, atol=1e-6)
            assert int(view.tau[b, k]) == rec["tau"]
            np.testing.assert_array_equal(np.asarray(obs[b, k]), rec["obs"])
        if want:  # the net's input after the last entry is the observation after it (the bootstrap row)
            np.testing.assert_array_equal(np.asarray(obs[b, count]), want[-1]["obs_next"])


def test_sample_windows_is_uniform_over_all_windows_of_the_ring():
    store = jax.jit(windows.store_views(jert=True, cert=False))
    slots = [episode_slot(s, length)[0] for s, length in ((0, 5), (1, 15))]
    ring = ring_lib.init(store(episode.empty_slot(config_for(H, N, GAMMA))), 4)
    ring = ring_lib.add(ring, stack([store(s) for s in slots]))
    idx, first = jax.jit(windows.draw_windows, static_argnums=(2, 3))(ring, jax.random.key(0), 40_000, L)
    lengths = np.asarray(ring.slots.length)[np.asarray(idx)]
    first = np.asarray(first)
    short = lengths == 5
    # episode of T steps has T + L - 1 windows: 9 and 19 of 28
    np.testing.assert_allclose(short.mean(), 9 / 28, atol=0.01)
    for t, sel in ((5, short), (15, ~short)):
        values, counts = np.unique(first[sel], return_counts=True)
        np.testing.assert_array_equal(values, np.arange(-(L - 1), t))
        np.testing.assert_allclose(counts / sel.sum(), 1 / (t + L - 1), atol=0.012)


# --- the Mac-Cen-DDRQN loss against a step-by-step reference ----------------------------------------------


def test_maccen_loss_equals_a_step_by_step_reference():
    counts = (4, 4)  # synthetic_rollout's action count
    net = DRQN(mlp=(6, 6), hidden=5, out=16)
    params = net.init(jax.random.key(0), jnp.zeros((1, N * 3)), jnp.zeros((1,), bool), jnp.zeros(5))
    target = net.init(jax.random.key(1), jnp.zeros((1, N * 3)), jnp.zeros((1,), bool), jnp.zeros(5))
    cases = [episode_slot(s, length, end) for s, length, end in ((3, 24, "none"), (4, 11, "terminated"),
                                                                 (5, 16, "truncated"))]
    firsts = [-2, 0, 7]
    @jax.jit
    def loss_fn(slots, firsts):
        stored = jax.vmap(windows.store_views(jert=True, cert=False))(slots)
        batch = windows.window_views(stored, jnp.arange(3), firsts, L)
        return centralised.conditional_double_q_loss(net, params, target, batch, counts)[:2]

    loss, metrics = loss_fn(stack([c[0] for c in cases]), jnp.asarray(firsts, jnp.int32))
    step = jax.jit(lambda p, x, h: net.apply(p, x.reshape(1, -1), jnp.zeros((1,), bool), h))
    q_seq = lambda p, xs: step_by_step(step, p, xs, jnp.zeros(5))  # noqa: E731  from a zero state

    squared = []
    for (slot, mac_done, reward, info), first in zip(cases, firsts):
        length = int(slot.length)
        terminated = np.asarray(slot.terminated)
        kept = [t for t in range(max(first, 0), min(first + L, length)) if mac_done[t].any()]
        if not kept:
            continue
        obs = info["obs_macro"]
        xs = [obs[t - int(np.min(info["t_m"][t]))] for t in kept] + [obs[kept[-1] + 1]]
        q_online, q_target = q_seq(params, xs), q_seq(target, xs)
        for k, t in enumerate(kept):
            start = t - int(np.min(info["t_m"][t]))
            tau = t - start + 1
            ret = sum(GAMMA ** j * float(reward[start + j]) for j in range(tau))
            taken = q_online[k][np.ravel_multi_index(tuple(info["mac"][t]), counts)]
            free = mac_done[t]
            best = brute_force_conditional_argmax(q_online[k + 1], info["avail"][t + 1], free, info["mac"][t], counts)
            boot = 0.0 if terminated[t] else GAMMA ** tau * q_target[k + 1][np.ravel_multi_index(best, counts)]
            squared.append((taken - (ret + boot)) ** 2)
    np.testing.assert_allclose(float(loss), np.mean(squared), rtol=2e-5)
    assert round(float(metrics["jert_entries"]) * 3) == len(squared)
