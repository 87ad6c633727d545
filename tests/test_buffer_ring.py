"""The FIFO ring of episode slots: wrap-around, batched adds, uniform sampling, jit/vmap."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _buffer_fixtures import config_for, synthetic_rollout

from jaxmac.buffer import episode, ring

H, N_AGENTS = 4, 2
CONFIG = config_for(H, N_AGENTS, 0.9)
_write = jax.jit(functools.partial(episode.write_episode, CONFIG))


def make_slot(ep_id: int):
    """A slot whose rewards carry its id (reward[t] = ep_id + t / 10)."""
    done = np.ones((H, N_AGENTS), bool)
    reset_ts, traj, _ = synthetic_rollout(done, ep_id + np.arange(H) / 10, H, end="truncated", seed=ep_id)
    return _write(reset_ts, traj)


def stack(slots):
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *slots)


def ids_in(r):
    return sorted(int(i) for i in np.round(np.asarray(r.slots.reward[: int(r.count), 0])))


@pytest.fixture(scope="module")
def slots():
    return [make_slot(i) for i in range(11)]


def test_wrap_around_keeps_exactly_the_newest(slots):
    add = jax.jit(ring.add, donate_argnums=0)
    r = ring.init(CONFIG, 4)
    assert int(r.count) == 0 and not bool(ring.can_sample(r, 1))
    for i, s in enumerate(slots):
        r = add(r, s)
        newest = list(range(max(0, i - 3), i + 1))
        assert ids_in(r) == newest
        assert sorted(np.asarray(r.episode_id[: int(r.count)]).tolist()) == newest
    assert int(r.added) == 11 and int(r.write_pos) == 11 % 4
    # slot contents are the episodes themselves, not just the ids
    for pos, ep_id in enumerate(np.asarray(r.episode_id)):
        for a, b in zip(jax.tree_util.tree_leaves(slots[ep_id]),
                        jax.tree_util.tree_leaves(jax.tree_util.tree_map(lambda x, pos=pos: x[pos], r.slots))):
            np.testing.assert_array_equal(a, b)


def test_batched_add_equals_sequential_adds(slots):
    seq = ring.init(slots[0], 4)  # init from an example slot
    for s in slots[:7]:
        seq = ring.add(seq, s)
    bat = ring.init(CONFIG, 4)
    for chunk in (slots[0:3], slots[3:4], slots[4:7]):
        bat = jax.jit(ring.add)(bat, stack(chunk))
    for a, b in zip(jax.tree_util.tree_leaves(seq), jax.tree_util.tree_leaves(bat)):
        np.testing.assert_array_equal(a, b)
    assert ids_in(bat) == [3, 4, 5, 6]


def test_bad_adds_raise(slots):
    r = ring.init(CONFIG, 2)
    with pytest.raises(ValueError, match="exceeds the capacity N=2"):
        ring.add(r, stack(slots[:3]))
    other = ring.init(config_for(H, N_AGENTS, 0.5), 2)
    with pytest.raises(ValueError, match="differs from the ring"):
        ring.add(other, slots[0])
    with pytest.raises(ValueError, match="capacity"):
        ring.init(CONFIG, 0)


def test_sampling_is_uniform_over_filled_slots_only(slots):
    r = ring.init(CONFIG, 8)
    r = ring.add(r, stack(slots[:3]))
    assert bool(ring.can_sample(r, 3)) and not bool(ring.can_sample(r, 4))
    batch, idx = jax.jit(ring.sample, static_argnums=2)(r, jax.random.key(0), 3000)
    idx = np.asarray(idx)
    assert idx.min() >= 0 and idx.max() <= 2
    counts = np.bincount(idx, minlength=3)
    # χ² test against uniform, 2 d.o.f.: 13.8 is the 0.1 % critical value
    chi2 = ((counts - 1000.0) ** 2 / 1000.0).sum()
    assert chi2 < 13.8, counts
    np.testing.assert_array_equal(np.round(np.asarray(batch.reward[:, 0])), idx)  # slot i holds episode i


def test_vmap_over_seeds_equals_separate_runs(slots):
    """init/add/sample vmapped over two seeds' rings equal the same calls run one by one."""
    def run(key, first):
        r = ring.init(CONFIG, 3)
        r = ring.add(r, first)
        r = ring.add(r, stack(slots[5:8]))
        return ring.sample(r, key, 5)

    keys = jax.random.split(jax.random.key(1), 2)
    firsts = stack(slots[:2])
    batched = jax.jit(jax.vmap(run))(keys, firsts)
    for s in range(2):
        single = jax.jit(run)(keys[s], slots[s])
        for a, b in zip(jax.tree_util.tree_leaves(single), jax.tree_util.tree_leaves(batched)):
            np.testing.assert_array_equal(a, b[s])
