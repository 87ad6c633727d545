"""The results page of a sweep: per experiment its figure, one table per scenario and the aggregates.

    python experiments/results_page.py [SWEEP_DIR] [--out experiments/results/sweep-PROTOCOL] [--experiments bp ...]

Reads the finished cells of ``SWEEP_DIR`` (default ``experiments/sweeps/cpu``, written by ``jaxmac sweep``) and writes
``OUT/RESULTS.md`` with headline tables (one row per scenario, one column per method), the paper's four questions
answered from the finished cells (ToMacVF against the baselines, the two ablations, the mixers) and, for each
experiment: the paper's figure (one panel per scenario, one curve per method,
mean ± s.e. over seeds of the 10-point moving average, the ceiling dashed; ``OUT/<experiment>.png`` and ``.pdf``), a
table per scenario (seeds, budget, final return mean ± s.e. with its bootstrap 95 % interval, fraction of the ceiling,
Welch's p against ToMacVF, wall time; the best mean in bold; a "who wins" line: the best and the methods Welch's test
cannot tell from it) and, where every method finished every scenario, the
IQM of ceiling-normalised final returns and ToMacVF's probability of improvement over each method (``jaxmac.stats``).
Cells not finished are listed as "not run".
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from jaxmac.plotting import mean_and_standard_error, save_figure, smooth
from jaxmac.scenarios import CEILINGS
from jaxmac.stats import aggregate, compare_methods, load_sweep, welch_p, who_wins
from jaxmac.sweep import EXPERIMENTS, PROTOCOLS

REFERENCE = "tomacvf"


def method_colours() -> dict[str, str]:
    """One colour per method name across every figure."""
    names = sorted({m.name for methods, _ in EXPERIMENTS.values() for m in methods})
    palette = [f"C{k}" for k in range(10)] + ["#8c564b", "#17becf", "#bcbd22", "#7f7f7f", "#000080"]
    return {name: palette[k % len(palette)] for k, name in enumerate(names)}


def experiment_figure(results, experiment: str, out_base: str, window: int = 10) -> bool:
    """One panel per scenario of ``experiment``; False when no cell of it has finished."""
    from matplotlib.figure import Figure  # its own Agg canvas: never touches pyplot's backend or figure list

    methods, scenarios = EXPERIMENTS[experiment]
    if not any((s, m.name) in results for s in scenarios for m in methods):
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
            ax.plot(cell.episodes, mean, color=colours[method.name], label=method.label or method.name, lw=1.2)
            ax.fill_between(cell.episodes, mean - se, mean + se, color=colours[method.name], alpha=0.2)
        if scenario in CEILINGS:
            ax.axhline(CEILINGS[scenario], color="k", ls="--", lw=1)
        ax.set_title(scenario, fontsize=10)
        ax.set_xlabel("training episodes")
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


def scenario_table(results, experiment: str, scenario: str, protocol: str | None = None) -> list[str]:
    methods, _ = EXPERIMENTS[experiment]
    cells = [results[(scenario, m.name)] for m in methods if (scenario, m.name) in results]
    labels = {m.name: m.label or m.name for m in methods}
    lines = [f"**{scenario}** (ceiling {CEILINGS.get(scenario, float('nan')):.1f})", "",
             "| method | seeds | episodes/seed | final return | 95 % CI | of ceiling | p vs ToMacVF | wall time |",
             "|---|---|---|---|---|---|---|---|"]
    for r in compare_methods(cells, REFERENCE):
        value = f"{r['mean']:.1f} ± {r['se']:.1f}" if not np.isnan(r["se"]) else f"{r['mean']:.1f}"
        value = f"**{value}**" if r["best"] else value
        lines.append(f"| {labels[r['method']]} | {r['seeds']} | {r['budget']:,} | {value} | "
                     f"[{r['ci'][0]:.1f}, {r['ci'][1]:.1f}] | {100 * r['of_ceiling']:.0f} % | "
                     f"{_fmt_p(r['p_vs_reference'])} | {r['wall_seconds'] / 60:.0f} min |")
    for m in methods:
        if (scenario, m.name) not in results:
            why = _not_run_reason(protocol, m.name, scenario)
            status = f"not run: {why}" if why else "not finished yet"
            lines.append(f"| {labels[m.name]} | {status} | | | | | | |")
    if len(cells) == 1:
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
    ceiling, the scenario's best in bold; "n.r." a cell the protocol leaves out, "…" one not finished, "" a method
    the experiment does not have."""
    columns: dict[str, str] = {}
    for experiment in experiments:
        for m in EXPERIMENTS[experiment][0]:
            columns.setdefault(m.name, m.label or m.name)
    lines = ["| experiment | scenario | " + " | ".join(columns.values()) + " |",
             "|---|---|" + "---|" * len(columns)]
    for experiment in experiments:
        methods, scenarios = EXPERIMENTS[experiment]
        names = {m.name for m in methods}
        for scenario in scenarios:
            cells = [results[(scenario, n)] for n in columns if n in names and (scenario, n) in results]
            best = who_wins(cells)[0] if cells else None
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
    of them; a method the protocol leaves out on some scenario is named and left out of the aggregates."""
    methods, scenarios = EXPERIMENTS[experiment]
    labels = {m.name: m.label or m.name for m in methods}
    left_out = [m.name for m in methods if any(_not_run_reason(protocol, m.name, s) for s in scenarios)]
    names = [m.name for m in methods if m.name not in left_out]
    if not names:
        return ["Aggregates: no method runs on every scenario under this protocol.", ""]
    if any((s, n) not in results for s in scenarios for n in names):
        return ["Aggregates: not every method has finished every scenario yet.", ""]
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


def _difference(results, scenario: str, method: str, other: str) -> str | None:
    """"mean(method) − mean(other) = d (Welch p)" on ``scenario``, None when either cell is not finished."""
    a, b = results.get((scenario, method)), results.get((scenario, other))
    if a is None or b is None:
        return None
    return f"{a.finals.mean() - b.finals.mean():+.1f} (p {_fmt_p(welch_p(a.finals, b.finals))})"


def questions_section(results, labels: dict[str, str]) -> list[str]:
    """The paper's four questions answered from the finished cells, one line per question and scenario group."""
    lines = ["## The paper's four questions", "",
             "Counted from the finished cells only; \"told apart\" means Welch's p < 0.05 with the seeds of this "
             "protocol.", ""]
    lines += ["**1. Does ToMacVF beat the asynchronous baselines?**", ""]
    baselines = [m.name for m in EXPERIMENTS["bp"][0] if not m.name.startswith("tomacvf")]
    for variant in ("tomacvf", "tomacvf-tuned", "tomacvf-paper"):
        won, tied, below, scenarios = [], [], [], 0
        for experiment in ("bp", "warehouse", "overcooked"):
            methods, exp_scenarios = EXPERIMENTS[experiment]
            for scenario in exp_scenarios:
                others = [results[(scenario, m.name)] for m in methods
                          if m.name in baselines and (scenario, m.name) in results]
                own = results.get((scenario, variant))
                if own is None or not others:
                    continue
                scenarios += 1
                best, close = who_wins(others + [own])
                if best == variant:
                    won.append(scenario)
                elif variant in close:
                    tied.append(f"{scenario} (best {labels[best]})")
                else:
                    below.append(f"{scenario} ({labels[best]})")
        if scenarios:
            lines.append(f"- {labels[variant]}, {scenarios} scenarios with baselines finished: best mean on "
                         f"{len(won)}{' (' + ', '.join(won) + ')' if won else ''}; not told apart from the best on "
                         f"{len(tied)}{' (' + ', '.join(tied) + ')' if tied else ''}; below the best, told apart, on "
                         f"{len(below)}{' (' + ', '.join(below) + ')' if below else ''}.")
    for number, (question, other) in enumerate((("Does ATPG help?", "tomacvf-wo-atpg"),
                                                 ("Does Mac-SJERT help (against Mac-JERT)?", "tomacvf-wo-sjert")), 2):
        lines += ["", f"**{number}. {question}** ToMacVF minus {labels[other]}, mean final return:", ""]
        found = [(sc, _difference(results, sc, "tomacvf", other)) for sc in EXPERIMENTS["ablation"][1]]
        lines += [f"- {sc}: {d}" for sc, d in found if d] or ["- no finished pair yet"]
        pairs = [(results[(sc, "tomacvf")].finals, results[(sc, other)].finals) for sc, d in found if d]
        if pairs:
            helps = sum(a.mean() > b.mean() and welch_p(a, b) < 0.05 for a, b in pairs)
            hurts = sum(a.mean() < b.mean() and welch_p(a, b) < 0.05 for a, b in pairs)
            lines.append(f"- Verdict: ToMacVF above {labels[other]}, told apart, on {helps} of {len(pairs)} "
                         f"scenarios; below it, told apart, on {hurts}.")
    lines += ["", "**4. Which mixer suits ToMacVF?** Who wins among QMIX, VDN, QPLEX and QTRAN:", ""]
    mixers, mixer_scenarios = EXPERIMENTS["mixers"]
    labels = {**labels, **{m.name: m.label or m.name for m in mixers}}  # ToMacVF is named by its mixer here
    winners = {}
    for scenario in mixer_scenarios:
        cells = [results[(scenario, m.name)] for m in mixers if (scenario, m.name) in results]
        if len(cells) == len(mixers):
            winners[scenario] = who_wins(cells)
    lines += [f"- {scenario}: **{labels[best]}**" + (f"; not told apart: {', '.join(labels[c] for c in close)}"
                                                     if close else "; the others told apart below it")
              for scenario, (best, close) in winners.items()] or ["- no scenario with all four mixers finished yet"]
    if winners:
        qmix = mixers[0].name  # ToMacVF's own mixer, the paper's pick
        alone = sum(best == qmix and not close for best, close in winners.values())
        lines.append(f"- Verdict: {labels[qmix]} is best and told apart from the other three on {alone} of "
                     f"{len(winners)} scenarios.")
    return lines + [""]


def write_page(sweep_dir: str, out_dir: str, experiments: list[str], protocol: str | None = None) -> str:
    """``protocol`` (default: the sweep folder's name, when it is one) gives the reasons of cells it leaves out."""
    if protocol is None:
        protocol = os.path.basename(os.path.normpath(sweep_dir))
    results = load_sweep(sweep_dir) if os.path.isdir(sweep_dir) else {}
    os.makedirs(out_dir, exist_ok=True)
    lines = ["# Results of the sweep", "", f"Generated by `python experiments/results_page.py {sweep_dir}` from the "
             "finished run folders. Final return: evaluation return averaged over a run's last 10 evaluations, per "
             "seed; mean ± s.e. over seeds.", "", "## Headline", ""]
    for group in HEADLINE_GROUPS:
        if any(e in experiments for e in group):
            lines += headline_table(results, [e for e in group if e in experiments], protocol)
    lines += ["Mean final return over seeds (its fraction of the scenario's ceiling); the best of each row in bold; "
              "n.r.: not run under this protocol (reason in the experiment's table); …: not finished.", ""]
    labels = {m.name: m.label or m.name for ms, _ in EXPERIMENTS.values() for m in ms}
    labels["tomacvf"] = "ToMacVF"  # not the mixers experiment's "ToMacVF_QMIX"
    lines += questions_section(results, labels)
    for experiment in experiments:
        lines += [f"## {experiment}", ""]
        if experiment_figure(results, experiment, os.path.join(out_dir, experiment)):
            lines += [f"![{experiment}]({experiment}.png)", ""]
        for scenario in EXPERIMENTS[experiment][1]:
            lines += scenario_table(results, experiment, scenario, protocol)
        lines += aggregate_lines(results, experiment, protocol)
    path = os.path.join(out_dir, "RESULTS.md")
    with open(path, "w") as f:
        f.write("\n".join(lines))
    return path


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("sweep_dir", nargs="?", default=os.path.join("experiments", "sweeps", "cpu"))
    p.add_argument("--out", default=None, help="default: experiments/results/sweep-<the sweep folder's name>")
    p.add_argument("--experiments", nargs="+", default=list(EXPERIMENTS), choices=list(EXPERIMENTS))
    args = p.parse_args(argv)
    out = args.out or os.path.join("experiments", "results", f"sweep-{os.path.basename(os.path.normpath(args.sweep_dir))}")
    print(f"wrote {write_page(args.sweep_dir, out, args.experiments)}")


if __name__ == "__main__":
    main()
