"""How close the committed runs' value estimates came to the divergence guard's bound, and how those runs ended.

For every run folder under ``experiments/`` whose ``metrics.csv`` has a value metric (``q_tot_mean``,
``cen_q_mean``, ``dec_q_mean``), each seed's highest per-round value over the env's upper value bound without the
margin (``envs_jax.core.value_bounds``) beside its last greedy evaluation. This measured the guard's default
``divergence_margin`` (docs/tomacvf-settings.md, "The divergence guard").

    python experiments/analysis/value_bound_survey.py [--top 25] [ROOT]
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import math
import os

import envs_jax
from envs_jax.core import value_bounds
from jaxmac.runs.divergence import VALUE_METRICS


def seed_peaks(run_dir: str) -> list[tuple[float, str, float, float, float | None]]:
    """(peak / bound, seed, peak, bound, last evaluation) per seed of one run folder; [] when it has no value
    metric or its config.json is missing."""
    try:
        with open(os.path.join(run_dir, "config.json")) as f:
            scenario = json.load(f)["config"]["scenario"]
    except (OSError, KeyError, ValueError):
        return []
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        rows = list(csv.DictReader(f))
    names = [k for k in VALUE_METRICS if rows and k in rows[0]]
    if not names:
        return []
    env = envs_jax.make(scenario)
    _, high = value_bounds(env.reward_bounds(), env.spec.discount, env.spec.horizon)
    peak: dict[str, float] = {}
    last: dict[str, float] = {}
    for row in rows:
        for name in names:
            value = float(row[name] or "nan")
            if not math.isnan(value):
                peak[row["seed"]] = max(peak.get(row["seed"], -math.inf), value)
        evaluation = row.get("eval_return") or "nan"
        if not math.isnan(float(evaluation)):
            last[row["seed"]] = float(evaluation)
    return [(v / high, seed, v, high, last.get(seed)) for seed, v in peak.items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", nargs="?", default="experiments")
    parser.add_argument("--top", type=int, default=25, help="rows to print, highest peak first")
    args = parser.parse_args()
    table = []
    for metrics in sorted(glob.glob(os.path.join(args.root, "**", "metrics.csv"), recursive=True)):
        run_dir = os.path.dirname(metrics)
        table += [(ratio, run_dir, seed, v, high, ev) for ratio, seed, v, high, ev in seed_peaks(run_dir)]
    table.sort(key=lambda row: row[0], reverse=True)
    print(f"{len(table)} seeds with a value metric; highest per-round value / the bound without margin:")
    print("| peak / bound | run | seed | peak | bound | last evaluation |\n|---|---|---|---|---|---|")
    for ratio, run_dir, seed, v, high, ev in table[: args.top]:
        print(f"| {ratio:.3f} | {run_dir} | {seed} | {v:.1f} | {high:.0f} | {'–' if ev is None else f'{ev:.1f}'} |")


if __name__ == "__main__":
    main()
