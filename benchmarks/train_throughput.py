"""Training throughput of the compiled trainer for any learner, per seed and in total.

    python benchmarks/train_throughput.py [--algorithm tomacvf] --scenario boxpushing-6x6 [--seeds 1 4 8]
                                          [--workers 1 2] [--chunks 3] [--set KEY=VALUE ...]

For every (seeds, workers) pair, each worker process compiles ``Trainer.seeds_chunk`` over its
share of the seeds (compile time reported apart) and then times ``--chunks`` chunks of the
scenario's configuration of that algorithm (warm-up chunks first fill the ring up to where
gradient steps run). Printed: training episodes/s and env steps/s per seed and in total, wall and
per CPU-second, and the ratio to the original implementation's recorded speed per CPU-second of
all its processes (BASELINES.md §4, measured on this machine kind): the same learner where the
original has it, Mac-IAICC (the fastest original) for ToMacVF.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

# The originals' recorded speed (BASELINES.md §4): (episodes/CPU-s, env steps/CPU-s, which original).
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


def measure(algorithm: str, scenario: str, seeds: int, seed_offset: int, chunks: int, assignments: list[str]) -> dict:
    """Compile and time the trainer in this process (one worker)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxmac.algos import make_algorithm
    from jaxmac.config import make_env, scenario_config
    from jaxmac.trainer import make_train

    config = scenario_config(scenario, algorithm).override_strings(assignments)
    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env))
    keys = jax.vmap(jax.random.key)(jnp.arange(seed_offset, seed_offset + seeds))
    state = jax.jit(jax.vmap(trainer.init))(keys)
    t0 = time.perf_counter()
    chunk = jax.jit(trainer.seeds_chunk, donate_argnums=0).lower(state).compile()
    compile_s = time.perf_counter() - t0
    needed = config.start_train_episodes or config.batch_size
    warm = max(1, -(-needed // (config.num_envs * trainer.rounds_per_chunk)) + 1)
    for _ in range(warm):  # fill the ring so that gradient steps really run
        state, _ = chunk(state)
    episodes = steps = 0
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(chunks):
        state, m = chunk(state)
        m = jax.device_get(m)
        episodes += seeds * trainer.rounds_per_chunk * config.num_envs
        steps += int(np.sum(m["train_length"]) * config.num_envs)
    return {"compile_s": compile_s, "wall_s": time.perf_counter() - w0, "cpu_s": time.process_time() - c0,
            "episodes": episodes, "env_steps": steps}


def run_workers(algorithm: str, scenario: str, seeds: int, workers: int, chunks: int,
                assignments: list[str]) -> list[dict]:
    """``workers`` concurrent processes, each measuring its share of the seeds."""
    share = [seeds // workers + (k < seeds % workers) for k in range(workers)]
    offsets = [sum(share[:k]) for k in range(workers)]
    procs = [subprocess.Popen([sys.executable, __file__, "--child", algorithm, scenario, str(s), str(o), str(chunks),
                              json.dumps(assignments)],
                              stdout=subprocess.PIPE, text=True) for s, o in zip(share, offsets) if s > 0]
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
        print(json.dumps(measure(algorithm, scenario, seeds, offset, chunks, json.loads(sys.argv[7]))))
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    from jaxmac.algos import REGISTRY

    p.add_argument("--algorithm", default="tomacvf", choices=list(REGISTRY))
    p.add_argument("--scenario", default="boxpushing-6x6")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 4, 8])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--chunks", type=int, default=3, help="timed chunks per worker (after compile and warm-up)")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="KEY=VALUE",
                   help="config override, as in `jaxmac train --set` (repeatable)")
    args = p.parse_args(argv)
    from jaxmac.config import scenario_config

    scenario_config(args.scenario, args.algorithm).override_strings(args.assignments)  # bad values fail here
    ref = ORIGINAL.get(args.algorithm, {}).get(args.scenario)
    setting = ", ".join(args.assignments) or "the scenario's configuration"
    print(f"{args.scenario}: {args.algorithm}, {setting}; rates over the timed chunks (compile apart)")
    print(f"{'seeds':>5} {'workers':>7} {'compile s':>9} {'ep/s total':>10} {'ep/s/seed':>9} {'steps/s':>9} "
          f"{'ep/CPU-s':>9}" + ("  vs original (episodes per CPU-second)" if ref else ""))
    for seeds in args.seeds:
        for workers in args.workers:
            if workers > seeds:
                continue
            res = run_workers(args.algorithm, args.scenario, seeds, workers, args.chunks, args.assignments)
            wall = max(r["wall_s"] for r in res)
            episodes = sum(r["episodes"] for r in res)
            steps = sum(r["env_steps"] for r in res)
            cpu = sum(r["cpu_s"] for r in res)
            line = (f"{seeds:>5} {workers:>7} {max(r['compile_s'] for r in res):>9.1f} {episodes / wall:>10.1f} "
                    f"{episodes / wall / seeds:>9.2f} {steps / wall:>9.0f} {episodes / cpu:>9.1f}")
            if ref:
                line += f"  {episodes / cpu / ref[0]:.2f}x ({ref[0]} for the original {ref[2]})"
            print(line, flush=True)


if __name__ == "__main__":
    main()
