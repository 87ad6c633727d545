"""The results page of a sweep: what it ran, per experiment its figure, one table per scenario and the aggregates.

    jaxmac results SWEEP_DIR [--out DIR] [--experiments bp ...] [--protocol NAME]

Reads the finished cells of ``SWEEP_DIR`` (written by ``jaxmac sweep``) and writes ``OUT/RESULTS.md`` (default
``SWEEP_DIR/results/``). The page opens with what it was made from: the protocol (the sweep folder's name when it
is one, else the protocol whose cells' configurations the finished cells hold), the finished cells, the seeds per
cell (min–max) and the episode budgets, and the experiments with no finished cell, in one line. Then headline tables
(one row per scenario, one column per method), the paper's four questions answered from the finished cells
(ToMacVF against the baselines, with who got to 90 % of the ceiling first and a verdict on the paper's claim; the two
ablations; the mixers) and, for each experiment with a finished cell: the
paper's figure (one panel per scenario, one curve per method, mean ± s.e. over seeds of the 10-point moving
average, a curve of one evaluation point drawn as a marker, the ceiling dashed; ``OUT/<experiment>.png`` and
``.pdf``), a table per scenario (seeds, budget, final return mean ± s.e. with its bootstrap 95 % interval, fraction
of the ceiling, Welch's p against ToMacVF, wall time; the best mean in bold; a "who wins" line: the best and the
methods Welch's test cannot tell from it) and, where every method finished every scenario, the IQM of
ceiling-normalised final returns and ToMacVF's probability of improvement over each method (``jaxmac.study.stats``).

Fewer than 2 seeds decide nothing: a scenario where a finished cell has one seed gets no interval, no p-value and
no "who wins" line, a question is answered only from cells of at least 2 seeds each, aggregates need 2 seeds per
cell, and the page says why (``NO_TEST_WHY``). Cells not finished are listed as "not finished yet" (how far they
ran, what they still cost), "not started" (a cell the protocol plans that no run has begun: its budget and estimated
cost, also in the closing "Cells not started" table), or "not run" with the reason where the protocol leaves them out.
"""

from __future__ import annotations

import json
import os

import numpy as np

from jaxmac.plotting import label_episode_axis, mean_and_standard_error, save_figure, smooth
from jaxmac.scenarios import CEILINGS, family
from jaxmac.study.stats import (aggregate, compare_methods, episodes_to_fraction, load_progress, load_sweep,
                                reach_summary, seed_range, seed_range_folders, welch_p, who_wins)
from jaxmac.study.sweep import EXPERIMENTS, PROTOCOLS, Cell, estimate_seconds, method_by_name, protocol_cell

REFERENCE = "tomacvf"
MIN_SEEDS = 2  # the fewest seeds per method for an interval, Welch's test and a winner
NO_TEST_WHY = ("a winner, an interval and a test need at least 2 seeds per method (the bootstrap and Welch's test "
               "need the spread of each method's final returns; one seed's return may be its luck)")


def method_colours() -> dict[str, str]:
    """One colour per method name across every figure."""
    names = sorted({m.name for methods, _ in EXPERIMENTS.values() for m in methods})
    palette = [f"C{k}" for k in range(10)] + ["#8c564b", "#17becf", "#bcbd22", "#7f7f7f", "#000080"]
    return {name: palette[k % len(palette)] for k, name in enumerate(names)}


def _seeds(cell) -> int:
    return len(cell.finals)


def _tested(cells) -> bool:
    """Whether every one of ``cells`` has the seeds a test and a winner need."""
    return all(_seeds(c) >= MIN_SEEDS for c in cells)


def _has_finished_cell(results, experiment: str, scenario: str | None = None, protocol: str | None = None) -> bool:
    """Whether any method of ``experiment`` has a finished cell: on ``scenario`` only, when given, else on the
    scenarios ``protocol`` runs the experiment on (``scenarios_run``: a ToMacVF cell another experiment finished on a
    scenario this one leaves out does not count)."""
    methods = EXPERIMENTS[experiment][0]
    scenarios = [scenario] if scenario else scenarios_run(experiment, protocol)
    return any((s, m.name) in results for s in scenarios for m in methods)


def experiment_figure(results, experiment: str, out_base: str, window: int = 10, protocol: str | None = None) -> bool:
    """One panel per scenario of ``experiment`` that ``protocol`` runs it on (``scenarios_run``); False when no cell
    of it has finished. A curve of a single evaluation point is a marker (with its s.e. bar), as a line through one
    point draws nothing."""
    from matplotlib.figure import Figure  # its own Agg canvas: never touches pyplot's backend or figure list

    methods, scenarios = EXPERIMENTS[experiment][0], scenarios_run(experiment, protocol)
    if not scenarios or not _has_finished_cell(results, experiment, protocol=protocol):
        return False
    colours = method_colours()
    fig = Figure(figsize=(4.2 * len(scenarios), 3.6), dpi=110)
    axes = fig.subplots(1, len(scenarios), squeeze=False)
    for ax, scenario in zip(axes[0], scenarios):
        for method in methods:
            cell = results.get((scenario, method.name))
            if cell is None or not cell.curves.size:
                continue
            w = max(1, min(window, cell.curves.shape[1] // 10))
            mean, se = mean_and_standard_error(smooth(cell.curves, w))
            se = np.zeros_like(mean) if se is None else se
            colour, label = colours[method.name], method.label or method.name
            if len(cell.episodes) == 1:
                ax.errorbar(cell.episodes, mean, yerr=se, color=colour, label=label, marker="o", ms=5, ls="none",
                            capsize=3)
                continue
            ax.plot(cell.episodes, mean, color=colour, label=label, lw=1.2)
            ax.fill_between(cell.episodes, mean - se, mean + se, color=colour, alpha=0.2)
        if not _has_finished_cell(results, experiment, scenario):
            ax.text(0.5, 0.5, "no finished cell yet", ha="center", va="center", transform=ax.transAxes,
                    color="0.4", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
        elif scenario in CEILINGS:
            ax.axhline(CEILINGS[scenario], color="k", ls="--", lw=1)
        ax.set_title(scenario, fontsize=10)
        label_episode_axis(ax)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("evaluation return")
    handles = {h.get_label(): h for ax in axes[0] for h in ax.get_legend_handles_labels()[0]}
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=min(7, len(handles)), fontsize=8,
               frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    save_figure(fig, out_base + ".png", pdf=True)
    return True


def _fmt_p(p: float) -> str:
    return "–" if np.isnan(p) else (f"{p:.3f}" if p >= 0.001 else "<0.001")


def _not_run_reason(protocol: str | None, method: str, scenario: str) -> str | None:
    """Why ``protocol`` leaves the cell out, None when it runs it (or the protocol is unknown)."""
    return PROTOCOLS[protocol].not_run_reason(method, scenario) if protocol in PROTOCOLS else None


def _left_out_reason(protocol: str | None, methods, scenario: str) -> str | None:
    """The protocol's reason (its first clause) where it leaves out every method of an experiment on ``scenario`` but
    ToMacVF (whose cell belongs to the comparison with the baselines), else None."""
    reasons = [_not_run_reason(protocol, m.name, scenario) for m in methods if m.name != REFERENCE]
    if not reasons or not all(reasons):
        return None
    return reasons[0].split(":")[0]


def scenarios_run(experiment: str, protocol: str | None) -> list[str]:
    """The scenarios of ``experiment`` that ``protocol`` runs it on: all but those where it leaves out every method
    but ToMacVF (``_left_out_reason``; e.g. the full protocol's mixers on Overcooked B and C, where ToMacVF's cell
    is the comparison's and no other mixer runs, so the experiment would have a row of one method)."""
    methods, scenarios = EXPERIMENTS[experiment]
    return [s for s in scenarios if not _left_out_reason(protocol, methods, s)]


def _few_seeds_sentence(cells, labels: dict[str, str]) -> str:
    """Why a scenario with a cell of fewer than 2 seeds gets no winner, interval or test."""
    few = [c for c in cells if _seeds(c) < MIN_SEEDS]
    names = "every method" if len(few) == len(cells) > 1 else ", ".join(labels.get(c.method, c.method) for c in few)
    return (f"No winner, interval or test here: {names} {'has' if len(few) == 1 or names == 'every method' else 'have'} "
            f"{'one seed' if all(_seeds(c) == 1 for c in few) else f'fewer than {MIN_SEEDS} seeds'}, and a winner "
            f"and a test need at least {MIN_SEEDS} seeds per method.")


def _reach(cell, fraction: float = 0.9) -> np.ndarray | None:
    """Per seed, the episodes at which the smoothed evaluation return first reaches ``fraction`` of the ceiling
    (NaN: never; ``stats.episodes_to_fraction``); None without a ceiling or curves."""
    ceiling = CEILINGS.get(cell.scenario)
    if ceiling is None or not cell.curves.size:
        return None
    return episodes_to_fraction(cell.episodes, cell.curves, fraction * ceiling)


def reach_text(cell, fraction: float = 0.9) -> str:
    """Sample efficiency of a cell: the mean over its seeds of the episodes at which the smoothed evaluation return
    first reaches ``fraction`` of the ceiling, "(k of n seeds)" when some seeds never did; "never" when none did,
    "–" without a ceiling."""
    reach = _reach(cell, fraction)
    return "–" if reach is None else reach_summary(reach)


def reach_rank(cell, fraction: float = 0.9) -> tuple[float, float] | None:
    """A sort key for "got to ``fraction`` of the ceiling first": (minus the share of seeds that got there, their
    mean episodes to it); None without a ceiling or when no seed got there."""
    reach = _reach(cell, fraction)
    got = reach[~np.isnan(reach)] if reach is not None else []
    return (-len(got) / len(reach), float(got.mean())) if len(got) else None


def _episodes_text(cell) -> str:
    """"96", or "52,000 of 120,000 (ended early)" for a cell a seed range of which ended before its budget."""
    if cell.ended_early and cell.trained < cell.budget:
        return f"{cell.trained:,} of {cell.budget:,} (ended early)"
    return f"{cell.budget:,}"


def progress_text(ranges, scenario: str, method: str, rates: dict | None) -> str:
    """What a cell's unfinished seed ranges have run ("14,208 of 120,000 episodes per seed (seeds 0–1), …") and the
    core-hours they still cost: at the rate each range has trained at so far (``own_rate``, once it has trained ten
    minutes), else at the rate measured for the method (``jaxmac calibrate``). A range the divergence guard stopped
    says so, with what diverged, and costs nothing more (the sweep does not rerun it)."""
    parts, seconds, measured, unknown = [], 0.0, set(), False
    try:
        method_obj = method_by_name(method)
    except ValueError:
        method_obj = None
    for r in ranges:
        first = seed_range(r.folder)[0]
        seeds = f"seeds {first}–{first + r.seeds - 1}"
        if r.diverged is not None:  # a result, not a run still to finish: the sweep does not rerun it
            parts.append(f"**diverged** at {r.episodes:,} of {r.budget:,} episodes per seed ({seeds}; the "
                         f"divergence guard stopped it: {r.diverged})")
            continue
        parts.append(f"{r.episodes:,} of {r.budget:,} episodes per seed ({seeds})")
        left = r.seeds * max(r.budget - r.episodes, 0)
        if r.rate is not None:
            seconds += left / r.rate
            measured.add("its own rate so far")
            continue
        estimate = (estimate_seconds(Cell("", method_obj, scenario, 0, 1, left), rates or {})
                    if method_obj is not None else None)
        if estimate is None:
            unknown = True
        else:
            seconds += estimate[0]
            measured.add(f"the rate measured for {estimate[1]}")
    text = "; ".join(parts)
    if measured and not unknown:
        text += f"; {_hours_text(seconds)} left at {' and '.join(sorted(measured))}"
    return text


def _hours_text(seconds: float) -> str:
    """"~5.3 core-hours" (whole hours from 10 on)."""
    hours = seconds / 3600
    return (f"~{hours:.1f}" if hours < 10 else f"~{hours:.0f}") + " core-hours"


def not_started_cells(experiments: list[str], protocol: str | None, results, progress) -> list[Cell]:
    """The cells ``protocol`` plans for ``experiments`` that no run has begun (no finished seeds, no run folder), in
    the plan's order, each once (the mixers' QMIX cell is the comparison's ToMacVF cell); [] for an unknown
    protocol."""
    from jaxmac.study.sweep import plan

    if protocol not in PROTOCOLS:
        return []
    cells, seen = [], set()
    for experiment in experiments:
        for cell in plan(experiment, protocol):
            key = (cell.scenario, cell.method.name)
            if key not in seen and key not in results and key not in (progress or {}):
                seen.add(key)
                cells.append(cell)
    return cells


def cost_text(cell: Cell, rates: dict | None) -> str:
    """What a cell not started costs: "~5.0 core-hours at the rate measured for tomacvf@warehouse-A", or "no rate
    measured for this method" (``jaxmac calibrate`` measures one), or "no rates given"."""
    if rates is None:
        return "no rates given"
    estimate = estimate_seconds(cell, rates)
    if estimate is None:
        return f"no rate measured for {cell.method.name}"
    seconds, measured = estimate
    return f"{_hours_text(seconds)} at the rate measured for {measured}"


def not_started_section(cells: list[Cell], protocol: str, rates: dict | None) -> list[str]:
    """One table of the cells no run has begun, each with its budget and estimated cost, and their total."""
    if not cells:
        return []
    lines = ["## Cells not started", "",
             f"The cells the protocol plans that no run has begun, with what each costs on one core at the training "
             f"rates measured here (`jaxmac sweep EXPERIMENT --protocol {protocol}` runs them, `--dry-run` lists "
             "them):", "",
             "| experiment | cell | seeds × episodes per seed | estimated cost |", "|---|---|---|---|"]
    lines += [f"| {cell.experiment} | {cell.path} | {cell.seeds} × {cell.episodes:,} | {cost_text(cell, rates)} |"
              for cell in cells]
    return lines + ["", f"In all {_not_started_total(cells, rates)}.", ""]


def _not_started_total(cells: list[Cell], rates: dict | None) -> str:
    """"~131.2 core-hours at the measured rates" (and how many cells had no rate to count)."""
    if rates is None:
        return "their costs need measured rates (`jaxmac results --rates`)"
    estimates = [estimate_seconds(cell, rates) for cell in cells]
    total = sum(e[0] for e in estimates if e is not None)
    unknown = sum(e is None for e in estimates)
    text = f"{_hours_text(total)} at the measured rates"
    return text + (f", {unknown} cells without a measured rate not counted" if unknown else "")


def scenario_table(results, experiment: str, scenario: str, protocol: str | None = None, progress=None,
                   rates: dict | None = None) -> list[str]:
    """The scenario's table: one row per finished cell (seeds, episodes per seed, final return, its interval, the
    fraction of the ceiling, the episodes to 90 % of the ceiling, Welch's p against ToMacVF, wall time), then the
    cells not finished: how far they ran and what they still cost (``progress``: ``stats.load_progress``), what a
    cell the protocol plans but no run has begun costs, or why the protocol leaves them out."""
    methods, _ = EXPERIMENTS[experiment]
    progress = progress or {}
    cells = [results[(scenario, m.name)] for m in methods if (scenario, m.name) in results]
    labels = {m.name: m.label or m.name for m in methods}
    tested = _tested(cells)
    lines = [f"**{scenario}** (ceiling {CEILINGS.get(scenario, float('nan')):.1f})", "",
             "| method | seeds | episodes/seed | final return | 95 % CI | of ceiling | episodes to 90 % "
             "| p vs ToMacVF | wall time |",
             "|---|---|---|---|---|---|---|---|---|"]
    reference_seeds = next((_seeds(c) for c in cells if c.method == REFERENCE), None)
    for r in compare_methods(cells, REFERENCE):
        value = f"{r['mean']:.1f} ± {r['se']:.1f}" if not np.isnan(r["se"]) else f"{r['mean']:.1f}"
        value = f"**{value}**" if r["best"] and tested else value
        if r["seeds"] < MIN_SEEDS:
            interval = f"n = {r['seeds']}: no interval"
        else:
            interval = f"[{r['ci'][0]:.1f}, {r['ci'][1]:.1f}]"
        if r["method"] == REFERENCE or reference_seeds is None:
            p_text = "–"
        elif min(r["seeds"], reference_seeds) < MIN_SEEDS:
            p_text = f"n = {min(r['seeds'], reference_seeds)}: no test"
        else:
            p_text = _fmt_p(r["p_vs_reference"])
        cell = results[(scenario, r["method"])]
        lines.append(f"| {labels[r['method']]} | {r['seeds']} | {_episodes_text(cell)} | {value} | {interval} | "
                     f"{100 * r['of_ceiling']:.0f} % | {reach_text(cell)} | {p_text} "
                     f"| {r['wall_seconds'] / 60:.0f} min |")
    running = []
    for m in methods:
        ranges = progress.get((scenario, m.name))
        if (scenario, m.name) not in results:
            why = _not_run_reason(protocol, m.name, scenario)
            if why:
                status = f"not run: {why}"
            elif ranges and all(r.diverged is not None for r in ranges):
                status = progress_text(ranges, scenario, m.name, rates)
            elif ranges:
                status = f"not finished yet: {progress_text(ranges, scenario, m.name, rates)}"
            elif protocol in PROTOCOLS:
                cell = protocol_cell(experiment, protocol, m, scenario, 0, PROTOCOLS[protocol].seeds)
                status = f"not started: {cell.seeds} seeds × {cell.episodes:,} episodes"
                status += f", {cost_text(cell, rates)}" if rates is not None else ""
            else:
                status = "not finished yet"
            lines.append(f"| {labels[m.name]} | {status} | | | | | | | |")
        elif ranges:
            running.append(f"{labels[m.name]}: {progress_text(ranges, scenario, m.name, rates)}")
    if running:
        lines += ["", "More seeds not finished yet (the rows above are the finished seeds only): "
                  + "; ".join(running) + "."]
    if cells and not tested:
        lines += ["", _few_seeds_sentence(cells, labels)]
    elif len(cells) == 1:
        lines += ["", f"Who wins: not decided; only {labels[cells[0].method]} has finished."]
    elif cells:
        best, tied = who_wins(cells)
        tied_text = f"; not told apart from it (Welch's p ≥ 0.05): {', '.join(labels[t] for t in tied)}" if tied else \
            "; every other method is below it (Welch's p < 0.05)"
        lines += ["", f"Who wins: **{labels[best]}**{tied_text}."]
    return lines + [""]


# experiments whose methods share the headline's columns: the comparison with the baselines, the ablation, the mixers
HEADLINE_GROUPS = (("bp", "warehouse", "overcooked"), ("ablation",), ("mixers",))


def headline_table(results, experiments: list[str], protocol: str | None = None) -> list[str]:
    """One row per (experiment, scenario), one column per method: mean final return and its fraction of the
    ceiling, the scenario's best in bold where every finished cell of the row has at least 2 seeds; "n.r." a cell
    the protocol leaves out, "…" one not finished, "" a method the experiment does not have. Scenarios and
    experiments with no finished cell have no row (the page names them in one line); [] when none of
    ``experiments`` has one."""
    experiments = [e for e in experiments if _has_finished_cell(results, e, protocol=protocol)]
    if not experiments:
        return []
    columns: dict[str, str] = {}
    for experiment in experiments:
        for m in EXPERIMENTS[experiment][0]:
            columns.setdefault(m.name, m.label or m.name)
    lines = ["| experiment | scenario | " + " | ".join(columns.values()) + " |",
             "|---|---|" + "---|" * len(columns)]
    for experiment in experiments:
        methods = EXPERIMENTS[experiment][0]
        names = {m.name for m in methods}
        for scenario in scenarios_run(experiment, protocol):
            cells = [results[(scenario, n)] for n in columns if n in names and (scenario, n) in results]
            if not cells:
                continue  # a scenario no method has finished: no row of "…"
            best = who_wins(cells)[0] if cells and _tested(cells) else None
            row = []
            for name in columns:
                cell = results.get((scenario, name))
                if name not in names:
                    row.append("")
                elif cell is None:
                    row.append("n.r." if _not_run_reason(protocol, name, scenario) else "…")
                else:
                    text = f"{cell.finals.mean():.1f} ({100 * cell.finals.mean() / CEILINGS[scenario]:.0f} %)"
                    row.append(f"**{text}**" if name == best else text)
            lines.append(f"| {experiment} | {scenario} | " + " | ".join(row) + " |")
    return lines + [""]


def aggregate_lines(results, experiment: str, protocol: str | None = None) -> list[str]:
    """IQM and probability of improvement across the experiment's scenarios, over the methods that ran on every one
    of them; a method the protocol leaves out on some scenario is named and left out of the aggregates. Not
    computed when a cell has fewer than 2 seeds (its intervals would be a single point)."""
    methods, scenarios = EXPERIMENTS[experiment][0], scenarios_run(experiment, protocol)
    labels = {m.name: m.label or m.name for m in methods}
    left_out = [m.name for m in methods if any(_not_run_reason(protocol, m.name, s) for s in scenarios)]
    names = [m.name for m in methods if m.name not in left_out]
    if not names or not scenarios:
        return ["Aggregates: no method runs on every scenario under this protocol.", ""]
    if any((s, n) not in results for s in scenarios for n in names):
        return ["Aggregates: not every method has finished every scenario yet.", ""]
    if not _tested([results[(s, n)] for s in scenarios for n in names]):
        return [f"Aggregates: not computed: some cells have fewer than {MIN_SEEDS} seeds, and their intervals and "
                f"probabilities of improvement need at least {MIN_SEEDS} seeds per method.", ""]
    agg = aggregate(results, list(scenarios), names, REFERENCE)
    without = (f"; without {', '.join(labels[n] for n in left_out)}, not run on every scenario under this protocol"
               if left_out else "")
    lines = [f"Aggregates over {len(scenarios)} scenarios ({agg['runs']} seeds each; final returns divided by the "
             f"ceiling; rliable, stratified bootstrap 95 % intervals{without}):", "",
             "| method | IQM | 95 % CI | P(ToMacVF > method) | 95 % CI |", "|---|---|---|---|---|"]
    for n in names:
        iqm = agg["iqm"][n]
        poi = agg["p_improvement"].get(n)
        poi_text = "– | –" if poi is None else f"{poi[0]:.2f} | [{poi[1]:.2f}, {poi[2]:.2f}]"
        lines.append(f"| {labels[n]} | {iqm[0]:.2f} | [{iqm[1]:.2f}, {iqm[2]:.2f}] | {poi_text} |")
    return lines + [""]


NOT_ANSWERED = f"not answered: fewer than {MIN_SEEDS} seeds"


def questions_section(results, labels: dict[str, str]) -> list[str]:
    """The paper's four questions answered from the finished cells, one line per question and scenario group; a
    comparison is counted only where each compared cell has at least 2 seeds, otherwise named "not answered"."""
    lines = ["## The paper's four questions", "",
             "Counted from the finished cells that have at least 2 seeds each (the others: \"not answered\"); "
             "\"told apart\" means Welch's p < 0.05 with the seeds of this sweep.", ""]
    lines += ["**1. Does ToMacVF beat the asynchronous baselines?**", ""]
    baselines = [m.name for m in EXPERIMENTS["bp"][0] if not m.name.startswith("tomacvf")]
    answered = False
    for variant in ("tomacvf", "tomacvf-tuned", "tomacvf-paper"):
        won, tied, below, untested, scenarios = [], [], [], [], 0
        alone, reached = [], []  # best told apart from every baseline; sample efficiency per scenario
        for experiment in ("bp", "warehouse", "overcooked"):
            methods, exp_scenarios = EXPERIMENTS[experiment]
            for scenario in exp_scenarios:
                others = [results[(scenario, m.name)] for m in methods
                          if m.name in baselines and (scenario, m.name) in results]
                own = results.get((scenario, variant))
                if own is None or not others:
                    continue
                if not _tested(others + [own]):
                    untested.append(scenario)
                    continue
                scenarios += 1
                best, close = who_wins(others + [own])
                reached.append(_reach_line(scenario, own, others, labels))
                if best == variant and not close:
                    alone.append(scenario)
                if best == variant:
                    won.append(scenario)
                elif variant in close:
                    tied.append(f"{scenario} (best {labels[best]})")
                else:
                    below.append(f"{scenario} ({labels[best]})")
        not_answered = f"{NOT_ANSWERED} on {len(untested)} ({', '.join(untested)})" if untested else ""
        if scenarios:
            answered = True
            lines.append(f"- {labels[variant]}, {scenarios} scenario{'s' if scenarios != 1 else ''} with baselines "
                         "finished: best mean on "
                         f"{len(won)}{' (' + ', '.join(won) + ')' if won else ''}; not told apart from the best on "
                         f"{len(tied)}{' (' + ', '.join(tied) + ')' if tied else ''}; below the best, told apart, on "
                         f"{len(below)}{' (' + ', '.join(below) + ')' if below else ''}"
                         f"{'; ' + not_answered if untested else ''}.")
            first = [scenario for scenario, is_first, _ in reached if is_first]
            lines.append(f"  - Episodes to 90 % of the ceiling, {labels[variant]} against the baseline that got there "
                         f"first: {'; '.join(text for _, _, text in reached)}.")
            lines.append(f"  - Verdict: the paper's claim that {labels[variant]} beats every baseline holds (best mean, "
                         f"told apart from every baseline) on {len(alone)} of {scenarios} "
                         f"scenario{'s' if scenarios != 1 else ''}{' (' + ', '.join(alone) + ')' if alone else ''}; "
                         f"{labels[variant]} gets to 90 % of the ceiling first (on more of its seeds, or on as many and sooner) on "
                         f"{len(first)} of {scenarios}"
                         f"{' (' + ', '.join(first) + ')' if first else ''}.")
        elif untested:
            answered = True
            lines.append(f"- {labels[variant]}: {not_answered}.")
    if not answered:
        lines.append("- no scenario with ToMacVF and a baseline finished yet")
    for number, (question, other) in enumerate((("Does ATPG help?", "tomacvf-wo-atpg"),
                                                 ("Does Mac-SJERT help (against Mac-JERT)?", "tomacvf-wo-sjert")), 2):
        lines += ["", f"**{number}. {question}** ToMacVF minus {labels[other]}, mean final return:", ""]
        pairs, found = [], []
        for sc in EXPERIMENTS["ablation"][1]:
            a, b = results.get((sc, "tomacvf")), results.get((sc, other))
            if a is None or b is None:
                continue
            if not _tested([a, b]):
                found.append(f"- {sc}: {NOT_ANSWERED} (ToMacVF {_seeds(a)}, {labels[other]} {_seeds(b)})")
                continue
            found.append(f"- {sc}: {a.finals.mean() - b.finals.mean():+.1f} (p {_fmt_p(welch_p(a.finals, b.finals))})")
            pairs.append((a.finals, b.finals))
        lines += found or ["- no finished pair yet"]
        if pairs:
            helps = sum(a.mean() > b.mean() and welch_p(a, b) < 0.05 for a, b in pairs)
            hurts = sum(a.mean() < b.mean() and welch_p(a, b) < 0.05 for a, b in pairs)
            lines.append(f"- Verdict: ToMacVF above {labels[other]}, told apart, on {helps} of {len(pairs)} "
                         f"scenarios; below it, told apart, on {hurts}.")
        elif found:
            lines.append(f"- Verdict: {NOT_ANSWERED}.")
    lines += ["", "**4. Which mixer suits ToMacVF?** The best of QMIX, VDN, QPLEX and QTRAN, and those not told "
              "apart from it:", ""]
    mixers, mixer_scenarios = EXPERIMENTS["mixers"]
    labels = {**labels, **{m.name: m.label or m.name for m in mixers}}  # ToMacVF is named by its mixer here
    winners, answers = {}, []
    for scenario in mixer_scenarios:
        cells = [results[(scenario, m.name)] for m in mixers if (scenario, m.name) in results]
        if len(cells) != len(mixers):
            continue
        if not _tested(cells):
            answers.append(f"- {scenario}: {NOT_ANSWERED}")
            continue
        best, close = winners[scenario] = who_wins(cells)
        answers.append(f"- {scenario}: **{labels[best]}**" + (
            f"; not told apart: {', '.join(labels[c] for c in close)}" if close else "; the others told apart below it"))
    lines += answers or ["- no scenario with all four mixers finished yet"]
    if winners:
        qmix = mixers[0].name  # ToMacVF's own mixer, the paper's pick
        alone = sum(best == qmix and not close for best, close in winners.values())
        lines.append(f"- Verdict: {labels[qmix]} is best and told apart from the other three on {alone} of "
                     f"{len(winners)} scenarios.")
    elif answers:
        lines.append(f"- Verdict: {NOT_ANSWERED}.")
    return lines + [""]


def _reach_line(scenario: str, own, others, labels: dict[str, str]) -> tuple[str, bool, str]:
    """(scenario, whether ``own`` got to 90 % of the ceiling first, "overcooked-A 44,017 vs Mac-IAICC 29,313"):
    first means more of its seeds got there than of any baseline's, or as many and sooner on average
    (``reach_rank``)."""
    ranked = sorted(((rank, c) for c in others if (rank := reach_rank(c)) is not None), key=lambda rc: rc[0])
    own_rank = reach_rank(own)
    if not ranked:
        return scenario, own_rank is not None, f"{scenario} {reach_text(own)} vs never (every baseline)"
    rank, fastest = ranked[0]
    return (scenario, own_rank is not None and own_rank < rank,
            f"{scenario} {reach_text(own)} vs {labels[fastest.method]} {reach_text(fastest)}")


def _finished_run_folders(sweep_dir: str, scenario: str, method: str) -> list[str]:
    method_dir = os.path.join(sweep_dir, scenario, method)
    return [os.path.join(method_dir, d) for d in seed_range_folders(method_dir, finished=True)]


def protocol_of_configs(sweep_dir: str, results) -> str | None:
    """The one protocol whose cells' configurations (``jaxmac.study.sweep.Cell.config``; the seeds aside) every finished
    cell of the sweep holds in its ``config.json``; None when no cell holds one, or none or several match."""
    from jaxmac.config import TrainConfig
    from jaxmac.study.sweep import Cell, method_by_name

    candidates, checked = set(PROTOCOLS), 0
    for scenario, method_name in results:
        try:
            method = method_by_name(method_name)
        except ValueError:
            return None
        for run in _finished_run_folders(sweep_dir, scenario, method_name):
            path = os.path.join(run, "config.json")
            if not os.path.exists(path):
                continue
            try:
                with open(path) as f:
                    held = TrainConfig.from_dict(json.load(f)["config"]).run_settings()
            except (KeyError, TypeError, ValueError):  # a configuration of an older jaxmac
                return None
            checked += 1
            for name in sorted(candidates):
                proto = PROTOCOLS[name]
                if proto.not_run_reason(method_name, scenario) is not None:
                    candidates.discard(name)
                    continue
                budget = proto.budget(scenario, method.config(scenario, proto.tiny).episodes)
                wanted = Cell("", method, scenario, 0, 1, budget, proto.tiny, proto.scale_schedules).config()
                if any(held.get(k) != v for k, v in wanted.run_settings().items()):
                    candidates.discard(name)
            if not candidates:
                return None
    return candidates.pop() if checked and len(candidates) == 1 else None


def find_protocol(sweep_dir: str, results) -> tuple[str | None, str]:
    """(protocol name or None, how it was found): the sweep folder's name when it is a protocol's (``jaxmac sweep``'s
    default folder), else the protocol the cells' configurations match."""
    folder = os.path.basename(os.path.normpath(sweep_dir))
    if folder in PROTOCOLS:
        return folder, "the sweep folder's name"
    name = protocol_of_configs(sweep_dir, results)
    if name is not None:
        return name, "the cells' configurations match it"
    return None, (f"not recognised: the folder `{folder}` is no protocol's name and the cells' configurations match "
                  "no single protocol")


def _budgets_text(cells) -> str:
    """Episodes per seed by scenario family: "32 on every cell" or "4,000 (boxpushing), 2,000 (overcooked)"."""
    budgets: dict[str, set[int]] = {}
    for c in cells:
        budgets.setdefault(family(c.scenario), set()).add(c.budget)
    if len({b for bs in budgets.values() for b in bs}) == 1:
        return f"{next(iter(next(iter(budgets.values())))):,} on every cell"
    return ", ".join((f"{min(bs):,}" if len(bs) == 1 else f"{min(bs):,}–{max(bs):,}") + f" ({fam})"
                     for fam, bs in sorted(budgets.items()))


def header_lines(sweep_dir: str, results, experiments: list[str], protocol: str | None, how: str, progress=None,
                 rates: dict | None = None, not_started: list[Cell] = ()) -> list[str]:
    """What the page was made from: the protocol, the finished cells, their seeds and budgets, the cells that ended
    early, the cells still running (how far, what they still cost), the experiments that have not run, how many cells
    no run has begun (``not_started``: ``not_started_cells``) and what they cost, and — below 2 seeds — why the page
    decides nothing there."""
    from jaxmac.study.sweep import plan

    wanted = {(s, m.name) for e in experiments for m in EXPERIMENTS[e][0] for s in EXPERIMENTS[e][1]}
    cells = [c for key, c in results.items() if key in wanted]
    if protocol in PROTOCOLS:
        proto = PROTOCOLS[protocol]
        planned = len({c.path for e in experiments for c in plan(e, protocol)})
        lines = [f"**Protocol: {protocol}** ({how}): {proto.about}.", ""]
        of_planned = f" of the {planned} this protocol plans for these experiments"
    else:
        lines, of_planned = [f"**Protocol: {how}.**", ""], ""
    if cells:
        seeds = sorted(_seeds(c) for c in cells)
        seeds_text = f"{seeds[0]}" if seeds[0] == seeds[-1] else f"{seeds[0]}–{seeds[-1]} (min–max)"
        lines += [f"**Finished cells: {len(cells)}**{of_planned}; **seeds per cell: {seeds_text}**; episodes per "
                  f"seed: {_budgets_text(cells)}.", ""]
    else:
        lines += [f"**Finished cells: none**{of_planned}.", ""]
    ended = [f"{c.scenario}/{c.method}/{folder}: {why}" for c in cells for folder, why in c.ended_early]
    if ended:
        lines += ["**Ended early** (the protocol's rule; the episodes column of their tables says where):", ""]
        lines += [f"- {e}" for e in ended] + [""]
    running = sorted(key for key in (progress or {}) if key in wanted)
    if running:
        lines += ["**Not finished yet** (running or interrupted, which `jaxmac sweep` resumes, or stopped by the "
                  "divergence guard, which it does not rerun):", ""]
        lines += [f"- {s}/{m}: {progress_text(progress[(s, m)], s, m, rates)}" for s, m in running] + [""]
    not_run = [e for e in experiments if not _has_finished_cell(results, e, protocol=protocol)]
    if not_run:
        lines += [f"Not run (no finished cell): {', '.join(not_run)}.", ""]
    if not_started:
        lines += [f"**Not started: {len(not_started)} cells** the protocol plans ({_not_started_total(not_started, rates)}"
                  "; each with its cost under [Cells not started](#cells-not-started)).", ""]
    few = [c for c in cells if _seeds(c) < MIN_SEEDS]
    if few:
        share = "every finished cell has" if len(few) == len(cells) else f"{len(few)} of {len(cells)} cells have"
        lines += [f"**Fewer than {MIN_SEEDS} seeds:** {share} fewer than {MIN_SEEDS} seeds, so their scenarios name no "
                  f"winner and get no p-values or intervals, and the paper's questions are not answered from "
                  f"them: {NO_TEST_WHY}. Seeds A..B-1 are added to the same cells, and merged with theirs, by "
                  f"`jaxmac sweep EXPERIMENT{' --protocol ' + protocol if protocol in PROTOCOLS else ''} --seeds A:B`"
                  f"{' (here e.g. `--seeds 1:4`)' if all(c.seeds == [0] for c in cells) else ''}.", ""]
    return lines


def write_page(sweep_dir: str, out_dir: str, experiments: list[str], protocol: str | None = None,
               rates: dict | None = None) -> str:
    """Write ``out_dir/RESULTS.md`` and the figures; returns the page's path. ``protocol`` (default:
    ``find_protocol``'s) gives the reasons of cells it leaves out and the header's description; ``rates``
    (``jaxmac calibrate``'s measured training rates) what the cells not finished still cost."""
    results = load_sweep(sweep_dir) if os.path.isdir(sweep_dir) else {}
    progress = load_progress(sweep_dir) if os.path.isdir(sweep_dir) else {}
    if protocol is None:
        protocol, how = find_protocol(sweep_dir, results)
    elif protocol in PROTOCOLS:
        how = "as given"
    else:
        protocol, how = None, f"not recognised: {protocol!r} is no protocol's name"
    os.makedirs(out_dir, exist_ok=True)
    lines = ["# Results of the sweep", "", f"Generated by `jaxmac results {sweep_dir}` from the finished run folders. "
             "Final return: evaluation return averaged over a run's last 10 evaluations, per seed; mean ± s.e. over "
             "seeds.", ""]
    not_started = not_started_cells(experiments, protocol, results, progress)
    lines += header_lines(sweep_dir, results, experiments, protocol, how, progress, rates, not_started)
    lines += ["## Headline", ""]
    tables = [headline_table(results, [e for e in group if e in experiments], protocol) for group in HEADLINE_GROUPS
              if any(e in experiments for e in group)]
    for table in tables:
        lines += table
    if any(tables):
        lines += ["Mean final return over seeds (its fraction of the scenario's ceiling); the best of each row in bold "
                  f"where every finished cell of the row has at least {MIN_SEEDS} seeds; n.r.: not run under this "
                  "protocol (reason in the experiment's table); …: not finished; a scenario with no finished cell has no "
                  "row.", ""]
    else:
        lines += ["No finished cell yet.", ""]
    labels = {m.name: m.label or m.name for ms, _ in EXPERIMENTS.values() for m in ms}
    labels["tomacvf"] = "ToMacVF"  # not the mixers experiment's "ToMacVF_QMIX"
    lines += questions_section(results, labels)
    for experiment in experiments:
        if not _has_finished_cell(results, experiment, protocol=protocol):
            continue  # named in the header's "Not run" line
        lines += [f"## {experiment}", ""]
        if experiment_figure(results, experiment, os.path.join(out_dir, experiment), protocol=protocol):
            lines += [f"![{experiment}]({experiment}.png)", ""]
        methods, scenarios = EXPERIMENTS[experiment]
        # a scenario the protocol leaves the experiment out of, or no cell of which has finished or started, gets
        # one line; the others their table
        left_out = {s: why for s in scenarios if (why := _left_out_reason(protocol, methods, s))}
        idle = [s for s in scenarios if s not in left_out
                and not any((s, m.name) in results or (s, m.name) in progress for m in methods)]
        for scenario in scenarios:
            if scenario not in idle and scenario not in left_out:
                lines += scenario_table(results, experiment, scenario, protocol, progress, rates)
        if idle:
            lines += [f"No method has finished on {', '.join(idle)} yet.", ""]
        for why in dict.fromkeys(left_out.values()):
            lines += [f"Not run on {', '.join(s for s in left_out if left_out[s] == why)} under this protocol: "
                      f"{why}.", ""]
        lines += aggregate_lines(results, experiment, protocol)
    lines += not_started_section(not_started, protocol, rates)
    path = os.path.join(out_dir, "RESULTS.md")
    with open(path, "w") as f:
        f.write("\n".join(lines))
    return path
