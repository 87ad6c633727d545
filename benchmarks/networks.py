"""Forward+backward cost of the ToMacVF networks (agent net + ATPG + mixer).

    python benchmarks/networks.py [--batch 32] [--steps 100] [--repeats 15]

For a Box-Pushing-like (n=2, O=5, A=8, S=18) and an Overcooked-like (n=3, O=32, A=14, S=32)
shape, GRU 32, times one jitted ``value_and_grad`` of a surrogate TD loss over B whole
episodes of T steps (T+1 rows): the agent nets over every row, Q_i at the executed actions,
the mixer's weights for every row and Q_tot = mix(weights, Q), MSE to fixed targets. Mixers:
'atpg_qmix' with the full causal window and with ``attn_window=32``, 'qmix' (w/o ATPG), 'vdn'.
Compile time is reported apart (``lower().compile()``); the cases are timed round robin,
``--repeats`` times each (min and median).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.networks import (
    AgentNetConfig,
    ATPGConfig,
    Mixer,
    MixerConfig,
    NetInputs,
    TemporalAgentNet,
    init_agent_params,
    init_mixer_params,
    initial_carry,
    mix,
)
from jaxmac.ops import gather_q

SHAPES = {"BP-like": dict(n=2, obs=5, actions=8, state=18), "OC-like": dict(n=3, obs=32, actions=14, state=32)}


def make_batch(rng, b, rows, n, o, a, s):
    t = np.broadcast_to(np.arange(rows, dtype=np.int32), (b, rows))
    prev_mac = rng.integers(0, a, (b, rows, n)).astype(np.int32)
    prev_mac[:, 0] = -1
    inputs = NetInputs(
        obs=jnp.asarray(rng.random((b, rows, n, o)), jnp.float32), t=jnp.asarray(t), prev_t=jnp.asarray(t - 1),
        prev_mac=jnp.asarray(prev_mac), prev_t_m=jnp.asarray(rng.integers(0, 10, (b, rows, n)), jnp.int32),
        reset=jnp.asarray(t == 0),
    )
    tau = jnp.asarray(rng.integers(0, 10, (b, rows, n)), jnp.int32)
    actions = jnp.asarray(rng.integers(0, a, (b, rows, n)), jnp.int32)
    state = jnp.asarray(rng.normal(size=(b, rows, s)), jnp.float32)
    target = jnp.asarray(rng.normal(size=(b, rows)), jnp.float32)
    return inputs, tau, actions, state, target


def build(shape, kind, window, b, steps, hidden=32):
    """(compiled value_and_grad of the surrogate loss, its (params, batch), compile seconds)."""
    n, o, a, s = shape["n"], shape["obs"], shape["actions"], shape["state"]
    agent_cfg = AgentNetConfig(num_agents=n, obs_dim=o, num_actions=a, hidden=hidden)
    atpg_cfg = ATPGConfig(num_agents=n, obs_dim=o, num_actions=a, attn_window=window)
    mixer_cfg = MixerConfig(num_agents=n, state_dim=s, kind=kind, atpg=atpg_cfg if kind == "atpg_qmix" else None)
    net, mixer = TemporalAgentNet(agent_cfg), Mixer(mixer_cfg)
    params = {"agent": init_agent_params(agent_cfg, jax.random.key(0)),
              "mixer": init_mixer_params(mixer_cfg, jax.random.key(1))}
    batch = make_batch(np.random.default_rng(0), b, steps + 1, n, o, a, s)

    def loss(p, batch):  # the batch is an argument, not a constant XLA could fold
        inputs, tau, actions, state, target = batch
        q, _, _ = net.apply(p["agent"], inputs, initial_carry(agent_cfg, (b,)), tau)
        weights, _ = mixer.apply(p["mixer"], state, inputs)
        q_tot = mix(weights, gather_q(q, actions))
        return jnp.mean((q_tot - target) ** 2)

    t0 = time.perf_counter()
    compiled = jax.jit(jax.value_and_grad(loss)).lower(params, batch).compile()
    return compiled, (params, batch), time.perf_counter() - t0


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    print(f"B={args.batch}, T={args.steps} steps ({args.steps + 1} rows), GRU 32, device {jax.devices()[0]}")
    cases = {}
    for label, shape in SHAPES.items():
        for kind, window in (("atpg_qmix", None), ("atpg_qmix", 32), ("qmix", None), ("vdn", None)):
            name = kind if kind != "atpg_qmix" else f"atpg_qmix(window={'full' if window is None else window})"
            cases[(label, shape["n"], name)] = build(shape, kind, window, args.batch, args.steps)
    runs = {key: [] for key in cases}
    for _ in range(args.repeats):  # round robin, so that load changes hit every case alike
        for key, (compiled, args_, _) in cases.items():
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(*args_))
            runs[key].append(time.perf_counter() - t0)
    for (label, n, name), (_, _, compile_s) in cases.items():
        r = np.asarray(runs[(label, n, name)]) * 1e3
        print(f"{label:8s} n={n}  {name:24s} compile {compile_s:6.2f} s   "
              f"fwd+bwd min {r.min():7.1f} ms  median {np.median(r):7.1f} ms")


if __name__ == "__main__":
    main()
