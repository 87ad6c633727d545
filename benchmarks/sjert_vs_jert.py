"""ToMacVF on Mac-SJERT against ToMacVF on Mac-JERT, side by side at equal episode budgets.

    python benchmarks/sjert_vs_jert.py --scenario boxpushing-6x6 --episodes 4000 --seeds 4 [--set KEY=VALUE ...]
                                       [--out experiments/sjert_vs_jert] [--devices 2]
    python benchmarks/sjert_vs_jert.py --scenario overcooked-B --protocol full --seeds 0:2   # and 2:4 on a 2nd core
    python benchmarks/sjert_vs_jert.py --scenario overcooked-B --protocol full --report      # the table when done

Trains two run folders one after the other in this process (``OUT/<scenario>/tomacvf/…`` and
``OUT/<scenario>/tomacvf-wo-sjert/…``, the sweep's ``tomacvf`` and ``tomacvf-wo-sjert`` methods: Mac-JERT is the
squeezed joint sequence of macro-observations, not packed), skipping a finished one and resuming an interrupted one,
then prints one table — final return (mean ± s.e. of each seed's last 10 evaluations), Welch's p-value, episodes to
90 % of the ceiling (mean over the seeds that got there), wall time, training episodes and gradient steps per second,
bytes per stored episode (the ring's slot, which both views read) and per materialised view (Mac-SJERT's micro- and
macro-views against the Mac-JERT view) — and writes one figure of both learning curves (mean ± s.e.) to
``OUT/<scenario>/sjert_vs_jert.png``. Time it on an otherwise idle machine.

With ``--protocol NAME`` the two runs are that sweep protocol's cells (its budget for the scenario, its schedules and
its rule for ending early) in its sweep folder (default ``experiments/sweeps/NAME``): a cell the sweep already ran
is read, not run again, and two processes with ``--seeds 0:2`` and ``--seeds 2:4`` train the seed halves on two
cores. The table merges every finished seed range of the two methods in the folder; ``--report`` only prints it.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os

import numpy as np


def view_bytes(config) -> dict[str, int]:
    """Bytes per episode of the ring slot and of each materialised view, for ``config``'s env (shapes only)."""
    import jax

    from jaxmac.buffer import episode, views
    from jaxmac.config import make_env

    env = make_env(config)
    slot = episode.empty_slot(episode.SlotConfig.from_spec(env.spec))

    def size(tree) -> int:
        return int(sum(np.prod(x.shape) * x.dtype.itemsize for x in jax.tree_util.tree_leaves(tree)))

    return {"slot": size(slot),
            "sjert_views": size(jax.eval_shape(lambda s: views.micro_view(s, config.algo.n_step), slot))
            + size(jax.eval_shape(views.macro_view, slot)),
            "jert_view": size(jax.eval_shape(views.jert_view, slot))}


def run_row(out: str, scenario: str, method: str) -> dict | None:
    """The table's numbers for one method's finished seed ranges in ``OUT/<scenario>/<method>/`` (merged as a
    results page merges them, ``stats.load_cell``; rates are their seeds' episodes and gradient steps over their
    summed wall time); None when none has finished."""
    import pandas as pd

    from jaxmac.scenarios import CEILINGS
    from jaxmac.study.stats import episodes_to_fraction, load_cell, load_run_result, seed_range_folders

    method_dir = os.path.join(out, scenario, method)
    cell = load_cell(method_dir, scenario, method)
    if cell is None:
        return None
    runs = [os.path.join(method_dir, d) for d in seed_range_folders(method_dir, finished=True)]
    updates = sum(pd.read_csv(os.path.join(d, "metrics.csv")).groupby("seed")["updates"].max().sum() for d in runs)
    seed_episodes = sum(len(seeds) * summary["episodes"] for seeds, _, _, summary in map(load_run_result, runs))
    ceiling = CEILINGS.get(scenario)
    reach = (episodes_to_fraction(cell.episodes, cell.curves, 0.9 * ceiling) if ceiling is not None
             else np.full(len(cell.curves), np.nan))
    return {"finals": cell.finals, "episodes": cell.episodes, "curves": cell.curves, "wall_s": cell.wall_seconds,
            "episodes_per_s": seed_episodes / cell.wall_seconds, "updates_per_s": updates / cell.wall_seconds,
            "reach": reach, "ended_early": [why for _, why in cell.ended_early]}


def main(argv=None) -> None:
    from jaxmac.cli import seed_range
    from jaxmac.scenarios import SCENARIOS

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="boxpushing-6x6", choices=list(SCENARIOS))
    p.add_argument("--episodes", type=int, default=None, help="training episodes per seed, both runs (default 4000)")
    p.add_argument("--seeds", type=seed_range, default=(0, 4), help="N (seeds 0..N-1) or A:B")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="KEY=VALUE",
                   help="a setting for both runs (repeatable)")
    p.add_argument("--devices", type=int, default=1, help="host devices the seeds are sharded over")
    p.add_argument("--out", default=None,
                   help="folder of the runs (default experiments/sjert_vs_jert, or the protocol's sweep folder)")
    p.add_argument("--protocol", default=None,
                   help="run the two methods as this sweep protocol's cells (its budget, schedules and early end; "
                        "--episodes and --set are then refused)")
    p.add_argument("--report", action="store_true", help="train nothing: print the table of the finished runs")
    p.add_argument("--tiny", action="store_true", help="tiny networks (a smoke check of the command, not a result)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if args.episodes is not None and args.episodes < 1:
        raise SystemExit(f"--episodes {args.episodes}: need at least 1")

    from jaxmac.runs import enable_compilation_cache, use_host_devices

    use_host_devices(args.devices)  # before JAX starts
    from jaxmac.plotting import plot_curves
    from jaxmac.presets import scenario_config
    from jaxmac.study.stats import reach_summary, return_column, welch_p
    from jaxmac.study.sweep import PROTOCOLS, TOMACVF, WO_SJERT, Cell, fit_to_existing, protocol_cell, run_sweep

    first, count = args.seeds
    if args.protocol is not None:
        if args.protocol not in PROTOCOLS:
            raise SystemExit(f"--protocol {args.protocol!r}: valid protocols are {list(PROTOCOLS)}")
        if args.assignments or args.episodes is not None:
            raise SystemExit("--protocol sets the budget and the settings: drop --episodes and --set")
        out = args.out or os.path.join("experiments", "sweeps", args.protocol)
        methods, changed = [TOMACVF, WO_SJERT], ()
        for m in methods:
            if (why := PROTOCOLS[args.protocol].not_run_reason(m.name, args.scenario)) is not None:
                raise SystemExit(f"protocol {args.protocol} does not run {m.name} on {args.scenario}: {why}")
        cells = fit_to_existing([protocol_cell("sjert_vs_jert", args.protocol, m, args.scenario, first, count)
                                 for m in methods], out)
    else:
        out = args.out or os.path.join("experiments", "sjert_vs_jert")
        extra = scenario_config(args.scenario, tiny=args.tiny).override_strings(args.assignments).flat_dict()
        base = scenario_config(args.scenario, tiny=args.tiny).flat_dict()
        changed = tuple((k, v) for k, v in extra.items() if base[k] != v)
        methods = [dataclasses.replace(m, overrides=changed + m.overrides) for m in (TOMACVF, WO_SJERT)]
        episodes = 4000 if args.episodes is None else args.episodes
        cells = [Cell("sjert_vs_jert", m, args.scenario, first, count, episodes, args.tiny) for m in methods]
    if not args.report:
        enable_compilation_cache()
        run_sweep(cells, out, devices=args.devices, progress=not args.no_progress)

    rows = {m.label: run_row(out, args.scenario, m.name) for m in methods}
    missing = [label for label, row in rows.items() if row is None]
    if missing:
        raise SystemExit(f"no finished run of {', '.join(missing)} in {os.path.join(out, args.scenario)} yet")
    sizes = view_bytes(cells[0].config())
    sjert, jert = rows[TOMACVF.label], rows[WO_SJERT.label]
    seeds = {label: len(r["finals"]) for label, r in rows.items()}
    budget = f"{cells[0].episodes:,} episodes" + (f" ({args.protocol} protocol)" if args.protocol else "")
    print(f"\n{args.scenario}, seeds {seeds} x {budget}, settings changed: {dict(changed) or 'none'}")
    for label, r in rows.items():
        for why in r["ended_early"]:
            print(f"  {label} ended early: {why}")
    print("| buffer | final return | Welch p | episodes to 90 % | wall s (compile included) | episodes/s "
          "| gradient steps/s | stored bytes/episode | view bytes/episode |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, row, view in ((TOMACVF.label, sjert, sizes["sjert_views"]), (WO_SJERT.label, jert, sizes["jert_view"])):
        f = row["finals"]
        final = f"{f.mean():.1f} ± {f.std(ddof=1) / np.sqrt(len(f)):.1f}" if len(f) > 1 else f"{f.mean():.1f}"
        p_value = "–" if row is sjert or len(f) < 2 else f"{welch_p(sjert['finals'], f):.3g}"
        print(f"| {label} | {final} | {p_value} | {reach_summary(row['reach'])} | {row['wall_s']:.0f} "
              f"| {row['episodes_per_s']:.1f} | {row['updates_per_s']:.2f} | {sizes['slot']:,} | {view:,} |")
    png = os.path.join(out, args.scenario, "sjert_vs_jert.png")
    undiscounted = return_column(args.scenario) == "eval_return"  # the measure run_row read (Warehouse: γ 1)
    plot_curves([(label, r["episodes"], r["curves"]) for label, r in rows.items()], png,
                f"{args.scenario}: ToMacVF, Mac-SJERT vs Mac-JERT ({min(seeds.values())} seeds)", pdf=True,
                ylabel="evaluation return (undiscounted)" if undiscounted else None)
    with open(os.path.join(out, args.scenario, "sjert_vs_jert.json"), "w") as fh:
        json.dump({"bytes": sizes, **{label: {"finals": r["finals"].tolist(), "wall_s": r["wall_s"],
                                              "episodes_per_s": r["episodes_per_s"],
                                              "updates_per_s": r["updates_per_s"],
                                              "episodes_to_90": [None if np.isnan(e) else float(e) for e in r["reach"]],
                                              "ended_early": r["ended_early"]} for label, r in rows.items()}},
                  fh, indent=1)
    print(f"wrote {png}")


if __name__ == "__main__":
    main()
