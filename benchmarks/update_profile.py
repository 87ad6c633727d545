"""Where a round of a learner with length buckets spends its time: collection, and the update at every bucket.

    python benchmarks/update_profile.py [--algorithm mac_iaicc] [--scenario overcooked-A] [--epsilon 1.0]
                                        [--repeats 5] [--set KEY=VALUE ...] [--ops K] [--roofline]

One seed, ``jax.jit`` of each piece, the scenario's configuration: a first-finished collection of episodes with
freshly initialised parameters (ε as given) — a round's ``num_envs`` for the on-policy learners (their batch), a
replay batch's ``batch_size`` for ToMacVF — then ``algorithm.update`` on that batch cut to each static length of
``bucket_sizes(H, length_buckets)`` that holds it (the trainer picks the smallest), and the full length; for ToMacVF also the update with ``packing`` (the episodes packed into the fewest rows of
``packed_row_sizes(B, length_buckets)``). ``--run RUN_DIR`` (ToMacVF) samples the batch from that run's replay ring
(its first seed's, as checkpointed) instead of collecting it. Printed: milliseconds per call (median of ``--repeats``) and the batch's real entries (``--ops K``: also the K
costliest XLA operation kinds of the full-length update, from a ``jax.profiler`` trace; ``--roofline``, ToMacVF:
the update's milliseconds per network part beside the part's hand-counted GFLOP and the rate it runs at); with
other jobs on the machine read the ratios between the lines, not the milliseconds.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time


def main(argv=None) -> None:
    from jaxmac.algos.registry import REGISTRY

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bucketed = [name for name, entry in REGISTRY.items() if entry.settings.supports_length_buckets]
    p.add_argument("--algorithm", default="mac_iaicc", choices=bucketed)
    p.add_argument("--scenario", default="overcooked-A")
    p.add_argument("--epsilon", type=float, default=1.0, help="exploration rate of the profiled collection")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--ops", type=int, default=0, metavar="K",
                   help="also trace the full-length update with jax.profiler and print the K costliest XLA operation "
                        "kinds (matmul fusions, loops, copies, ...) in ms per update")
    p.add_argument("--roofline", action="store_true",
                   help="ToMacVF: the full-length update's time per network part (from a jax.profiler trace, each "
                        "XLA operation attributed to the part its metadata names) beside the part's hand-counted "
                        "GFLOP: the table of rates that says where the update runs far below the matmul rate")
    p.add_argument("--run", default=None, metavar="RUN_DIR",
                   help="ToMacVF: sample the batch from this run's ring (its config, with --set applied, replaces "
                        "--scenario)")
    args = p.parse_args(argv)

    import jax
    import jax.numpy as jnp

    from jaxmac.algos.base import Progress
    from jaxmac.algos.registry import make_algorithm
    from jaxmac.buckets import bucket_sizes, packed_row_sizes
    from jaxmac.buffer.episode import write_episode
    from jaxmac.buffer.sources import store_length
    from jaxmac.collect import run_episodes_first_finished
    from jaxmac.config import make_env
    from jaxmac.presets import scenario_config
    from jaxmac.trainer import make_train

    if args.run is not None:
        from jaxmac.buffer import ring as ring_lib
        from jaxmac.runs import load_run

        trainer, run_state, _, _ = load_run(args.run)
        env = trainer.env
        config = trainer.config.override_strings(args.assignments)  # e.g. batch_size; not the networks' sizes
        algorithm = make_algorithm(config, env)
        state = jax.tree_util.tree_map(lambda x: x[0], run_state)
        args.scenario, args.algorithm = config.scenario, config.algorithm
    else:
        config = scenario_config(args.scenario, args.algorithm).override_strings(args.assignments)
        env = make_env(config)
        algorithm = make_algorithm(config, env)
        trainer = make_train(config, env, algorithm)
        state = jax.jit(trainer.init)(jax.random.key(0))
    replay = algorithm.store is not store_length  # a replay learner (ToMacVF) samples episode slots from its ring
    E = config.batch_size if replay else config.num_envs

    def timed(fn, *xs):
        out = jax.block_until_ready(fn(*xs))  # compile
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*xs))
            times.append(time.perf_counter() - t0)
        return 1000 * statistics.median(times), out

    @jax.jit
    def collect(params, key):
        reset_ts, traj = run_episodes_first_finished(env, algorithm.act, algorithm.init_carry, params, key,
                                                     args.epsilon, E, E)
        return jax.vmap(write_episode, in_axes=(None, 0, 0))(trainer.slot_config, reset_ts, traj)

    if args.run is not None:
        ms, slots = timed(jax.jit(lambda ring, key: ring_lib.sample(ring, key, E)[0]), state.ring, jax.random.key(1))
    else:
        ms, slots = timed(collect, state.params, jax.random.key(1))
    if replay:
        batch, real, full = slots, int(slots.length.max()), env.spec.horizon
    else:
        batch = jax.jit(lambda s: algorithm.sample(None, s, None))(slots)
        real = int(batch.entries())
        full = (batch.cert if batch.cert is not None else batch.jert).mask.shape[-1]
    what = "sampled batch" if replay else "round"
    print(f"{args.scenario}: {args.algorithm}, {E} episodes per {what} (mean length {float(slots.length.mean()):.1f} "
          f"of {env.spec.horizon}); longest real sequence {real} of {full} entries")
    print(f"  {'sampling' if args.run else 'collection'} of {E} episodes: {ms:8.1f} ms")
    zero = jnp.zeros((), jnp.int32)
    progress = Progress(episodes=zero, env_steps=zero, updates=zero)
    plain = config.override(length_buckets=1)
    update = jax.jit(make_algorithm(plain, env).update)
    if args.roofline:
        if args.algorithm != "tomacvf":
            p.error("--roofline counts ToMacVF's network parts; use it with --algorithm tomacvf")
        update_args = (state.params, state.target_params, state.opt_state, batch, jax.random.key(2), progress)
        print_roofline(update, update_args, config, env, batch.length.shape[0], full + 1, args.repeats)
    if args.ops:
        print("  XLA operation kinds of the full-length update (ms per update; a loop's time includes its body's):")
        for kind, ms in op_kinds(update, (state.params, state.target_params, state.opt_state, batch, jax.random.key(2),
                                          progress), args.repeats)[:args.ops]:
            print(f"    {ms:8.1f} ms  {kind}")
    for size in [s for s in bucket_sizes(full, config.length_buckets) if s >= real] or [full]:
        ms, _ = timed(update, state.params, state.target_params, state.opt_state, batch.prefix(size),
                      jax.random.key(2), progress)
        label = "full length" if size == full else f"bucket of {size}"
        print(f"  update on {label:>15}: {ms:8.1f} ms")
    if replay:
        from jaxmac.buffer.packing import pack_plan

        rows = int(pack_plan(batch.length, full + 1).rows_used)
        packed = jax.jit(make_algorithm(config.override(packing=True), env).update)
        ms, _ = timed(packed, state.params, state.target_params, state.opt_state, batch, jax.random.key(2), progress)
        size = min(s for s in packed_row_sizes(E, config.length_buckets) if s >= rows)
        print(f"  update with packing ({rows} rows needed, {size} run of {E}): {ms:8.1f} ms")


def trace_events(fn, args, repeats: int) -> list[dict]:
    """The complete-duration events of a ``jax.profiler`` trace of ``repeats`` calls of the jitted ``fn``."""
    import glob
    import gzip
    import json
    import tempfile

    import jax

    jax.block_until_ready(fn(*args))
    with tempfile.TemporaryDirectory() as trace_dir:
        jax.profiler.start_trace(trace_dir, create_perfetto_trace=True)
        for _ in range(repeats):
            jax.block_until_ready(fn(*args))
        jax.profiler.stop_trace()
        # the perfetto trace (the profiler writes a second, TensorBoard-format json.gz beside it)
        (path,) = glob.glob(os.path.join(trace_dir, "**", "perfetto_trace.json.gz"), recursive=True)
        with gzip.open(path) as f:
            return [e for e in json.load(f)["traceEvents"] if e.get("ph") == "X"]


# (part, what its XLA operations' metadata contains), first match wins: the network parts of ToMacVF's update
PARTS = (
    ("agent GRU recurrence", ("TemporalAgentNet", "/while")),
    ("agent Dense fc + GRU input", ("TemporalAgentNet", "torso")),
    ("agent Q head", ("TemporalAgentNet", "head")),
    ("agent input features", ("TemporalAgentNet",)),
    ("ATPG temporal attention", ("atpg/temporal",)),
    ("ATPG agent attention", ("atpg/agents",)),
    ("ATPG tokens", ("atpg/",)),
    ("mixer hyper-networks", ("Mixer",)),
)
OTHER = "losses, targets, gathers, optimizer"


def part_of(op_name: str) -> str:
    for part, needles in PARTS:
        if all(needle in op_name for needle in needles):
            return part
    return OTHER


def part_gflop(config, env, rows_batch: int, rows_time: int) -> dict[str, float]:
    """Hand-counted GFLOP of one update per part: matmuls only (2 per multiply-add), counted once for the online
    forward, twice for its backward (the input and the weight gradients) and once for the target forward — 4
    forward passes. The causal attention is counted whole (T² per agent), as the reference implementation runs it.
    """
    from jaxmac.algos.tomacvf.model import network_configs

    agent, mixer = network_configs(config, env)
    n, h, a = agent.num_agents, agent.hidden, agent.num_actions
    rows = rows_batch * rows_time  # B·T rows, each with n agents
    d, hid, emb, s = mixer.embed, mixer.hyper_hidden, mixer.embed, mixer.state_dim
    atpg = mixer.atpg
    token_in = agent.feature_dim  # the token features have the agent features' width
    head_in = h + agent.encoding.dim_tm
    head = sum(i * o for i, o in zip((head_in,) + agent.head_hidden, agent.head_hidden + (a,)))
    fwd = {
        "agent GRU recurrence": rows * n * h * 3 * h,
        "agent Dense fc + GRU input": rows * n * (agent.feature_dim * agent.fc + agent.fc * 3 * h),
        "agent Q head": rows * n * head,
        "agent input features": 0,
        "ATPG tokens": rows * n * (token_in * atpg.token_hidden + atpg.token_hidden * d),
        "ATPG temporal attention": rows * n * 3 * d * d + rows_batch * n * rows_time ** 2 * d * 2,
        "ATPG agent attention": rows * n * 3 * d * d + rows * n * n * d * 2,
        "mixer hyper-networks": rows * (n * ((s + d) * hid + hid * emb) + (s + d) * hid + hid * emb
                                        + s * hid + hid * emb + s * hid + hid),
        OTHER: 0,
    }
    return {part: 4 * 2 * macs / 1e9 for part, macs in fwd.items()}


def print_roofline(update, update_args, config, env, rows_batch: int, rows_time: int, repeats: int) -> None:
    """Print the update's time per part (trace events attributed through the compiled HLO's metadata), the part's
    hand-counted GFLOP and the rate it runs at."""
    import collections
    import re
    import statistics
    import time

    import jax

    names = {}
    for line in update.lower(*update_args).compile().as_text().splitlines():
        m = re.match(r'\s*(?:ROOT )?%([\w.\-]+) = .*?metadata=\{op_name="([^"]+)"', line)
        if m:
            names[m.group(1)] = m.group(2)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(update(*update_args))
        times.append(time.perf_counter() - t0)
    total = 1000 * statistics.median(times)
    ms = collections.Counter()
    for event in trace_events(update, update_args, repeats):
        op = names.get(event["name"])
        # a loop's event spans its body's operations: count the body's (they carry the same part), not the loop
        if op is not None and not event["name"].startswith("while"):
            ms[part_of(op)] += event["dur"] / 1000 / repeats
    traced = sum(ms.values())
    gflop = part_gflop(config, env, rows_batch, rows_time)
    print(f"  roofline of the full-length update ({total:.1f} ms per update; {traced:.1f} ms of it in traced "
          f"operations; GFLOP hand-counted, matmuls of the online forward + backward + target forward):")
    print(f"    {'part':36s} {'GFLOP':>7s} {'ms':>7s} {'GFLOP/s':>8s} {'share':>6s}")
    for part in [p for p, _ in PARTS] + [OTHER]:
        rate = f"{gflop[part] / ms[part] * 1000:8.1f}" if gflop[part] and ms[part] else f"{'-':>8s}"
        print(f"    {part:36s} {gflop[part]:7.2f} {ms[part]:7.1f} {rate} {ms[part] / traced:6.1%}")
    all_gflop = sum(gflop.values())
    print(f"    {'all':36s} {all_gflop:7.2f} {traced:7.1f} {all_gflop / traced * 1000:8.1f} {1:6.0%}")


def op_kinds(fn, args, repeats: int) -> list[tuple[str, float]]:
    """[(operation kind, ms per call)], costliest first, from a ``jax.profiler`` trace of ``repeats`` calls of the
    jitted ``fn``: XLA's thunk names without their numbers (``ynn_fusion`` = XNNPACK matmul fusions, ``dot``,
    ``while`` = the scans, ``copy``/``transpose`` fusions = layout changes, ...)."""
    import collections
    import re

    events = trace_events(fn, args, repeats)
    kinds = collections.Counter()
    for e in events:
        if not e["name"].startswith(("Thunk", "$", "PjitFunction")):
            kinds[re.sub(r"[.\d]+$", "", e["name"])] += e["dur"] / 1000 / repeats
    return kinds.most_common()


if __name__ == "__main__":
    main()
