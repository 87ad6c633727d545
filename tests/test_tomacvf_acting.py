"""ToMacVF's decentralised acting rule (DECISIONS D17): busy agents re-send their running macro-action, free agents
choose among their available ones — greedily on the agent network's Q at ε = 0, uniformly at ε = 1 — and the
recurrent carry steps every primitive step on Mac-SJERT but only at joint decision points on Mac-JERT."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _learner_helpers import assert_frequencies, random_params

from jaxmac.algos.registry import make_algorithm
from jaxmac.algos.tomacvf import network_configs
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.networks import TemporalAgentNet, initial_carry, timestep_inputs
from jaxmac.ops import masked_argmax

KEYS = 4000  # draws per frequency check


@pytest.fixture(scope="module", params=["mac_sjert", "mac_jert"])
def acting(request):
    """The algorithm's ``act`` (jitted, vmapped over keys), its agent network, params, and timesteps of the env with
    chosen free/busy patterns and availability masks."""
    values = dict(buffer=request.param, obs_mode="macro") if request.param == "mac_jert" else {}
    config = scenario_config("boxpushing-6x6", tiny=True).override(**values)
    env = make_env(config)
    algo = make_algorithm(config, env)
    params = random_params(algo.init_params, 5, scale=0.6)
    net = TemporalAgentNet(network_configs(config, env)[0])
    _, ts = env.reset(jax.random.key(0))
    n, width = ts.avail_actions.shape
    rng = np.random.default_rng(1)
    avail = rng.random((n, width)) < 0.5
    avail[:, 0] = True  # at least one available action each; several unavailable ones
    avail[:, 1] = False
    carry = jnp.asarray(rng.normal(size=np.shape(initial_carry(net.config))), jnp.float32)

    obs_real = jnp.asarray(rng.integers(0, 3, ts.obs_real.shape), jnp.float32)  # unlike the frozen obs_macro

    def timestep(free):
        return ts.replace(mac_done=jnp.asarray(free), avail_actions=jnp.asarray(avail), obs_real=obs_real,
                          mac=jnp.asarray([3, 5][:n], jnp.int32), t_m=jnp.asarray([2, 1][:n], jnp.int32),
                          t=jnp.int32(7))

    many = jax.jit(jax.vmap(algo.act, in_axes=(None, None, None, 0, None)))
    return dict(config=config, algo=algo, params=params, net=net, timestep=timestep, carry=carry, avail=avail,
                many=many, n=n)


def greedy_reference(acting, ts):
    """The free agents' greedy choice written out: the agent network's Q at τ = 0 on the timestep's inputs (macro
    observations on Mac-JERT), then the argmax over available actions."""
    inputs = timestep_inputs(ts)
    if acting["config"].algo.obs_mode == "macro":
        inputs = inputs.replace(obs=jnp.asarray(ts.obs_macro, jnp.float32))
    q, _ = acting["net"].apply(acting["params"]["agent"], inputs, acting["carry"], jnp.zeros_like(ts.t_m),
                               method="step")
    return np.asarray(masked_argmax(q, jnp.asarray(acting["avail"])))


def test_busy_agents_resend_and_free_agents_choose_available_actions(acting):
    keys = jax.random.split(jax.random.key(2), 200)
    ts = acting["timestep"]([True, False])
    for epsilon in (0.0, 0.5, 1.0):
        _, actions = acting["many"](acting["params"], acting["carry"], ts, keys, epsilon)
        actions = np.asarray(actions)
        assert (actions[:, 1] == 5).all()  # busy: its running macro-action, whatever ε
        assert acting["avail"][0, actions[:, 0]].all()  # free: an available action only


def test_epsilon_zero_is_greedy_and_epsilon_one_uniform(acting):
    ts = acting["timestep"]([True, True])
    want = greedy_reference(acting, ts)
    keys = jax.random.split(jax.random.key(3), KEYS)
    _, greedy = acting["many"](acting["params"], acting["carry"], ts, keys, 0.0)
    assert (np.asarray(greedy) == want[None, :]).all()
    _, uniform = acting["many"](acting["params"], acting["carry"], ts, keys, 1.0)
    uniform = np.asarray(uniform)
    for i in range(acting["n"]):
        allowed = acting["avail"][i]
        assert_frequencies(uniform[:, i], allowed / allowed.sum(), f"agent {i} at ε = 1")
    # in between: the greedy action with probability 1 − ε + ε/|available|
    _, mixed = acting["many"](acting["params"], acting["carry"], ts, keys, 0.4)
    for i in range(acting["n"]):
        p = 0.6 + 0.4 / acting["avail"][i].sum()
        freq = np.mean(np.asarray(mixed)[:, i] == want[i])
        assert abs(freq - p) < 5 * np.sqrt(p * (1 - p) / KEYS), (i, freq, p)


def test_the_carry_steps_every_step_on_sjert_and_only_at_decisions_on_jert(acting):
    act = jax.jit(acting["algo"].act)
    key = jax.random.key(4)
    busy, _ = act(acting["params"], acting["carry"], acting["timestep"]([False, False]), key, 0.0)
    some, _ = act(acting["params"], acting["carry"], acting["timestep"]([False, True]), key, 0.0)
    assert not np.allclose(np.asarray(some), np.asarray(acting["carry"]))  # a decision point: the GRU steps
    if acting["config"].algo.buffer == "mac_jert":
        np.testing.assert_array_equal(np.asarray(busy), np.asarray(acting["carry"]))  # no decision: frozen
    else:
        assert not np.allclose(np.asarray(busy), np.asarray(acting["carry"]))  # every primitive step
