"""Measure what a sweep cell costs on this machine, to size the ``cpu`` protocol.

    taskset -c 0 python experiments/calibrate_protocol.py --pairs tomacvf@overcooked-B maccen_ddrqn@boxpushing-14x14
    taskset -c 0 python experiments/calibrate_protocol.py --experiment bp overcooked   # every (method, scenario)

For each (method, scenario) — a method is a sweep method name (``jaxmac.study.sweep``: ``tomacvf``, ``tomacvf-qplex``,
``tomacvf-wo-sjert``, ``mac_cac`` ...) — one process compiles the method's training chunk for ``--seeds`` vmapped
seeds, fills the ring to where gradient steps run, and times ``--chunks`` chunks (``benchmarks/train_throughput.py``'s
measurement). The training episodes per wall-second of all seeds go to ``--out`` (JSON, one entry per pair, kept
between calls: pairs already there are skipped). Run it held to one core (``taskset``) with nothing else heavy on that
core: the rate is then per core. The first chunks are the slow end of a run where episodes are longest at the start
(Box Pushing, Warehouse), so estimates from them are upper bounds there.

``--from-run METHOD@SCENARIO=RUN_DIR`` records instead the rate of a finished run folder trained with that
method's settings (seeds × episodes / wall time: a whole run, exploration included).

``--from-sweep SWEEP_DIR`` does that for every finished cell of a sweep folder (``jaxmac sweep``'s).

``jaxmac sweep EXPERIMENT --dry-run`` reads the file to estimate each cell's core-hours.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks"))

DEFAULT_OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "protocol_rates.json")


def method_assignments(method, scenario: str) -> list[str]:
    """A sweep method's overrides on ``scenario`` as ``--set`` strings."""
    return [f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in method.overrides_for(scenario).items()]


def measure_pair(method_name: str, scenario: str, seeds: int, chunks: int) -> dict:
    from train_throughput import run_workers

    from jaxmac.study.sweep import method_by_name

    method = method_by_name(method_name)
    (m,) = run_workers(method.algorithm, scenario, seeds, 1, chunks, method_assignments(method, scenario))
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
    wanted = method_by_name(method_name).config(scenario).flat_dict()
    differ = {k: (held.flat_dict().get(k), v) for k, v in wanted.items()
              if held.flat_dict().get(k) != v and k not in ("episodes", "length_buckets") + SCHEDULE_SETTINGS}
    if differ:
        raise SystemExit(f"{run_dir} was not trained with {method_name}'s settings on {scenario}: {differ}")
    note = "" if held.length_buckets == wanted["length_buckets"] else \
        f" (length_buckets={held.length_buckets} there, {wanted['length_buckets']} now)"
    return {"method": method_name, "scenario": scenario, "seeds": summary["seeds"],
            "episodes_per_s": summary["seeds"] * summary["episodes"] / summary["wall_seconds"],
            "source": f"{run_dir}: a whole run, seeds x episodes / wall time{note}"}


def main(argv=None) -> None:
    from jaxmac.study.sweep import EXPERIMENTS, plan

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--pairs", nargs="*", default=[], metavar="METHOD@SCENARIO")
    p.add_argument("--experiment", nargs="*", default=[], choices=list(EXPERIMENTS),
                   help="every (method, scenario) of these experiments")
    p.add_argument("--from-run", nargs="*", default=[], metavar="METHOD@SCENARIO=RUN_DIR")
    p.add_argument("--from-sweep", metavar="SWEEP_DIR",
                   help="--from-run for every finished cell of a sweep folder (<scenario>/<method>/seeds<A>-<B>)")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--chunks", type=int, default=1)
    p.add_argument("--out", default=DEFAULT_OUT)
    args = p.parse_args(argv)
    pairs = []
    for text in args.pairs:
        method, sep, scenario = text.partition("@")
        if not sep:
            raise SystemExit(f"--pairs expects METHOD@SCENARIO, got {text!r}")
        pairs.append((method, scenario))
    for experiment in args.experiment:
        pairs += [(c.method.name, c.scenario) for c in plan(experiment, "cpu")]
    if args.from_sweep:
        args.from_run += sweep_cells(args.from_sweep)
    if not pairs and not args.from_run:
        raise SystemExit("nothing to measure: give --pairs, --experiment, --from-run or --from-sweep")
    rates = {}
    if os.path.exists(args.out):
        with open(args.out) as f:
            rates = json.load(f)
    for text in args.from_run:
        key, sep, run_dir = text.partition("=")
        method, _, scenario = key.partition("@")
        if not sep or not scenario:
            raise SystemExit(f"--from-run expects METHOD@SCENARIO=RUN_DIR, got {text!r}")
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


def sweep_cells(sweep_dir: str) -> list[str]:
    """``METHOD@SCENARIO=RUN_DIR`` of every finished cell of a sweep folder (one seed range per pair: the first)."""
    found = {}
    for summary in sorted(glob.glob(os.path.join(sweep_dir, "*", "*", "seeds*", "summary.json"))):
        run_dir = os.path.dirname(summary)
        method_dir, scenario_dir = os.path.dirname(run_dir), os.path.dirname(os.path.dirname(run_dir))
        found.setdefault(f"{os.path.basename(method_dir)}@{os.path.basename(scenario_dir)}", run_dir)
    if not found:
        raise SystemExit(f"--from-sweep: no finished cell under {sweep_dir!r}")
    return [f"{key}={run_dir}" for key, run_dir in found.items()]


def save(rates: dict, path: str) -> None:
    """Write ``rates`` over the file's entries (another calibration may have added some meanwhile)."""
    if os.path.exists(path):
        with open(path) as f:
            rates = {**json.load(f), **rates}
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(dict(sorted(rates.items())), f, indent=1)
    os.replace(tmp, path)


if __name__ == "__main__":
    main()
