"""ToMacVF's full-length update in this checkout against a base commit: milliseconds, ratio and equality.

    python benchmarks/update_compare.py --base COMMIT [--scenario overcooked-A warehouse-A boxpushing-6x6]
                                        [--repeats 7] [--rounds 1] [--cores 0]

The base commit is checked out into a temporary ``git worktree``. For each scenario and round, one process per tree
(base first, then this checkout), held to the cores of ``--cores`` (``taskset``), collects the same batch (its
scenario's ``batch_size`` episodes at ε = 1: uniformly random available actions, whatever the parameters) and times
``jax.jit(algorithm.update)`` on it at the full length (``length_buckets=1``; median of ``--repeats`` calls after
compiling). Printed per scenario: both medians, base / new, and the largest relative difference between the two
trees' updated parameters and loss terms (the same math: float rounding only). Run it with nothing else on the
cores it uses.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

WORKER = r'''
import json, statistics, sys, time
import jax, jax.numpy as jnp, numpy as np
from jaxmac.algos.base import Progress
from jaxmac.algos.registry import make_algorithm
from jaxmac.buffer.episode import write_episode
from jaxmac.collect import run_episodes_first_finished
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.trainer import make_train

scenario, out, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3])
config = scenario_config(scenario, "tomacvf").override(length_buckets=1)
env = make_env(config)
algorithm = make_algorithm(config, env)
trainer = make_train(config, env, algorithm)
state = jax.jit(trainer.init)(jax.random.key(0))
count = config.batch_size

@jax.jit
def collect(params, key):
    reset_ts, traj = run_episodes_first_finished(env, algorithm.act, algorithm.init_carry, params, key, 1.0, count,
                                                 count)
    return jax.vmap(write_episode, in_axes=(None, 0, 0))(trainer.slot_config, reset_ts, traj)

batch = collect(state.params, jax.random.key(1))
zero = jnp.zeros((), jnp.int32)
args = (state.params, state.target_params, state.opt_state, batch, jax.random.key(2), Progress(zero, zero, zero))
update = jax.jit(algorithm.update)
params, _, metrics = jax.block_until_ready(update(*args))
times = []
for _ in range(repeats):
    start = time.perf_counter()
    jax.block_until_ready(update(*args))
    times.append(time.perf_counter() - start)
leaves = {jax.tree_util.keystr(k): np.asarray(v) for k, v in jax.tree_util.tree_leaves_with_path(params)}
leaves |= {"metric " + k: np.asarray(v) for k, v in metrics.items()}
np.savez(out, **leaves)
print(json.dumps({"ms": 1000 * statistics.median(times)}))
'''


def run_worker(tree: str, scenario: str, out: str, repeats: int, cores: str) -> float:
    env = dict(os.environ, PYTHONPATH=tree)
    cmd = ["taskset", "-c", cores, sys.executable, "-c", WORKER, scenario, out, str(repeats)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tree)
    if done.returncode != 0:
        raise RuntimeError(f"the {scenario} update of {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])["ms"]


def largest_difference(path_a: str, path_b: str) -> tuple[float, str]:
    import numpy as np

    a, b = np.load(path_a), np.load(path_b)
    if set(a) != set(b):
        raise RuntimeError(f"the two trees' updates have different parameters: {sorted(set(a) ^ set(b))[:5]}")
    return max((float(np.max(np.abs(a[k] - b[k])) / max(float(np.max(np.abs(a[k]))), 1e-6)), k) for k in a)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--base", required=True, help="the commit to compare against (any git revision)")
    p.add_argument("--scenario", nargs="+", default=["overcooked-A", "warehouse-A", "boxpushing-6x6"])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--rounds", type=int, default=1, help="base/new pairs per scenario, interleaved")
    p.add_argument("--cores", default="0", help="taskset's core list for every process (default: core 0)")
    args = p.parse_args(argv)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with tempfile.TemporaryDirectory() as tmp:
        base = os.path.join(tmp, "base")
        subprocess.run(["git", "-C", here, "worktree", "add", "--detach", base, args.base], check=True,
                       capture_output=True)
        try:
            print(f"ToMacVF's full-length update, ms (median of {args.repeats}); base {args.base}, new {here}")
            for scenario in args.scenario:
                base_ms, new_ms = [], []
                for r in range(args.rounds):
                    base_ms.append(run_worker(base, scenario, os.path.join(tmp, f"base{r}.npz"), args.repeats,
                                              args.cores))
                    new_ms.append(run_worker(here, scenario, os.path.join(tmp, f"new{r}.npz"), args.repeats,
                                             args.cores))
                diff, where = largest_difference(os.path.join(tmp, "base0.npz"), os.path.join(tmp, "new0.npz"))
                b, n = min(base_ms), min(new_ms)
                print(f"  {scenario:16s} base {b:7.1f}  new {n:7.1f}  base/new {b / n:5.2f}x   largest relative "
                      f"difference {diff:.1e} ({where})")
        finally:
            subprocess.run(["git", "-C", here, "worktree", "remove", "--force", base], capture_output=True)


if __name__ == "__main__":
    main()
