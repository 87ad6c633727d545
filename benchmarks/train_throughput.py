"""Training throughput of the compiled trainer for any learner, per seed and in total.

    python benchmarks/train_throughput.py [--algorithm tomacvf] --scenario boxpushing-6x6 [--seeds 1 4 8]
                                          [--workers 1 2] [--devices 2] [--chunks 3] [--set KEY=VALUE ...]

For every (seeds, workers) pair (several workers each held to a core of its own), and every (seeds, devices) pair
of one process whose seeds are sharded over that many host devices (``jax.sharding``, the way that carries to GPUs
and hosts), each worker process compiles ``Trainer.seeds_chunk`` over its share of the seeds (compile time reported
apart) and then times ``--chunks`` chunks of the scenario's configuration of that algorithm (warm-up chunks first fill the ring up to where
gradient steps run). Printed: training episodes/s and env steps/s per seed and in total, wall and
per CPU-second, and the ratio to the original implementation's recorded speed per CPU-second of
all its processes (docs/baselines.md §4, measured on this machine kind): the same learner where the
original has it, Mac-IAICC (the fastest original) for ToMacVF.

    python benchmarks/train_throughput.py --compare [--algorithm tomacvf] [--scenario S ...] [--from-run RUN ...]

``--compare`` times, for each scenario, the reference path (the update always on the full horizon: no length buckets,
no packing) and the new path (the scenario's length buckets, and packing for ToMacVF) one after the other, each in
its own process on one seed, and prints episodes per CPU-second of both and their ratio. Fresh parameters (ε near
its start, the longest episodes) unless ``--from-run`` names, per scenario, a run folder whose newest checkpoint
(its first seed: trained parameters, replay ring and ε) both paths continue from.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

# The originals' recorded speed (docs/baselines.md §4): (episodes/CPU-s, env steps/CPU-s, which original).
ORIGINAL = {
    "tomacvf": {"boxpushing-6x6": (37.133, 875.7, "Mac-IAICC"), "overcooked-A": (2.719, 546.8, "Mac-IAICC")},
    "maccen_ddrqn": {"boxpushing-6x6": (5.176, 133.8, "MacCen-Q"), "overcooked-A": (0.577, 115.8, "MacCen-Q")},
    "macdec_ddrqn": {"boxpushing-6x6": (1.879, 63.3, "MacDec-DDRQN"), "overcooked-A": (0.565, 113.0, "MacDec-DDRQN")},
    "macdec_q": {"boxpushing-6x6": (11.876, 288.2, "MacDec-Q"), "overcooked-A": (0.782, 157.7, "MacDec-Q")},
    "mac_iaicc": {"boxpushing-6x6": (37.133, 875.7, "Mac-IAICC"), "overcooked-A": (2.719, 546.8, "Mac-IAICC")},
    # no recorded rate of the originals' Mac-NIACC / Mac-CAC: Mac-IAICC's, whose runner and update they share
    "mac_niacc": {"boxpushing-6x6": (37.133, 875.7, "Mac-IAICC"), "overcooked-A": (2.719, 546.8, "Mac-IAICC")},
    "mac_cac": {"boxpushing-6x6": (37.133, 875.7, "Mac-IAICC"), "overcooked-A": (2.719, 546.8, "Mac-IAICC")},
}


# The two paths of --compare: the update on the full horizon, and on the batch's real lengths (the scenario's own
# settings: packed episodes).
REFERENCE_PATH = {"tomacvf": ["length_buckets=1", "packing=false"]}
NEW_PATH = {"tomacvf": []}


def measure(algorithm: str, scenario: str, seeds: int, seed_offset: int, chunks: int, assignments: list[str],
            run_dir: str | None = None, devices: int = 1) -> dict:
    """Compile and time the trainer in this process (one worker); with ``run_dir``, continue from that run's newest
    checkpoint (its first ``seeds`` seeds; ``algorithm``, ``scenario`` and ``seed_offset`` are then the run's)."""
    import jax
    import jax.numpy as jnp

    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.presets import scenario_config
    from jaxmac.study.calibrate import time_chunks
    from jaxmac.trainer import make_train

    if run_dir is None:
        config = scenario_config(scenario, algorithm).override_strings(assignments)
        rounds_per_chunk = None
    else:
        from jaxmac.runs import load_run

        run_trainer, run_state, _, _ = load_run(run_dir)
        config = run_trainer.config.override_strings(assignments)
        if (config.scenario, config.algorithm) != (scenario, algorithm):
            raise SystemExit(f"{run_dir} is a run of {config.algorithm} on {config.scenario}, not {algorithm} on "
                             f"{scenario}")
        rounds_per_chunk = run_trainer.rounds_per_chunk
    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env), rounds_per_chunk)
    if run_dir is None:
        keys = jax.vmap(jax.random.key)(jnp.arange(seed_offset, seed_offset + seeds))
        state = jax.jit(jax.vmap(trainer.init))(keys)
    else:
        state = jax.tree_util.tree_map(lambda x: x[:seeds], run_state)
    if devices > 1:
        from jaxmac.runs import seed_sharding

        state = jax.device_put(state, seed_sharding(seeds, devices))
    # a run's state has a full ring already: one warm-up chunk
    return time_chunks(trainer, state, seeds, chunks, fill_ring=run_dir is None)


def run_workers(algorithm: str, scenario: str, seeds: int, workers: int, chunks: int,
                assignments: list[str], run_dir: str | None = None, devices: int = 1) -> list[dict]:
    """``workers`` concurrent processes, each measuring its share of the seeds (sharded over ``devices`` host
    devices of its own); several workers are each held to one core (``taskset``, round robin over the cores this
    process may use)."""
    from jaxmac.runs.workers import split_seeds

    import os

    cores = sorted(os.sched_getaffinity(0))
    # each of several workers held to a core of its own (as `jaxmac sweep` runs on a 2-core machine: one process
    # per core), so that their XLA thread pools do not share the cores
    pin = (lambda k: ["taskset", "-c", str(cores[k % len(cores)])]) if workers > 1 else (lambda k: [])
    procs = [subprocess.Popen(pin(k) + [sys.executable, __file__, "--child", algorithm, scenario, str(s), str(o),
                                        str(chunks), json.dumps(assignments), run_dir or "", str(devices)],
                              stdout=subprocess.PIPE, text=True) for k, (o, s) in enumerate(split_seeds(seeds, workers))]
    out = []
    for p in procs:
        stdout, _ = p.communicate()
        if p.returncode != 0:
            raise RuntimeError(f"worker failed with exit code {p.returncode}")
        out.append(json.loads(stdout.strip().splitlines()[-1]))
    return out


def main(argv=None) -> None:
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "--child":
        algorithm, scenario = sys.argv[2], sys.argv[3]
        seeds, offset, chunks = int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6])
        from jaxmac.runs import use_host_devices

        use_host_devices(int(sys.argv[9]))  # before JAX starts
        print(json.dumps(measure(algorithm, scenario, seeds, offset, chunks, json.loads(sys.argv[7]),
                                 sys.argv[8] or None, int(sys.argv[9]))))
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    from jaxmac.algos.registry import REGISTRY

    p.add_argument("--algorithm", default="tomacvf", choices=list(REGISTRY))
    p.add_argument("--scenario", nargs="+", default=["boxpushing-6x6"],
                   help="one scenario (several with --compare)")
    p.add_argument("--compare", action="store_true",
                   help="the reference path (full horizon) against the new path (real lengths), one seed each")
    p.add_argument("--from-run", nargs="+", default=None, metavar="RUN_DIR",
                   help="with --compare: per scenario, a run folder whose newest checkpoint both paths continue from")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 4, 8])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--devices", type=int, nargs="+", default=[1],
                   help="host devices one process shards its seeds over (jax.sharding), against --workers processes")
    p.add_argument("--chunks", type=int, default=3, help="timed chunks per worker (after compile and warm-up)")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="KEY=VALUE",
                   help="config override, as in `jaxmac train --set` (repeatable)")
    args = p.parse_args(argv)
    from jaxmac.presets import scenario_config

    for scenario in args.scenario:
        scenario_config(scenario, args.algorithm).override_strings(args.assignments)  # bad values fail here
    if args.compare:
        compare(args)
        return
    if len(args.scenario) != 1 or args.from_run:
        p.error("several scenarios and --from-run go with --compare only")
    args.scenario = args.scenario[0]
    ref = ORIGINAL.get(args.algorithm, {}).get(args.scenario)
    setting = ", ".join(args.assignments) or "the scenario's configuration"
    print(f"{args.scenario}: {args.algorithm}, {setting}; rates over the timed chunks (compile apart)")
    print(f"{'seeds':>5} {'workers':>7} {'devices':>7} {'compile s':>9} {'ep/s total':>10} {'ep/s/seed':>9} {'steps/s':>9} "
          f"{'ep/CPU-s':>9}" + ("  vs original (episodes per CPU-second)" if ref else ""))
    combos = [(w, 1) for w in args.workers] + [(1, d) for d in args.devices if d > 1]
    for seeds in args.seeds:
        for workers, devices in combos:
            if workers > seeds or seeds % devices:
                continue
            res = run_workers(args.algorithm, args.scenario, seeds, workers, args.chunks, args.assignments,
                              devices=devices)
            wall = max(r["wall_s"] for r in res)
            episodes = sum(r["episodes"] for r in res)
            steps = sum(r["env_steps"] for r in res)
            cpu = sum(r["cpu_s"] for r in res)
            line = (f"{seeds:>5} {workers:>7} {devices:>7} {max(r['compile_s'] for r in res):>9.1f} {episodes / wall:>10.1f} "
                    f"{episodes / wall / seeds:>9.2f} {steps / wall:>9.0f} {episodes / cpu:>9.1f}")
            if ref:
                line += f"  {episodes / cpu / ref[0]:.2f}x ({ref[0]} for the original {ref[2]})"
            print(line, flush=True)


def compare(args) -> None:
    """The reference path against the new path per scenario (see the module docstring)."""
    if args.algorithm not in NEW_PATH:
        raise SystemExit(f"--compare: no new path for algorithm={args.algorithm!r}; algorithms with one: "
                         f"{list(NEW_PATH)}")
    runs = args.from_run or [None] * len(args.scenario)
    if len(runs) != len(args.scenario):
        raise SystemExit(f"--from-run names {len(runs)} runs for {len(args.scenario)} scenarios: give one per scenario")
    seeds = args.seeds[0] if args.seeds != [1, 4, 8] else 1
    print(f"{args.algorithm}: reference path ({' '.join(REFERENCE_PATH[args.algorithm])}) against the new path "
          f"({' '.join(NEW_PATH[args.algorithm]) or 'the scenario settings'}); {seeds} seed(s), {args.chunks} timed chunks each, one process at a "
          f"time; extra settings: {' '.join(args.assignments) or 'none'}")
    print(f"{'scenario':<16} {'from':<10} {'mean length':>11} {'ref ep/CPU-s':>12} {'new ep/CPU-s':>12} {'new/ref':>8}")
    for scenario, run_dir in zip(args.scenario, runs):
        rates, lengths = [], []
        for path in (REFERENCE_PATH, NEW_PATH):
            (res,) = run_workers(args.algorithm, scenario, seeds, 1, args.chunks,
                                 args.assignments + path[args.algorithm], run_dir)
            rates.append(res["episodes"] / res["cpu_s"])
            lengths.append(res["env_steps"] / res["episodes"])
        print(f"{scenario:<16} {'fresh' if run_dir is None else 'its run':<10} {sum(lengths) / 2:>11.1f} "
              f"{rates[0]:>12.2f} {rates[1]:>12.2f} {rates[1] / rates[0]:>7.2f}x", flush=True)


if __name__ == "__main__":
    main()
