"""docs/baselines.md §2.2: the 2-agent, 6-step worked example, every view written out.

Steps are 0-indexed here (the document's step k is our step k-1). Agent 0 runs m0¹ on steps
0-2 and m1¹ on 3-5; agent 1 runs m0² on 0-1, m1² on 2-4, m2² on 5; the episode terminates
at step 5. γ = 0.5 and rewards 1, 2, 4, …, 32 keep every sum exact in float32.
Observation rows are labelled: agent i's real observation at row r is [i+1, r, 0], so a
frozen macro-observation names the row it was taken at (o^i_k of the document = [i+1, k, 0]).
"""

import jax
import numpy as np
import pytest
from _buffer_fixtures import config_for, synthetic_rollout

from jaxmac.buffer import episode, views

G = 0.5
R = np.array([1, 2, 4, 8, 16, 32], np.float32)
DONE = np.array([[0, 0], [0, 1], [1, 0], [0, 0], [0, 1], [1, 1]], bool)
MAC = np.array([[0, 2], [0, 2], [0, 3], [1, 3], [1, 3], [1, 1]], np.int32)  # m0¹=0 m1¹=1; m0²=2 m1²=3 m2²=1


def o(i, k):
    return [i + 1, k, 0]


def build(end="terminated"):
    obs_real = np.array([[o(0, r), o(1, r)] for r in range(7)], np.float32)
    reset_ts, traj, _ = synthetic_rollout(DONE, R, 6, end=end, obs_real=obs_real)
    traj = traj.replace(mac=MAC)
    return episode.write_episode(config_for(6, 2, G), reset_ts, traj)


@pytest.fixture(scope="module")
def slot():
    return build()


def test_t_m_sequences(slot):
    np.testing.assert_array_equal(slot.t_m[:, 0], [0, 1, 2, 0, 1, 2])
    np.testing.assert_array_equal(slot.t_m[:, 1], [0, 1, 0, 1, 2, 0])
    np.testing.assert_array_equal(views.micro_view(slot).t_m, slot.t_m)
    assert int(slot.length) == 6 and bool(slot.valid.all())


def test_mac_cert(slot):
    v = views.cert_view(slot)
    # agent 0: steps 2 and 5
    np.testing.assert_array_equal(v.mask[0, :3], [1, 1, 0])
    np.testing.assert_array_equal(v.step[0, :2], [2, 5])
    np.testing.assert_array_equal(v.mac[0, :2], [0, 1])
    np.testing.assert_array_equal(v.reward[0, :2], [1 + G * 2 + G**2 * 4, 8 + G * 16 + G**2 * 32])
    np.testing.assert_array_equal(v.tau[0, :2], [3, 3])
    np.testing.assert_array_equal(v.discount[0, :2], [G**3, 0.0])
    np.testing.assert_array_equal(v.obs[0, :2], [o(0, 0), o(0, 3)])
    np.testing.assert_array_equal(v.obs_next[0, :2], [o(0, 3), o(0, 6)])
    # agent 1: steps 1, 4, 5
    np.testing.assert_array_equal(v.mask[1, :4], [1, 1, 1, 0])
    np.testing.assert_array_equal(v.step[1, :3], [1, 4, 5])
    np.testing.assert_array_equal(v.mac[1, :3], [2, 3, 1])
    np.testing.assert_array_equal(v.reward[1, :3], [1 + G * 2, 4 + G * 8 + G**2 * 16, 32])
    np.testing.assert_array_equal(v.tau[1, :3], [2, 3, 1])
    np.testing.assert_array_equal(v.discount[1, :3], [G**2, G**3, 0.0])
    np.testing.assert_array_equal(v.obs[1, :3], [o(1, 0), o(1, 2), o(1, 5)])
    np.testing.assert_array_equal(v.obs_next[1, :3], [o(1, 2), o(1, 5), o(1, 6)])


def test_mac_jert(slot):
    v = views.jert_view(slot)
    np.testing.assert_array_equal(v.mask, [1, 1, 1, 1, 0, 0])
    np.testing.assert_array_equal(v.step[:4], [1, 2, 4, 5])
    np.testing.assert_array_equal(v.start[:4], [0, 2, 3, 5])
    np.testing.assert_array_equal(v.mac[:4], [[0, 2], [0, 3], [1, 3], [1, 1]])
    np.testing.assert_array_equal(v.reward[:4], [1 + G * 2, 4, 8 + G * 16, 32])
    np.testing.assert_array_equal(v.tau[:4], [2, 1, 2, 1])
    np.testing.assert_array_equal(v.discount[:4], [G**2, G, G**2, 0.0])
    np.testing.assert_array_equal(v.terminal[:4], [0, 0, 0, 1])
    # joint o: stale observations of the busy agent (o2_2 at step 5 although steps 3-5 happened)
    np.testing.assert_array_equal(v.obs[:4], [[o(0, 0), o(1, 0)], [o(0, 0), o(1, 2)],
                                              [o(0, 3), o(1, 2)], [o(0, 3), o(1, 5)]])
    np.testing.assert_array_equal(v.obs_next[:4], [[o(0, 0), o(1, 2)], [o(0, 3), o(1, 2)],
                                                   [o(0, 3), o(1, 5)], [o(0, 6), o(1, 6)]])
    # the `valid` pattern of the original = agents free at the next decision point
    np.testing.assert_array_equal(v.free_next[:4], [[0, 1], [1, 0], [0, 1], [1, 1]])
    # conditional target: busy agents pinned to their running macro-action
    np.testing.assert_array_equal(v.next_mac[:3][~np.asarray(v.free_next[:3])], [0, 3, 1])
    np.testing.assert_array_equal(v.t[:4], [0, 2, 3, 5])
    np.testing.assert_array_equal(v.t_m[:4], [[0, 0], [2, 0], [0, 1], [2, 0]])


def test_mac_sjert_segments_and_macro_transitions(slot):
    s = slot.segments
    np.testing.assert_array_equal(s.count, [2, 3])
    np.testing.assert_array_equal(s.valid[:, :4], [[1, 1, 0, 0], [1, 1, 1, 0]])
    np.testing.assert_array_equal(s.start[0, :2], [0, 3])
    np.testing.assert_array_equal(s.end[0, :2], [2, 5])
    np.testing.assert_array_equal(s.start[1, :3], [0, 2, 5])
    np.testing.assert_array_equal(s.end[1, :3], [1, 4, 5])
    np.testing.assert_array_equal(s.duration[1, :3], [2, 3, 1])
    np.testing.assert_array_equal(s.mac[0, :2], [0, 1])
    np.testing.assert_array_equal(s.mac[1, :3], [2, 3, 1])
    np.testing.assert_array_equal(s.R_m[0, :2], [1 + G * 2 + G**2 * 4, 8 + G * 16 + G**2 * 32])
    np.testing.assert_array_equal(s.R_m[1, :3], [1 + G * 2, 4 + G * 8 + G**2 * 16, 32])

    m = views.macro_view(slot)
    assert int(m.mask.sum()) == 5
    # agent 0's m0¹: <s_1, ô_1, m_1, r1+γr2+γ²r3, s_4, ô_4> bootstrapped with γ³ (rows 0 and 3)
    assert (int(m.start[0, 0]), int(m.boot_row[0, 0]), float(m.discount[0, 0])) == (0, 3, G**3)
    np.testing.assert_array_equal(m.boot_row[1, :3], [2, 5, 6])
    np.testing.assert_array_equal(m.discount[1, :3], [G**2, G**3, 0.0])
    # Q_tot at a segment's first step: the segment's agent at progress 0, the other at its own
    np.testing.assert_array_equal(m.start_t_m[0, 1], [0, 1])  # agent 0's m1¹ starts at step 3
    np.testing.assert_array_equal(m.start_t_m[1, 1], [2, 0])  # agent 1's m1² starts at step 2
    np.testing.assert_array_equal(m.start_mac[1, 1], [0, 3])
    # at agent 1's m0² bootstrap (row 2) agent 0 is busy: pinned to m0¹ at progress 2
    np.testing.assert_array_equal(m.boot_free[1, 0], [0, 1])
    assert int(m.boot_mac[1, 0, 0]) == 0 and int(m.boot_t_m[1, 0, 0]) == 2


def test_mac_sjert_micro_transitions(slot):
    v = views.micro_view(slot)
    np.testing.assert_array_equal(v.mask, np.ones(6, bool))
    np.testing.assert_array_equal(v.ret, R)
    np.testing.assert_array_equal(v.boot_row, [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(v.boot_discount, [G] * 5 + [0.0])
    np.testing.assert_array_equal(v.free_next, DONE)
    # the real per-step observations are the rows themselves, every agent every step
    np.testing.assert_array_equal(slot.decode_obs("real")[:, 1], [o(1, r) for r in range(7)])
    v3 = views.micro_view(slot, n_step=3)
    np.testing.assert_array_equal(v3.ret, [1 + 1 + 1, 2 + 2 + 2, 4 + 4 + 4, 8 + 8 + 8, 16 + 16, 32])
    np.testing.assert_array_equal(v3.n_steps, [3, 3, 3, 3, 2, 1])
    np.testing.assert_array_equal(v3.boot_row, [3, 4, 5, 6, 6, 6])
    np.testing.assert_array_equal(v3.boot_discount, [G**3, G**3, G**3, 0.0, 0.0, 0.0])


def test_truncation_bootstraps_everywhere():
    slot = build(end="truncated")
    np.testing.assert_array_equal(views.micro_view(slot).boot_discount, [G] * 6)
    np.testing.assert_array_equal(views.micro_view(slot, n_step=3).boot_discount, [G**3] * 4 + [G**2, G])
    np.testing.assert_array_equal(views.jert_view(slot).discount[:4], [G**2, G, G**2, G])
    np.testing.assert_array_equal(views.macro_view(slot).discount[1, :3], [G**2, G**3, G])


def test_jit_and_vmap_equal_plain(slot):
    """Each view under jit, and jitted on a stacked batch (auto-vmapped), equals the plain call."""
    other = build(end="truncated")
    batch = jax.tree_util.tree_map(lambda a, b: np.stack([a, b]), slot, other)
    for view in (views.micro_view, views.macro_view, views.jert_view, views.cert_view):
        plain = [view(slot), view(other)]
        jitted = jax.jit(view)(slot)
        batched = jax.jit(view)(batch)
        for leaf_p, leaf_j in zip(jax.tree_util.tree_leaves(plain[0]), jax.tree_util.tree_leaves(jitted)):
            np.testing.assert_array_equal(leaf_p, leaf_j)
        for b in range(2):
            for leaf_p, leaf_b in zip(jax.tree_util.tree_leaves(plain[b]), jax.tree_util.tree_leaves(batched)):
                np.testing.assert_array_equal(leaf_p, leaf_b[b])
    # two leading axes (seeds × episodes) are vmapped too
    seeds = jax.tree_util.tree_map(lambda x: np.stack([x, x[::-1]]), batch)
    two = jax.jit(views.jert_view)(seeds)
    np.testing.assert_array_equal(two.reward[1, 0], views.jert_view(other).reward)
