"""A Markdown results table from finished run folders (their ``summary.json`` and ``config.json``).

    jaxmac table RUN_DIR [RUN_DIR ...]

One row per run: scenario, algorithm, seeds, episodes per seed, final greedy discounted return (mean ± standard error
over seeds, and the per-seed values), the optimal return where known, the fraction of it reached, the
settings that differ from the scenario's defaults, the run's wall time, and — where the scenario has a ceiling
(``jaxmac.scenarios.CEILINGS``) — the final return as the results pages measure it (the mean of each seed's last 10
evaluations, undiscounted on Warehouse) and the episodes each seed needed to reach 90 % of the ceiling
(``jaxmac.study.stats.episodes_to_fraction``; "–" for a seed that never did).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from jaxmac.config import TrainConfig
from jaxmac.plotting import mean_and_standard_error
from jaxmac.presets import scenario_config
from jaxmac.scenarios import CEILINGS
from jaxmac.study.stats import episodes_to_fraction, final_returns, load_run_result, reach_summary


def _changed_settings(run_dir: pathlib.Path, scenario: str) -> str:
    """``key=value`` for every config field that differs from the scenario's defaults of the run's algorithm
    (episodes, length_buckets, packing and the divergence guard's settings aside: ``TrainConfig.run_settings``)."""
    config = TrainConfig.from_dict(json.loads((run_dir / "config.json").read_text())["config"])
    resolved = config.run_settings()
    defaults = scenario_config(scenario, config.algorithm).run_settings()
    ignored = {"episodes", "length_buckets", "packing"}  # the budget is its own column; these change the speed only
    changed = [f"{k}={v}" for k, v in resolved.items() if k in defaults and k not in ignored and defaults[k] != v]
    return ", ".join(changed) or "defaults"


def _efficiency(run_dir: pathlib.Path, scenario: str) -> str:
    """"last-10 means (their mean, % of ceiling) | episodes to 90 % per seed (mean over the seeds that got there)"."""
    ceiling = CEILINGS.get(scenario)
    if ceiling is None or not (run_dir / "metrics.csv").is_file():  # no ceiling, or a summary without its curves
        return "– | –"
    _, episodes, curves, _ = load_run_result(str(run_dir))
    finals = final_returns(curves)
    reach = episodes_to_fraction(episodes, curves, 0.9 * ceiling)
    per_seed = " ".join("–" if np.isnan(e) else f"{int(e):,}" for e in reach)
    return (f"{' '.join(f'{v:.1f}' for v in finals)}; {finals.mean():.1f}, {finals.mean() / ceiling:.0%} | "
            f"{per_seed}; {reach_summary(reach)}")


def table_rows(run_dirs: list[pathlib.Path]) -> list[str]:
    header = ("| scenario | algorithm | seeds | episodes/seed | final greedy return (mean ± s.e.) | per seed | optimal | "
              "reached | settings | wall time | last-10 evaluations (per seed), % of ceiling | episodes to 90 % "
              "(per seed; mean) |")
    rows = [header,
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
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
                    f"{_changed_settings(run_dir, summary['scenario'])} | {summary['wall_seconds'] / 60:.0f} min | "
                    f"{_efficiency(run_dir, summary['scenario'])} |")
    return rows


def table(run_dirs: list[pathlib.Path]) -> str:
    """The table of ``run_dirs``; a ValueError naming the folders that hold no finished run."""
    missing = [str(r) for r in run_dirs if not (r / "summary.json").is_file()]
    if missing:
        raise ValueError(f"no summary.json (run not finished?) in: {', '.join(missing)}")
    return "\n".join(table_rows(run_dirs))
