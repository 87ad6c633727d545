"""Hypothesis property tests of the writer and the views over random termination patterns.

Shapes are fixed (H = 10, n ∈ {1, 2, 3}, γ = 0.9) so every function compiles once per n;
only the contents vary: which steps end which agent's macro-action, the episode length,
how it ends (terminated / truncated / cut by the slot end) and the rewards. Everything is
checked against plain-Python loops written here.
"""

import functools

import jax
import numpy as np
from _buffer_fixtures import config_for, reference_accumulators, synthetic_rollout
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxmac.buffer import episode, views

H, GAMMA = 10, 0.9
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


N_STEPS = (1, 3, 5)


@functools.lru_cache(maxsize=None)
def pipeline(n):
    """Writer and every view in one jitted call (one compile per agent count)."""

    def run(reset_ts, traj):
        slot = episode.write_episode(config_for(H, n, GAMMA), reset_ts, traj)
        micro = {k: views.micro_view(slot, k) for k in N_STEPS}
        return slot, micro, views.macro_view(slot), views.jert_view(slot), views.cert_view(slot)

    return jax.jit(run)


@st.composite
def rollouts(draw):
    n = draw(st.integers(1, 3))
    mac_done = np.array(draw(st.lists(st.booleans(), min_size=H * n, max_size=H * n)), bool).reshape(H, n)
    length = draw(st.integers(1, H))
    end = draw(st.sampled_from(["terminated", "truncated"] + (["none"] if length == H else [])))
    reward = np.array(draw(st.lists(st.integers(-40, 40), min_size=H, max_size=H)), np.float32) / 4
    seed = draw(st.integers(0, 2**16))
    reset_ts, traj, info = synthetic_rollout(mac_done, reward, length, end=end, seed=seed)
    slot, micro, macro, jert, cert = pipeline(n)(reset_ts, traj)
    return dict(n=n, mac_done=mac_done, length=length, end=end, reward=reward, slot=slot, micro=micro,
                macro=macro, jert=jert, cert=cert, **info)


def discounted(rewards):
    return sum(GAMMA**k * float(r) for k, r in enumerate(rewards))


@SETTINGS
@given(rollouts())
def test_writer_masks_everything_after_the_episode(ep):
    s, L = ep["slot"], ep["length"]
    assert int(s.length) == L
    np.testing.assert_array_equal(s.valid, np.arange(H) < L)
    np.testing.assert_array_equal(s.reward[:L], ep["reward"][:L])
    assert not s.reward[L:].any() and not s.mac_done[L:].any() and (np.asarray(s.mac[L:]) == -1).all()
    assert int(s.terminated.sum()) == (ep["end"] == "terminated") and bool(s.terminated[L - 1]) == (ep["end"] == "terminated")
    assert int(s.truncated.sum()) == (ep["end"] == "truncated")
    np.testing.assert_array_equal(s.decode_obs("real")[: L + 1], ep["obs_real"][: L + 1])
    np.testing.assert_array_equal(s.decode_obs("macro")[: L + 1], ep["obs_macro"][: L + 1])
    assert not s.decode_obs("real")[L + 1:].any() and not s.avail[L + 1:].any()
    np.testing.assert_array_equal(s.decode_state()[: L + 1], ep["state"][: L + 1])


@SETTINGS
@given(rollouts())
def test_segments_partition_each_agents_steps(ep):
    s, L, done = ep["slot"], ep["length"], ep["mac_done"]
    seg = s.segments
    for i in range(ep["n"]):
        k = int(seg.valid[i].sum())
        assert np.asarray(seg.valid[i]).tolist() == [True] * k + [False] * (H - k)  # left-packed
        ends = [t for t in range(L) if done[t, i] or (t == L - 1 and ep["end"] == "terminated")]
        assert int(seg.count[i]) == k == len(ends)
        np.testing.assert_array_equal(seg.end[i, :k], ends)
        starts = [0] + [e + 1 for e in ends[:-1]] if ends else []
        np.testing.assert_array_equal(seg.start[i, :k], starts)  # contiguous, ordered, from step 0
        np.testing.assert_array_equal(seg.duration[i, :k], np.array(ends) - np.array(starts) + 1)
        # the uncovered tail is one macro-action still running at truncation / slot end
        tail = range(ends[-1] + 1 if ends else 0, L)
        assert not any(done[t, i] for t in tail)
        assert not (ep["end"] == "terminated" and len(tail))
        for a, b, m, r in zip(starts, ends, np.asarray(seg.mac[i]), np.asarray(seg.R_m[i])):
            assert (ep["mac"][a : b + 1, i] == m).all()  # one executed macro-action per segment
            np.testing.assert_allclose(r, discounted(ep["reward"][a : b + 1]), rtol=1e-5, atol=1e-5)
        assert (np.asarray(seg.mac[i, k:]) == -1).all() and not seg.R_m[i, k:].any()


@SETTINGS
@given(rollouts())
def test_jert_and_cert_match_the_running_accumulator_reference(ep):
    L, done, n = ep["length"], ep["mac_done"], ep["n"]
    joint, agents = reference_accumulators(done, ep["reward"], L, GAMMA)
    last_obs = ep["obs_macro"]  # the record's "last_obs" at step t is obs_macro row t

    v = ep["jert"]
    kept = [t for t in range(L) if done[t].any()]
    k = len(kept)
    np.testing.assert_array_equal(v.mask, np.arange(H) < k)
    np.testing.assert_array_equal(v.step[:k], kept)
    np.testing.assert_allclose(v.reward[:k], [joint[t][0] for t in kept], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(v.tau[:k], [joint[t][1] for t in kept])
    np.testing.assert_array_equal(v.free_next[:k], done[kept])
    np.testing.assert_array_equal(v.mac[:k], ep["mac"][kept])
    np.testing.assert_array_equal(v.obs[:k], last_obs[kept])  # no observation changes inside a joint step
    np.testing.assert_array_equal(v.obs_next[:k], last_obs[np.array(kept, int) + 1])
    terminal = [ep["end"] == "terminated" and t == L - 1 for t in kept]
    np.testing.assert_allclose(v.discount[:k], [0.0 if term else GAMMA ** joint[t][1] for t, term in zip(kept, terminal)],
                               rtol=1e-6)
    assert not v.reward[k:].any() and not v.discount[k:].any()

    c = ep["cert"]
    for i in range(n):
        kept_i = [t for t in range(L) if done[t, i]]
        k = len(kept_i)
        np.testing.assert_array_equal(c.mask[i], np.arange(H) < k)
        np.testing.assert_array_equal(c.step[i, :k], kept_i)
        np.testing.assert_allclose(c.reward[i, :k], [agents[t][i][0] for t in kept_i], rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(c.tau[i, :k], [agents[t][i][1] for t in kept_i])
        np.testing.assert_array_equal(c.obs[i, :k], last_obs[kept_i, i])
        np.testing.assert_array_equal(c.mac[i, :k], ep["mac"][kept_i, i])


@SETTINGS
@given(rollouts(), st.sampled_from(N_STEPS))
def test_micro_n_step_returns_equal_brute_force(ep, n_step):
    L, r = ep["length"], ep["reward"]
    v = ep["micro"][n_step]
    terminated = ep["end"] == "terminated"
    for t in range(H):
        if t >= L:
            assert not v.mask[t] and float(v.ret[t]) == 0.0 and float(v.boot_discount[t]) == 0.0
            continue
        m = min(n_step, L - t)
        np.testing.assert_allclose(v.ret[t], discounted(r[t : t + m]), rtol=1e-5, atol=1e-5)
        assert int(v.boot_row[t]) == t + m
        expect = 0.0 if (terminated and t + m == L) else GAMMA**m
        np.testing.assert_allclose(v.boot_discount[t], expect, rtol=1e-6)
        last = t + m - 1
        np.testing.assert_array_equal(v.boot_free[t], ep["mac_done"][last])
        busy = ~ep["mac_done"][last]
        np.testing.assert_array_equal(v.boot_mac[t][busy], ep["mac"][last][busy])
        np.testing.assert_array_equal(v.boot_t_m[t], np.where(busy, ep["t_m"][last] + 1, 0))
        np.testing.assert_array_equal(v.boot_avail[t], ep["avail"][t + m])


@SETTINGS
@given(rollouts())
def test_macro_view_targets(ep):
    s, L = ep["slot"], ep["length"]
    m = ep["macro"]
    seg = s.segments
    np.testing.assert_array_equal(m.mask, seg.valid)
    for i, k in zip(*np.nonzero(np.asarray(seg.valid))):
        start, end, tau = int(seg.start[i, k]), int(seg.end[i, k]), int(seg.duration[i, k])
        assert int(m.boot_row[i, k]) == end + 1 <= L
        terminal = ep["end"] == "terminated" and end == L - 1
        np.testing.assert_allclose(m.discount[i, k], 0.0 if terminal else GAMMA**tau, rtol=1e-6)
        assert int(m.start_t_m[i, k, i]) == 0  # the segment's own agent starts fresh
        np.testing.assert_array_equal(m.start_t_m[i, k], ep["t_m"][start])
        np.testing.assert_array_equal(m.start_mac[i, k], ep["mac"][start])
