"""Episode slot: a real Box Pushing rollout round-trips; storage codecs; config validation."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _buffer_fixtures import config_for, synthetic_rollout

import envs_jax
from jaxmac import collect
from jaxmac.buffer import episode, views
from jaxmac.buffer.episode import ObsCodec, SlotConfig


@pytest.fixture(scope="module")
def bp():
    env = envs_jax.make("boxpushing-6x6")
    config = SlotConfig.from_spec(env.spec)

    init_carry, act = collect.random_policy()

    def rollout_and_write(key):
        reset_ts, traj, _ = collect.run_episode(env, act, init_carry, None, key, 0.0)
        return reset_ts, traj, episode.write_episode(config, reset_ts, traj)

    # two seeds: vmapped writing must equal writing each episode alone
    keys = jax.random.split(jax.random.key(3), 2)
    reset_ts, traj, slots = jax.jit(jax.vmap(rollout_and_write))(keys)
    first = lambda tree: jax.tree_util.tree_map(lambda x: x[0], tree)
    single = jax.jit(functools.partial(episode.write_episode, config))(first(reset_ts), first(traj))
    return env, config, reset_ts, traj, slots, single


def test_boxpushing_slot_round_trips(bp):
    env, config, reset_ts, traj, slots, _ = bp
    assert config.obs == ObsCodec("uint8") and config.horizon == env.spec.horizon == 100
    for e in range(2):
        slot, ts0, tr = jax.tree_util.tree_map(lambda x, e=e: np.asarray(x[e]), (slots, reset_ts, traj))
        done = tr.terminated | tr.truncated
        L = int(np.argmax(done)) + 1 if done.any() else config.horizon
        assert int(slot.length) == L
        np.testing.assert_array_equal(slot.reward[:L], tr.reward[:L])
        np.testing.assert_array_equal(slot.mac[:L], tr.mac[:L])
        np.testing.assert_array_equal(slot.t_m[:L], tr.t_m[:L])
        np.testing.assert_array_equal(slot.mac_done[:L], tr.mac_done[:L])
        for name, field in (("real", "obs_real"), ("macro", "obs_macro")):
            want = np.concatenate([getattr(ts0, field)[None], getattr(tr, field)[:L]])
            assert config.obs.roundtrip_error(want) == 0.0  # binary features: uint8 is lossless
            np.testing.assert_array_equal(slot.decode_obs(name)[: L + 1], want)
        np.testing.assert_array_equal(slot.decode_state()[: L + 1], np.concatenate([ts0.state[None], tr.state[:L]]))
        np.testing.assert_array_equal(slot.avail[: L + 1], np.concatenate([ts0.avail_actions[None], tr.avail_actions[:L]]))
        # the segment table's returns are the episode's rewards regrouped: with γ = 1 they sum to
        # the rewards of each agent's completed segments, which cover every step up to the last end
        seg = slot.segments
        for i in range(env.spec.num_agents):
            k = int(seg.valid[i].sum())
            for s, t, r in zip(np.asarray(seg.start[i, :k]), np.asarray(seg.end[i, :k]), np.asarray(seg.R_m[i, :k])):
                want_r = sum(env.spec.discount**j * float(x) for j, x in enumerate(tr.reward[s : t + 1]))
                np.testing.assert_allclose(r, want_r, rtol=1e-5, atol=1e-4)


def test_boxpushing_vmapped_write_equals_single(bp):
    *_, slots, single = bp
    for a, b in zip(jax.tree_util.tree_leaves(single), jax.tree_util.tree_leaves(slots)):
        np.testing.assert_array_equal(a, b[0])


def test_boxpushing_views_run_on_a_sampled_batch(bp):
    """Views accept the [B, ...] batch a ring sample returns; masks count what they should."""
    slots = bp[4]
    jv = jax.jit(views.jert_view)(slots)
    mv = jax.jit(views.macro_view)(slots)
    assert jv.mask.shape == (2, 100) and mv.mask.shape == (2, 2, 100)
    mac_done = np.asarray(slots.mac_done)
    np.testing.assert_array_equal(jv.mask.sum(1), mac_done.any(2).sum(1))
    np.testing.assert_array_equal(mv.mask.sum(2), slots.segments.count)


def test_overcooked_fractions_round_trip_in_scaled_uint8():
    codec = ObsCodec("uint8", 21.0)  # the Overcooked default
    k7, c3 = np.arange(8, dtype=np.float32), np.arange(4, dtype=np.float32)
    exact = np.concatenate([k7 / 7, c3 / 3]).astype(np.float32)  # correctly rounded
    xla = np.concatenate([k7 * np.float32(1 / 7), c3 * np.float32(1 / 3)])  # what a jitted x/7 gives
    np.testing.assert_array_equal(codec.encode(jnp.asarray(xla)), np.r_[np.arange(8) * 3, np.arange(4) * 7])
    assert codec.roundtrip_error(exact) <= 6e-8 and codec.roundtrip_error(xla) <= 6e-8  # ≤ 1 ulp of 1.0
    assert ObsCodec("uint8").roundtrip_error(exact) > 0.1  # unscaled uint8 would lose them


def test_storage_dtypes_and_bytes():
    reset_ts, traj, info = synthetic_rollout(np.ones((6, 2), bool), np.ones(6), 6)
    sizes = {}
    for dtype in ("float32", "float16", "uint8", "bool"):
        cfg = config_for(6, 2, 0.5, obs=ObsCodec(dtype))
        slot = episode.write_episode(cfg, reset_ts, traj)
        assert slot.obs_real.dtype == np.dtype(dtype) and slot.obs_macro.dtype == np.dtype(dtype)
        sizes[dtype] = episode.slot_nbytes(slot)
        assert sizes[dtype] == episode.slot_nbytes(cfg)
        if dtype in ("float32", "float16", "uint8"):  # small integers survive all three
            np.testing.assert_array_equal(slot.decode_obs(), info["obs_real"])
    obs_entries = 2 * 7 * 2 * 3  # real + macro rows, [H+1, n, O]
    assert sizes["float32"] - sizes["uint8"] == 3 * obs_entries
    assert sizes["float32"] - sizes["float16"] == 2 * obs_entries


def test_from_spec_defaults_and_overrides():
    spec = envs_jax.make("boxpushing-6x6").spec
    cfg = SlotConfig.from_spec(spec, horizon=50, k_max=20)
    assert (cfg.horizon, cfg.k_max, cfg.num_agents, cfg.obs_dim, cfg.num_actions, cfg.state_dim) == (50, 20, 2, 5, 8, 18)
    assert cfg.discount == pytest.approx(0.98) and SlotConfig.from_spec(spec).k_max == 100
    with pytest.raises(ValueError, match="unknown override"):
        SlotConfig.from_spec(spec, horizn=50)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(k_max=0), "k_max=0"),
        (dict(k_max=11), r"k_max=11 must be an integer in \[1, horizon=10\]"),
        (dict(discount=1.5), "discount=1.5"),
        (dict(state_dtype="int8"), "state_dtype='int8'; valid choices"),
        (dict(num_agents=0), "num_agents=0"),
    ],
)
def test_bad_config_raises(kwargs, match):
    base = dict(horizon=10, num_agents=2, obs_dim=3, num_actions=4, state_dim=2, discount=0.9)
    with pytest.raises(ValueError, match=match):
        SlotConfig(**{**base, **kwargs})


def test_bad_codec_raises():
    with pytest.raises(ValueError, match=r"dtype='int4'; valid choices: \['bfloat16', 'bool'"):
        ObsCodec("int4")
    with pytest.raises(ValueError, match="only meaningful with dtype 'uint8'"):
        ObsCodec("float16", 21.0)


def test_writer_rejects_wrong_shapes():
    reset_ts, traj, _ = synthetic_rollout(np.ones((5, 2), bool), np.ones(5), 5)
    with pytest.raises(ValueError, match=r"trajectory.obs_real has shape \(5, 2, 3\), expected \(6, 2, 3\)"):
        episode.write_episode(config_for(6, 2, 0.9), reset_ts, traj)
    with pytest.raises(ValueError, match=r"obs_real has shape \(2, 3\), expected \(2, 4\)"):
        episode.write_episode(config_for(5, 2, 0.9, obs_dim=4), reset_ts, traj)


def test_k_max_smaller_than_segments_keeps_the_first_and_counts_all():
    reset_ts, traj, _ = synthetic_rollout(np.ones((6, 2), bool), np.arange(6), 6, end="truncated")
    slot = episode.write_episode(config_for(6, 2, 0.5, k_max=3), reset_ts, traj)
    np.testing.assert_array_equal(slot.segments.end, [[0, 1, 2]] * 2)
    np.testing.assert_array_equal(slot.segments.R_m, [[0, 1, 2]] * 2)
    np.testing.assert_array_equal(slot.segments.count, [6, 6])
    assert views.cert_view(slot).mask.shape == (2, 3)


def test_close_on_terminal_flag():
    """A macro-action still running at termination is a complete (terminal) segment by
    default; with close_on_terminal=False it is dropped like at truncation (MacroMARL)."""
    reset_ts, traj, _ = synthetic_rollout(np.zeros((6, 2), bool), np.ones(6), 3, end="terminated")
    on = episode.write_episode(config_for(6, 2, 0.5), reset_ts, traj)
    off = episode.write_episode(config_for(6, 2, 0.5, close_on_terminal=False), reset_ts, traj)
    np.testing.assert_array_equal(on.segments.count, [1, 1])
    np.testing.assert_array_equal(on.segments.R_m[:, 0], [1.75, 1.75])
    np.testing.assert_array_equal(views.macro_view(on).discount[:, 0], [0.0, 0.0])
    assert int(off.segments.count.sum()) == 0 and not bool(off.segments.valid.any())
    assert not bool(views.cert_view(on).mask.any())  # Mac-CERT follows mac_done only
