"""ToMacVF on Mac-SJERT against ToMacVF on Mac-JERT, side by side at equal episode budgets.

    python benchmarks/sjert_vs_jert.py --scenario boxpushing-6x6 --episodes 4000 --seeds 4 [--set KEY=VALUE ...]
                                       [--out experiments/sjert_vs_jert] [--devices 2]

Trains two run folders one after the other in this process (``OUT/<scenario>/tomacvf/…`` and
``OUT/<scenario>/tomacvf-wo-sjert/…``, the sweep's ``tomacvf`` and ``tomacvf-wo-sjert`` methods: Mac-JERT is the
squeezed joint sequence of macro-observations, not packed), skipping a finished one and resuming an interrupted one,
then prints one table — final return (mean ± s.e. of each seed's last 10 evaluations), Welch's p-value, wall time,
training episodes and gradient steps per second, bytes per stored episode (the ring's slot, which both views read)
and per materialised view (Mac-SJERT's micro- and macro-views against the Mac-JERT view) — and writes one figure of
both learning curves (mean ± s.e.) to ``OUT/<scenario>/sjert_vs_jert.png``. Time it on an otherwise idle machine.
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


def run_row(run_dir: str) -> dict:
    """The table's numbers for one finished run folder."""
    import pandas as pd

    from jaxmac.study.stats import final_returns, load_run_result

    seeds, episodes, curves, summary = load_run_result(run_dir)
    metrics = pd.read_csv(os.path.join(run_dir, "metrics.csv"))
    updates = metrics.groupby("seed")["updates"].max().sum()
    wall = summary["wall_seconds"]
    return {"finals": final_returns(curves), "episodes": episodes, "curves": curves, "wall_s": wall,
            "episodes_per_s": len(seeds) * summary["episodes"] / wall, "updates_per_s": updates / wall}


def main(argv=None) -> None:
    from jaxmac.cli import seed_range
    from jaxmac.scenarios import SCENARIOS

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="boxpushing-6x6", choices=list(SCENARIOS))
    p.add_argument("--episodes", type=int, default=4000, help="training episodes per seed, both runs")
    p.add_argument("--seeds", type=seed_range, default=(0, 4), help="N (seeds 0..N-1) or A:B")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="KEY=VALUE",
                   help="a setting for both runs (repeatable)")
    p.add_argument("--devices", type=int, default=1, help="host devices the seeds are sharded over")
    p.add_argument("--out", default=os.path.join("experiments", "sjert_vs_jert"))
    p.add_argument("--tiny", action="store_true", help="tiny networks (a smoke check of the command, not a result)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if args.episodes < 1:
        raise SystemExit(f"--episodes {args.episodes}: need at least 1")

    from jaxmac.runs import enable_compilation_cache, use_host_devices

    use_host_devices(args.devices)  # before JAX starts
    from jaxmac.presets import scenario_config
    from jaxmac.plotting import plot_curves
    from jaxmac.study.stats import welch_p
    from jaxmac.study.sweep import TOMACVF, WO_SJERT, Cell, run_sweep

    extra = scenario_config(args.scenario, tiny=args.tiny).override_strings(args.assignments).flat_dict()
    base = scenario_config(args.scenario, tiny=args.tiny).flat_dict()
    changed = tuple((k, v) for k, v in extra.items() if base[k] != v)
    methods = [dataclasses.replace(m, overrides=changed + m.overrides) for m in (TOMACVF, WO_SJERT)]
    first, count = args.seeds
    cells = [Cell("sjert_vs_jert", m, args.scenario, first, count, args.episodes, args.tiny) for m in methods]
    enable_compilation_cache()
    run_sweep(cells, args.out, devices=args.devices, progress=not args.no_progress)

    rows = {m.label: run_row(os.path.join(args.out, c.path)) for m, c in zip(methods, cells)}
    sizes = view_bytes(cells[0].config())
    sjert, jert = rows[TOMACVF.label], rows[WO_SJERT.label]
    print(f"\n{args.scenario}, {count} seeds x {args.episodes} episodes, settings changed: {dict(changed) or 'none'}")
    print("| buffer | final return | Welch p | wall s (compile included) | episodes/s | gradient steps/s | stored bytes/episode "
          "| view bytes/episode |")
    print("|---|---|---|---|---|---|---|---|")
    for label, row, view in ((TOMACVF.label, sjert, sizes["sjert_views"]), (WO_SJERT.label, jert, sizes["jert_view"])):
        f = row["finals"]
        final = f"{f.mean():.1f} ± {f.std(ddof=1) / np.sqrt(len(f)):.1f}" if len(f) > 1 else f"{f.mean():.1f}"
        p_value = "–" if row is sjert or len(f) < 2 else f"{welch_p(sjert['finals'], f):.3g}"
        print(f"| {label} | {final} | {p_value} | {row['wall_s']:.0f} | {row['episodes_per_s']:.1f} "
              f"| {row['updates_per_s']:.2f} | {sizes['slot']:,} | {view:,} |")
    png = os.path.join(args.out, args.scenario, "sjert_vs_jert.png")
    plot_curves([(label, r["episodes"], r["curves"]) for label, r in rows.items()], png,
                f"{args.scenario}: ToMacVF, Mac-SJERT vs Mac-JERT ({count} seeds)", pdf=True)
    with open(os.path.join(args.out, args.scenario, "sjert_vs_jert.json"), "w") as fh:
        json.dump({"bytes": sizes, **{label: {"finals": r["finals"].tolist(), "wall_s": r["wall_s"],
                                              "episodes_per_s": r["episodes_per_s"],
                                              "updates_per_s": r["updates_per_s"]} for label, r in rows.items()}},
                  fh, indent=1)
    print(f"wrote {png}")


if __name__ == "__main__":
    main()
