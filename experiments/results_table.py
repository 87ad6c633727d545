"""A Markdown results table from finished run folders (their ``summary.json`` and ``config.json``).

    python experiments/results_table.py RUN_DIR [RUN_DIR ...]

One row per run: scenario, algorithm, seeds, episodes per seed, final greedy discounted return (mean ± standard error
over seeds, and the per-seed values), the optimal return where known, the fraction of it reached, the
settings that differ from the scenario's defaults, and the run's wall time.
"""

from __future__ import annotations

import argparse
import json
import pathlib

from jaxmac.config import TrainConfig, scenario_config
from jaxmac.plotting import mean_and_standard_error


def _changed_settings(run_dir: pathlib.Path, scenario: str) -> str:
    """``key=value`` for every config field that differs from the scenario's defaults of the run's algorithm
    (episodes and length_buckets aside)."""
    config = TrainConfig.from_dict(json.loads((run_dir / "config.json").read_text())["config"])
    resolved = config.flat_dict()
    defaults = scenario_config(scenario, config.algorithm).flat_dict()
    ignored = {"episodes", "length_buckets", "packing"}  # the budget is its own column; these change the speed only
    changed = [f"{k}={v}" for k, v in resolved.items() if k in defaults and k not in ignored and defaults[k] != v]
    return ", ".join(changed) or "defaults"


def table_rows(run_dirs: list[pathlib.Path]) -> list[str]:
    header = ("| scenario | algorithm | seeds | episodes/seed | final greedy return (mean ± s.e.) | per seed | optimal | "
              "reached | settings | wall time |")
    rows = [header,
            "|---|---|---|---|---|---|---|---|---|---|"]
    for run_dir in run_dirs:
        summary = json.loads((run_dir / "summary.json").read_text())
        values = summary["final_greedy_return"]
        mean, se = mean_and_standard_error(values)
        se = "–" if se is None else f"{se:.1f}"
        optimal = summary.get("optimal_return")
        reached = f"{mean / optimal:.0%}" if optimal else "–"
        per_seed = " ".join(f"{v:.1f}" for v in values)
        rows.append(f"| {summary['scenario']} | {summary.get('algorithm', 'tomacvf')} | {summary['seeds']} | {summary['episodes']:,} | {mean:.1f} ± {se} | "
                    f"{per_seed} | {optimal if optimal else '–'} | {reached} | "
                    f"{_changed_settings(run_dir, summary['scenario'])} | {summary['wall_seconds'] / 60:.0f} min |")
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=pathlib.Path, help="finished run folders")
    args = p.parse_args(argv)
    missing = [str(r) for r in args.runs if not (r / "summary.json").is_file()]
    if missing:
        raise SystemExit(f"no summary.json (run not finished?) in: {', '.join(missing)}")
    print("\n".join(table_rows(args.runs)))


if __name__ == "__main__":
    main()
