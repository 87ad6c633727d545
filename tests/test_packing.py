"""Packing episodes back to back (``jaxmac.buffer.packing``): the plan is a valid first-fit packing, pack/unpack are
inverse on every episode's rows, and ToMacVF's networks and update on packed rows equal those on the episodes' own
slots (Box Pushing and Overcooked-A; whole-episode and windowed attention)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _learner_helpers import episode_slot, random_params
from _value_references import stack
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxmac.algos.registry import make_algorithm
from jaxmac.algos.base import Progress
from jaxmac.algos.tomacvf import network_configs
from jaxmac.buffer import packing
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.networks import Mixer, TemporalAgentNet, initial_carry, slot_inputs
from jaxmac.networks.inputs import NetInputs

WIDTH = 12
_plan = jax.jit(packing.pack_plan, static_argnums=1)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, WIDTH - 1), min_size=1, max_size=9))
def test_the_plan_packs_every_episode_without_overlap_and_unpack_inverts_pack(lengths):
    lengths = np.asarray(lengths, np.int32)
    b = len(lengths)
    plan = jax.device_get(_plan(jnp.asarray(lengths), WIDTH))
    used = np.zeros((b, WIDTH), int)
    for e in range(b):
        assert 0 <= plan.row[e] < plan.rows_used <= b
        assert plan.offset[e] + lengths[e] + 1 <= WIDTH  # its rows and its bootstrap row fit
        used[plan.row[e], plan.offset[e]:plan.offset[e] + lengths[e] + 1] += 1
    assert used.max() == 1  # no position holds two episodes
    assert plan.rows_used == len(set(plan.row.tolist()))  # the rows used are 0..rows_used-1
    # first fit never leaves two rows at most half full
    assert plan.rows_used <= -(-2 * int((lengths + 1).sum()) // WIDTH) + 1
    x = jnp.asarray(np.random.default_rng(b).normal(size=(b, WIDTH, 3)), jnp.float32)
    for rows in (int(plan.rows_used), b):
        back = np.asarray(packing.unpack(packing.pack(x, packing.packed_layout(plan, rows, WIDTH)), plan))
        for e in range(b):
            np.testing.assert_array_equal(back[e, :lengths[e] + 1], np.asarray(x[e, :lengths[e] + 1]))
            assert (back[e, lengths[e] + 1:] == 0).all()
    reset = np.asarray(packing.packed_layout(plan, b, WIDTH).reset)
    starts = {(int(plan.row[e]), int(plan.offset[e])) for e in range(b)}
    assert all(reset[r, c] for r, c in starts)
    assert reset[used == 0].all() and not any(reset[r, c] for r, c in zip(*np.nonzero(used)) if (r, c) not in starts)


CASES = [("boxpushing-6x6", 0), ("overcooked-A", 5)]


def short_slots(spec, h=16):
    shape = dict(h=h, n=spec.num_agents, obs_dim=spec.obs_dim, num_actions=spec.max_actions,
                 state_dim=spec.state_dim, gamma=spec.discount)
    done = [True] + [False] * (spec.num_agents - 1)
    return stack([episode_slot(seed, length, end, p=0.5, last_done=last, **shape)[0]
                  for seed, length, end, last in ((40, 7, "terminated", done), (41, 3, "truncated", None),
                                                   (42, 5, "terminated", None), (43, 16, "truncated", None),
                                                   (44, 1, "terminated", done))])


@pytest.mark.parametrize("scenario,window", CASES)
def test_networks_on_packed_rows_equal_the_networks_on_each_slot(scenario, window):
    config = scenario_config(scenario, "tomacvf", tiny=True).override(horizon=16, attn_window=window)
    env = make_env(config)
    agent_cfg, mixer_cfg = network_configs(config, env)
    net, mixer = TemporalAgentNet(agent_cfg), Mixer(mixer_cfg)
    slots = short_slots(env.spec)
    inputs, tau = slot_inputs(slots)
    state = slots.decode_state()
    algo = make_algorithm(config, env)
    params = random_params(algo.init_params, 5, 0.3)

    def forward(inputs, tau, state):
        q, _, _ = net.apply(params["agent"], inputs, initial_carry(agent_cfg, inputs.t.shape[:-1]), tau)
        w, _ = mixer.apply(params["mixer"], state, inputs)
        return q, w

    plan = _plan(slots.length, 17)
    rows = int(plan.rows_used)
    assert rows < 5  # several episodes share a row
    layout = packing.packed_layout(plan, rows, 17)
    pk = lambda x: packing.pack(x, layout)  # noqa: E731
    packed = NetInputs(obs=pk(inputs.obs), t=pk(inputs.t), prev_t=pk(inputs.prev_t), prev_mac=pk(inputs.prev_mac),
                       prev_t_m=pk(inputs.prev_t_m), reset=layout.reset)
    q_ref, w_ref = jax.jit(forward)(inputs, tau, state)
    q_pk, w_pk = jax.jit(forward)(packed, pk(tau), pk(state))
    q_back = packing.unpack(q_pk, plan)
    w_back = w_pk.map_rows(lambda x: packing.unpack(x, plan))
    for e, length in enumerate(np.asarray(slots.length)):
        np.testing.assert_allclose(np.asarray(q_back[e, :length + 1]), np.asarray(q_ref[e, :length + 1]),
                                   rtol=1e-5, atol=1e-5)
        for got, want in zip(jax.tree_util.tree_leaves(w_back), jax.tree_util.tree_leaves(w_ref)):
            np.testing.assert_allclose(np.asarray(got[e, :length + 1]), np.asarray(want[e, :length + 1]),
                                       rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("scenario", ["overcooked-A"])  # 3 agents; the networks test above covers Box Pushing too
def test_tomacvf_update_with_packing_equals_the_full_length_update(scenario):
    config = scenario_config(scenario, "tomacvf", tiny=True).override(horizon=16, n_step=2, batch_size=5)
    env = make_env(config)
    slots = short_slots(env.spec)
    plain = make_algorithm(config, env)
    packed = make_algorithm(config.override(packing=True, length_buckets=3), env)  # 2, 3, 4 or 5 rows: 3 here
    params, target = random_params(plain.init_params, 6, 0.3), random_params(plain.init_params, 7, 0.3)
    progress = Progress(episodes=jnp.int32(8), env_steps=jnp.int32(60), updates=jnp.int32(1))
    args = (params, target, plain.optimizer.init(params), slots, jax.random.key(1), progress)
    update = jax.jit(packed.update)
    assert "stablehlo.case" in update.lower(*args).as_text()
    new_ref, _, m_ref = jax.jit(plain.update)(*args)
    new_pk, _, m_pk = update(*args)
    assert set(m_ref) == set(m_pk)
    for name in m_ref:  # the loss terms and the gradient's norm
        np.testing.assert_allclose(float(m_pk[name]), float(m_ref[name]), rtol=1e-5, atol=1e-6, err_msg=name)
    for a, b in zip(jax.tree_util.tree_leaves(new_ref), jax.tree_util.tree_leaves(new_pk)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=0.5 * config.lr)


def test_packing_is_refused_with_the_squeezed_buffer():
    with pytest.raises(ValueError, match="packing=True"):
        scenario_config("boxpushing-6x6", tiny=True).override(packing=True, buffer="mac_jert", obs_mode="macro")
