"""Measure what a sweep cell costs on this machine, to size the ``cpu`` protocol (``jaxmac calibrate``).

    taskset -c 0 jaxmac calibrate --pairs tomacvf@overcooked-B maccen_ddrqn@boxpushing-14x14
    taskset -c 0 jaxmac calibrate --experiment bp overcooked   # every (method, scenario)

For each (method, scenario) — a method is a sweep method name (``jaxmac.study.sweep``: ``tomacvf``, ``tomacvf-qplex``,
``tomacvf-wo-sjert``, ``mac_cac`` ...) — a child process compiles the method's training chunk for ``--seeds`` vmapped
seeds, fills the ring to where gradient steps run, and times ``--chunks`` chunks (as ``benchmarks/train_throughput.py``
measures). The training episodes per wall-second of all seeds go to ``--out`` (JSON, one entry per pair, kept
between calls: pairs already there are skipped; default experiments/protocol_rates.json under the current
directory, the file ``jaxmac sweep --dry-run`` reads by default). Run it held to one core (``taskset``) with nothing
else heavy on that core: the rate is then per core. The first chunks are the slow end of a run where episodes are
longest at the start (Box Pushing, Warehouse), so estimates from them are upper bounds there.

``--from-run METHOD@SCENARIO=RUN_DIR`` records instead the rate of a finished run folder trained with that
method's settings (seeds × episodes / wall time: a whole run, exploration included).

``--from-sweep SWEEP_DIR`` does that for every finished cell of a sweep folder (``jaxmac sweep``'s).

``jaxmac sweep EXPERIMENT --dry-run --rates FILE`` reads the file to estimate each cell's core-hours.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time

# relative to the current directory: the file `jaxmac sweep --rates` reads by default
DEFAULT_OUT = os.path.join("experiments", "protocol_rates.json")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``jaxmac calibrate``'s arguments (the CLI's subcommand and ``main`` share them)."""
    from jaxmac.study.sweep import EXPERIMENTS

    p.add_argument("--pairs", nargs="*", default=[], metavar="METHOD@SCENARIO",
                   help="(sweep method, scenario) pairs to time, e.g. tomacvf@overcooked-B")
    p.add_argument("--experiment", nargs="*", default=[], choices=list(EXPERIMENTS),
                   help="every (method, scenario) of these experiments")
    p.add_argument("--from-run", nargs="*", default=[], metavar="METHOD@SCENARIO=RUN_DIR",
                   help="record the whole-run rate of a finished run folder trained with the method's settings")
    p.add_argument("--from-sweep", metavar="SWEEP_DIR",
                   help="--from-run for every finished cell of a sweep folder (<scenario>/<method>/seeds<A>-<B>)")
    p.add_argument("--seeds", type=int, default=4, help="vmapped seeds of each timed pair (default 4)")
    p.add_argument("--chunks", type=int, default=1, help="chunks timed per pair after the warm-up (default 1)")
    p.add_argument("--out", default=DEFAULT_OUT,
                   help=f"the rates file, JSON, updated in place (default: {DEFAULT_OUT} under the current "
                        "directory, the file `jaxmac sweep --rates` reads by default)")


def measure_chunks(config, seeds: int, chunks: int) -> dict:
    """Compile ``config``'s training chunk for ``seeds`` vmapped seeds (fresh parameters), fill the ring until
    gradient steps run, then time ``chunks`` chunks in this process: compile seconds, wall and CPU seconds, training
    episodes and env steps of all seeds."""
    import jax
    import jax.numpy as jnp

    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.trainer import make_train

    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env))
    state = jax.jit(jax.vmap(trainer.init))(jax.vmap(jax.random.key)(jnp.arange(seeds)))
    return time_chunks(trainer, state, seeds, chunks)


def time_chunks(trainer, state, seeds: int, chunks: int, fill_ring: bool = True) -> dict:
    """Compile ``trainer.seeds_chunk`` for ``state`` (leaves ``[seeds, ...]``), run warm-up chunks — until the ring
    holds a batch and gradient steps run when ``fill_ring``, else one — then time ``chunks`` chunks: compile seconds,
    wall and CPU seconds, training episodes and env steps of all seeds."""
    import jax
    import numpy as np

    config = trainer.config
    t0 = time.perf_counter()
    chunk = jax.jit(trainer.seeds_chunk, donate_argnums=0).lower(state).compile()
    compile_s = time.perf_counter() - t0
    needed = config.start_train_episodes or config.batch_size
    warm = max(1, -(-needed // (config.num_envs * trainer.rounds_per_chunk)) + 1) if fill_ring else 1
    for _ in range(warm):
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


def _measure_child(request: str) -> None:
    """The child process of ``measure_in_child``: measure the JSON request, print the result as the last line."""
    import jaxmac.algos.registry  # noqa: F401  (registers every learner's settings, which from_dict reads)
    from jaxmac.config import TrainConfig

    values = json.loads(request)
    print(json.dumps(measure_chunks(TrainConfig.from_dict(values["config"]), values["seeds"], values["chunks"])))


def measure_in_child(config, seeds: int, chunks: int) -> dict:
    """``measure_chunks`` in a fresh child process (it inherits ``taskset``; nothing compiled before counts)."""
    request = json.dumps({"config": config.to_dict(), "seeds": seeds, "chunks": chunks})
    program = "import sys; from jaxmac.study.calibrate import _measure_child; _measure_child(sys.argv[1])"
    child = subprocess.run([sys.executable, "-c", program, request], stdout=subprocess.PIPE, text=True, check=False)
    if child.returncode != 0:
        raise RuntimeError(f"measuring {config.algorithm} on {config.scenario} failed with exit code "
                           f"{child.returncode}")
    return json.loads(child.stdout.strip().splitlines()[-1])


def measure_pair(method_name: str, scenario: str, seeds: int, chunks: int) -> dict:
    """A sweep method's rate on ``scenario`` (its settings as the sweep runs them), measured in a child process."""
    from jaxmac.study.sweep import method_by_name

    m = measure_in_child(method_by_name(method_name).config(scenario), seeds, chunks)
    return {"method": method_name, "scenario": scenario, "seeds": seeds, "chunks": chunks,
            "episodes_per_s": m["episodes"] / m["wall_s"], "episodes_per_cpu_s": m["episodes"] / m["cpu_s"],
            "env_steps_per_episode": m["env_steps"] / m["episodes"],
            "compile_s": m["compile_s"], "measured": time.strftime("%Y-%m-%d %H:%M")}


def rate_from_run(method_name: str, scenario: str, run_dir: str) -> dict:
    """The rate of a finished run folder, refused if it was trained with other settings than the method's (its
    budget, the schedules a protocol scales with it and the length buckets aside: buckets change the cost, not the
    result)."""
    from jaxmac.config import TrainConfig
    from jaxmac.study.sweep import SCHEDULE_SETTINGS, method_by_name

    with open(os.path.join(run_dir, "config.json")) as f:
        held = TrainConfig.from_dict(json.load(f)["config"])
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)
    wanted = method_by_name(method_name).config(scenario).run_settings()
    trained = held.run_settings()
    differ = {k: (trained.get(k), v) for k, v in wanted.items()
              if trained.get(k) != v and k not in ("episodes", "length_buckets") + SCHEDULE_SETTINGS}
    if differ:
        raise ValueError(f"{run_dir} was not trained with {method_name}'s settings on {scenario}: {differ}")
    note = "" if held.length_buckets == wanted["length_buckets"] else \
        f" (length_buckets={held.length_buckets} there, {wanted['length_buckets']} now)"
    return {"method": method_name, "scenario": scenario, "seeds": summary["seeds"],
            "episodes_per_s": summary["seeds"] * summary["episodes"] / summary["wall_seconds"],
            "source": f"{run_dir}: a whole run, seeds x episodes / wall time{note}"}


def sweep_cells(sweep_dir: str) -> list[str]:
    """``METHOD@SCENARIO=RUN_DIR`` of every finished cell of a sweep folder (one seed range per pair: the first)."""
    found = {}
    for summary in sorted(glob.glob(os.path.join(sweep_dir, "*", "*", "seeds*", "summary.json"))):
        run_dir = os.path.dirname(summary)
        method_dir, scenario_dir = os.path.dirname(run_dir), os.path.dirname(os.path.dirname(run_dir))
        found.setdefault(f"{os.path.basename(method_dir)}@{os.path.basename(scenario_dir)}", run_dir)
    if not found:
        raise ValueError(f"--from-sweep: no finished cell under {sweep_dir!r}")
    return [f"{key}={run_dir}" for key, run_dir in found.items()]


def save(rates: dict, path: str) -> None:
    """Write ``rates`` over the file's entries (another calibration may have added some meanwhile)."""
    if os.path.exists(path):
        with open(path) as f:
            rates = {**json.load(f), **rates}
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(dict(sorted(rates.items())), f, indent=1)
    os.replace(tmp, path)


def run(args: argparse.Namespace) -> int:
    """``jaxmac calibrate``: measure the pairs asked for, record the run folders' rates, into ``args.out``."""
    from jaxmac.study.sweep import plan

    pairs = []
    for text in args.pairs:
        method, sep, scenario = text.partition("@")
        if not sep:
            raise ValueError(f"--pairs expects METHOD@SCENARIO, got {text!r}")
        pairs.append((method, scenario))
    for experiment in args.experiment:
        pairs += [(c.method.name, c.scenario) for c in plan(experiment, "cpu")]
    from_run = list(args.from_run) + (sweep_cells(args.from_sweep) if args.from_sweep else [])
    if not pairs and not from_run:
        raise ValueError("nothing to measure: give --pairs, --experiment, --from-run or --from-sweep")
    rates = {}
    if os.path.exists(args.out):
        with open(args.out) as f:
            rates = json.load(f)
    for text in from_run:
        key, sep, run_dir = text.partition("=")
        method, _, scenario = key.partition("@")
        if not sep or not scenario:
            raise ValueError(f"--from-run expects METHOD@SCENARIO=RUN_DIR, got {text!r}")
        rates[key] = rate_from_run(method, scenario, run_dir)
        print(f"{key}: {rates[key]['episodes_per_s']:.2f} episodes/s ({rates[key]['source']})")
        save(rates, args.out)
    for method, scenario in dict.fromkeys(pairs):
        key = f"{method}@{scenario}"
        if key in rates:
            print(f"{key}: {rates[key]['episodes_per_s']:.2f} episodes/s (kept)")
            continue
        rates[key] = measure_pair(method, scenario, args.seeds, args.chunks)
        print(f"{key}: {rates[key]['episodes_per_s']:.2f} episodes/s over {args.seeds} seeds "
              f"({rates[key]['env_steps_per_episode']:.0f} steps per episode), compile {rates[key]['compile_s']:.0f} s",
              flush=True)
        save(rates, args.out)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``jaxmac calibrate ARGS`` from Python."""
    p = argparse.ArgumentParser(prog="jaxmac calibrate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))
