"""Statistics of a sweep's results: final returns per seed, per-scenario comparisons, aggregates over scenarios.

The paper's metric for a run is its *final return*: the evaluation return (greedy for the value learners, the
policy's for the actor-critics, as ``metrics.csv``'s ``eval_disc_return``; on Warehouse the undiscounted
``eval_return``, see ``return_column``) averaged over the run's last 10
evaluations, per seed. Per scenario every method gets mean ± s.e. over seeds, a bootstrap 95 % confidence interval
of the mean (``scipy.stats.bootstrap``), the fraction of the scenario's ceiling (the optimal return on Box Pushing,
the scripted policies' elsewhere) and Welch's t-test p-value against the reference method (ToMacVF;
``scipy.stats.ttest_ind(equal_var=False)``). Across the scenarios of an experiment: the interquartile mean (IQM) of
ceiling-normalised final returns with stratified-bootstrap 95 % intervals and the probability of improvement of the
reference over each method (rliable, Agarwal et al. 2021).

    results = load_sweep("experiments/sweeps/cpu")          # {(scenario, method): CellResult}
    rows = compare_methods([r for r in results.values() if r.scenario == "boxpushing-6x6"])
    agg = aggregate(results, scenarios, methods)
"""

from __future__ import annotations

import dataclasses
import json
import os
import re

import numpy as np

from jaxmac.plotting import read_eval_curves
from jaxmac.runs.divergence import diverged_record
from jaxmac.scenarios import CEILINGS

FINAL_POINTS = 10  # the final return averages a run's last this many evaluations


def return_column(scenario: str) -> str:
    """The ``metrics.csv`` column a scenario's results are read from: the discounted evaluation return, except on
    Warehouse, whose returns are undiscounted (γ 1), so that a run learning with another γ (``discount``) is
    compared on the same measure."""
    return "eval_return" if scenario.startswith("warehouse") else "eval_disc_return"


@dataclasses.dataclass
class CellResult:
    """One (scenario, method) of a sweep, its seed ranges merged."""

    scenario: str
    method: str
    seeds: list[int]  # seed ids, ascending
    finals: np.ndarray  # f64[seeds] final return per seed
    episodes: np.ndarray  # i64[P] evaluation points (episodes per seed)
    curves: np.ndarray  # f64[seeds, P] evaluation return per seed
    budget: int  # training episodes per seed the cell was planned for (its configuration's ``episodes``)
    wall_seconds: float  # summed over the seed ranges' runs
    trained: int = 0  # training episodes per seed it ran: the budget, or fewer where a seed range ended early
    ended_early: tuple[tuple[str, str], ...] = ()  # (seed range folder, why: summary.json's ``ended_early``)


def final_returns(curves: np.ndarray, last: int = FINAL_POINTS) -> np.ndarray:
    """Per seed, the mean of the last ``last`` evaluation points of ``curves`` f[seeds, P] (all if fewer)."""
    curves = np.asarray(curves, dtype=np.float64)
    if curves.shape[-1] == 0:
        raise ValueError("final_returns: a run without evaluations")
    return curves[:, -last:].mean(-1)


def episodes_to_fraction(episodes: np.ndarray, curves: np.ndarray, target: float,
                         window: int = FINAL_POINTS) -> np.ndarray:
    """Sample efficiency per seed: the episodes at the first evaluation point where the trailing mean of the last
    ``window`` evaluations (``plotting.smooth``, the curves' smoothing) reaches ``target`` (e.g. 0.9 × the
    ceiling); NaN for a seed that never does. ``episodes`` [P], ``curves`` f[seeds, P] -> f64[seeds]."""
    curves = np.asarray(curves, dtype=np.float64)
    out = np.full(curves.shape[0], np.nan)
    for s, row in enumerate(curves):
        for p in range(window - 1, len(row)):
            if row[p - window + 1: p + 1].mean() >= target:
                out[s] = episodes[p]
                break
    return out


def planned_episodes(run_dir: str, summary: dict) -> int:
    """The training episodes per seed a run was configured for (``config.json``), which a run that ended early did
    not reach; the summary's ``episodes`` when the folder has no configuration."""
    path = os.path.join(run_dir, "config.json")
    if os.path.exists(path):
        with open(path) as f:
            held = json.load(f)
        episodes = held.get("config", {}).get("episodes")
        if isinstance(episodes, int):
            return episodes
    return int(summary["episodes"])


def reach_summary(reach: np.ndarray) -> str:
    """``episodes_to_fraction``'s per-seed episodes in a table cell: their mean over the seeds that got there,
    "(k of n seeds)" when some never did, "never" when none did."""
    got = reach[~np.isnan(reach)]
    if not len(got):
        return "never"
    return f"{got.mean():,.0f}" + ("" if len(got) == len(reach) else f" ({len(got)} of {len(reach)} seeds)")


def load_run_result(run_dir: str) -> tuple[list[int], np.ndarray, np.ndarray, dict]:
    """(seed ids, episodes [P], curves [seeds, P], summary) of a finished run folder."""
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)
    episodes, curves = read_eval_curves(os.path.join(run_dir, "metrics.csv"), return_column(summary["scenario"]))
    first = summary.get("seed_offset", 0)
    return list(range(first, first + summary["seeds"])), episodes, curves, summary


def method_folders(sweep_dir: str):
    """(scenario, method, folder) of every ``<scenario>/<method>/`` folder of a sweep, sorted; files are skipped (a
    results page in ``SWEEP_DIR/results/`` holds no cell)."""
    for scenario in sorted(os.listdir(sweep_dir)):
        if not os.path.isdir(os.path.join(sweep_dir, scenario)):
            continue
        for method in sorted(os.listdir(os.path.join(sweep_dir, scenario))):
            if os.path.isdir(os.path.join(sweep_dir, scenario, method)):
                yield scenario, method, os.path.join(sweep_dir, scenario, method)


def seed_range(folder: str) -> tuple[int, int]:
    """(first seed, end seed) of a ``seeds<A>-<B>`` folder name: seeds A..B-1."""
    first, end = folder[5:].split("-")
    return int(first), int(end)


def seed_range_folders(method_dir: str, finished: bool | None = None) -> list[str]:
    """The ``seeds<A>-<B>`` folders of a cell, by first seed; ``finished`` True / False keeps those with / without
    a ``summary.json``."""
    if not os.path.isdir(method_dir):
        return []
    names = sorted((d for d in os.listdir(method_dir) if re.fullmatch(r"seeds\d+-\d+", d)),
                   key=lambda d: seed_range(d)[0])
    return [d for d in names
            if finished is None or os.path.exists(os.path.join(method_dir, d, "summary.json")) == finished]


def load_cell(method_dir: str, scenario: str, method: str) -> CellResult | None:
    """The finished seed ranges of one cell folder merged (None when none has finished); the curves are cut to the
    evaluation points all ranges have. A seed that two ranges both hold, or ranges planned for different budgets,
    are errors."""
    finished = seed_range_folders(method_dir, finished=True)
    parts = [load_run_result(os.path.join(method_dir, d)) for d in finished]
    if not parts:
        return None
    seeds = [s for p in parts for s in p[0]]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"{method_dir}: seed ranges overlap ({seed_range_folders(method_dir)})")
    budgets = {planned_episodes(os.path.join(method_dir, d), p[3]) for d, p in zip(finished, parts)}
    if len(budgets) != 1:
        raise ValueError(f"{method_dir}: seed ranges were trained for different budgets {sorted(budgets)}")
    points = min(p[1].shape[0] for p in parts)
    curves = np.concatenate([p[2][:, :points] for p in parts])
    return CellResult(
        scenario, method, seeds, np.concatenate([final_returns(p[2]) for p in parts]), parts[0][1][:points],
        curves, budgets.pop(), float(sum(p[3].get("wall_seconds", 0.0) for p in parts)),
        trained=min(int(p[3]["episodes"]) for p in parts),
        ended_early=tuple((d, p[3]["ended_early"]) for d, p in zip(finished, parts) if p[3].get("ended_early")))


def load_sweep(sweep_dir: str) -> dict[tuple[str, str], CellResult]:
    """Every finished cell of a sweep folder (``<scenario>/<method>/seeds<A>-<B>/``), the seed ranges of a
    (scenario, method) merged (``load_cell``). Unfinished cells are left out."""
    results: dict[tuple[str, str], CellResult] = {}
    for scenario, method, method_dir in method_folders(sweep_dir):
        cell = load_cell(method_dir, scenario, method)
        if cell is not None:
            results[(scenario, method)] = cell
    return results


@dataclasses.dataclass
class RangeProgress:
    """A seed range of a sweep cell that has not finished: how far its run folder got."""

    folder: str  # "seeds<A>-<B>"
    seeds: int
    episodes: int  # training episodes per seed in its metrics.csv so far (the least over its seeds; 0 = none yet)
    budget: int  # training episodes per seed it is configured for
    rate: float | None = None  # seed-episodes per core-second it has trained at so far (``own_rate``); None: unknown
    diverged: str | None = None  # what the divergence guard stopped (``diverged.json``'s problem); None: it did not


def trained_episodes(run_dir: str, seeds: int) -> int:
    """Training episodes per seed that the run folder ``run_dir`` of ``seeds`` seeds has in its ``metrics.csv`` (the
    least over its seeds; 0 before every seed has a row)."""
    from jaxmac.runs.metrics_csv import episodes_per_seed

    last = episodes_per_seed(os.path.join(run_dir, "metrics.csv"))
    return min(last.values()) if len(last) == seeds else 0


OWN_RATE_MIN_SECONDS = 600.0  # a run's own pace is trusted once it has trained this long (wall seconds, resumes summed)


def own_rate(run_dir: str, min_seconds: float = OWN_RATE_MIN_SECONDS) -> float | None:
    """The rate an unfinished run folder has trained at so far, in seed-episodes per core-second: the episodes its
    newest checkpoint covers (``progress.json``'s chunks × rounds per chunk × parallel episodes × seeds) over the wall
    seconds they took, accumulated over resumes and compilations included, times the most devices any attempt used
    (``attempts.jsonl``; 1 without it). A better guide to what the run still costs than another scenario's rate:
    Overcooked-C's ToMacVF ran at twice Overcooked-B's.

    None before its first checkpoint, when a file is unreadable, or while those wall seconds are under
    ``min_seconds``: until then compilation (a minute or more per attempt) dominates them — Warehouse-E's Mac-CAC read
    ~5.3 core-hours left after its first 640 episodes — and the callers fall back to a measured rate."""
    from jaxmac.runs.folders import read_meta, read_progress

    progress = read_progress(run_dir)
    if progress is None:
        return None
    try:
        meta = read_meta(run_dir)
        episodes = progress["chunks_done"] * meta["rounds_per_chunk"] * meta["config"]["num_envs"] * meta["seeds"]
        wall = float(progress["wall_seconds"])
    except (ValueError, KeyError, TypeError):
        return None
    devices = 1
    try:
        with open(os.path.join(run_dir, "attempts.jsonl")) as f:
            devices = max([devices] + [len(json.loads(line).get("devices", [])) for line in f if line.strip()])
    except (OSError, ValueError):
        pass
    return episodes / (wall * devices) if episodes > 0 and wall > 0 and wall >= min_seconds else None


def load_progress(sweep_dir: str) -> dict[tuple[str, str], list[RangeProgress]]:
    """Every seed range of a sweep folder that has a run folder (its ``config.json``) but no ``summary.json`` yet,
    per (scenario, method): what a results page reports of cells still running, interrupted, or stopped by the
    divergence guard."""
    progress: dict[tuple[str, str], list[RangeProgress]] = {}
    for scenario, method, method_dir in method_folders(sweep_dir):
        for d in seed_range_folders(method_dir, finished=False):
            run = os.path.join(method_dir, d)
            if not os.path.exists(os.path.join(run, "config.json")):
                continue
            first, end = seed_range(d)
            episodes = trained_episodes(run, end - first)
            record = diverged_record(run)
            progress.setdefault((scenario, method), []).append(
                RangeProgress(d, end - first, episodes, planned_episodes(run, {"episodes": 0}), own_rate(run),
                              None if record is None else record["problem"]))
    return progress


def welch_p(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided p-value of Welch's t-test that ``a`` and ``b`` have the same mean (nan with fewer than 2 each)."""
    from scipy import stats

    if len(a) < 2 or len(b) < 2:
        return float("nan")
    return float(stats.ttest_ind(a, b, equal_var=False).pvalue)


def bootstrap_ci(values: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """95 % percentile-bootstrap confidence interval of the mean of ``values`` (nan with fewer than 2)."""
    from scipy import stats

    values = np.asarray(values, dtype=np.float64)
    if len(values) < 2 or np.all(values == values[0]):
        return (float(values.mean()), float(values.mean())) if len(values) >= 2 else (float("nan"),) * 2
    res = stats.bootstrap((values,), np.mean, confidence_level=0.95, n_resamples=10_000, method="percentile",
                          rng=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def compare_methods(cells: list[CellResult], reference: str = "tomacvf") -> list[dict]:
    """One row per method of one scenario: n, mean, s.e., bootstrap CI, fraction of the ceiling, Welch's p against
    ``reference`` (nan for itself or when it is missing), and ``best`` (the highest mean)."""
    ceiling = CEILINGS.get(cells[0].scenario) if cells else None
    ref = next((c for c in cells if c.method == reference), None)
    rows = []
    for c in cells:
        n = len(c.finals)
        rows.append({
            "scenario": c.scenario, "method": c.method, "seeds": n, "budget": c.budget,
            "wall_seconds": c.wall_seconds, "mean": float(c.finals.mean()),
            "se": float(c.finals.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan"),
            "ci": bootstrap_ci(c.finals), "of_ceiling": float(c.finals.mean() / ceiling) if ceiling else float("nan"),
            "p_vs_reference": welch_p(ref.finals, c.finals) if ref is not None and c is not ref else float("nan"),
        })
    if rows:
        best = max(rows, key=lambda r: r["mean"])
        for r in rows:
            r["best"] = r is best
    return rows


def who_wins(cells: list[CellResult], alpha: float = 0.05) -> tuple[str, list[str]]:
    """The method with the highest mean final return of one scenario, and the others Welch's test cannot tell
    from it at level ``alpha`` (p ≥ alpha; with fewer than 2 seeds a method is never told apart), best mean first."""
    if not cells:
        raise ValueError("who_wins: no finished cell")
    ranked = sorted(cells, key=lambda c: -c.finals.mean())
    best = ranked[0]
    tied = [c.method for c in ranked[1:] if not welch_p(best.finals, c.finals) < alpha]
    return best.method, tied


def aggregate(results: dict[tuple[str, str], CellResult], scenarios: list[str], methods: list[str],
              reference: str = "tomacvf", reps: int = 2000, seed: int = 0) -> dict:
    """Across ``scenarios``: per method the IQM of ceiling-normalised final returns with its stratified-bootstrap
    95 % interval, and the probability that ``reference`` improves on each other method (with its interval).
    Every method needs every scenario; the seeds per scenario are cut to the fewest any cell has (rliable needs a
    [runs, tasks] matrix)."""
    from rliable import library as rly
    from rliable import metrics

    missing = [(s, m) for s in scenarios for m in methods if (s, m) not in results]
    if missing:
        raise ValueError(f"aggregate: cells not finished: {missing}")
    runs = min(len(results[(s, m)].finals) for s in scenarios for m in methods)
    scores = {m: np.stack([results[(s, m)].finals[:runs] / CEILINGS[s] for s in scenarios], axis=1) for m in methods}
    np.random.seed(seed)  # rliable's bootstrap draws from NumPy's global generator
    iqm, iqm_ci = rly.get_interval_estimates(scores, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=reps)
    out = {"runs": runs, "iqm": {m: (float(iqm[m][0]), float(iqm_ci[m][0, 0]), float(iqm_ci[m][1, 0]))
                                 for m in methods}, "p_improvement": {}}
    if reference in methods:
        pairs = {f"{reference},{m}": (scores[reference], scores[m]) for m in methods if m != reference}
        if pairs:
            poi, poi_ci = rly.get_interval_estimates(pairs, metrics.probability_of_improvement, reps=reps)
            out["p_improvement"] = {k.split(",")[1]: (float(poi[k]), *map(float, np.ravel(poi_ci[k])))
                                    for k in pairs}
    return out
