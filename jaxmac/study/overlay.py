"""One figure overlaying learning curves (mean ± s.e. over seeds) of jaxmac runs and of original MacroMARL runs
(``jaxmac overlay``).

    jaxmac overlay --out fig.png [--title T] [--optimum 270.6] \\
        --run "Mac-Cen-DDRQN (jaxmac)=experiments/results/RUN" \\
        --original "MacCen-Q (original)=/path/orig/s0,/path/orig/s1"

``--run LABEL=DIR`` reads a run folder's ``metrics.csv`` (its evaluation return: greedy for the value learners,
sampled from the policy for the actor-critics); ``--original LABEL=DIR,DIR`` reads ``test_returns.csv`` of each
seed's folder of an original MacroMARL run (columns eval, episodes, return — the original's logged evaluation
return, discounted with the training γ; e.g. experiments/results/original-maccen_q-boxpushing-6x6/seed0). A label ends at its first ``=``. Every curve is
smoothed over 10 evaluation points (DECISIONS D15) and cut to the evaluations all its seeds reached. Writes the PNG
``--out`` (a path relative to the current directory) and a PDF beside it.
"""

from __future__ import annotations

import argparse
import csv
import os


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``jaxmac overlay``'s arguments (the CLI's subcommand and ``main`` share them)."""
    p.add_argument("--run", action="append", default=[], metavar="LABEL=DIR",
                   help="a jaxmac run folder's curve (its metrics.csv); repeat for more")
    p.add_argument("--original", action="append", default=[], metavar="LABEL=DIR[,DIR…]",
                   help="an original MacroMARL run's curve, one folder (test_returns.csv) per seed; repeat for more")
    p.add_argument("--out", required=True, help="the PNG to write (a PDF is written beside it)")
    p.add_argument("--title", default="")
    p.add_argument("--optimum", type=float, default=None, help="draw the optimal return as a line")


def read_original(dirs: list[str]):
    """``episodes [P]`` and ``values [seeds, P]`` of original runs (one folder per seed)."""
    import numpy as np

    curves = []
    for d in dirs:
        with open(os.path.join(d, "test_returns.csv"), newline="") as f:
            rows = list(csv.DictReader(f))
        curves.append((np.array([int(r["episodes"]) for r in rows]), np.array([float(r["return"]) for r in rows])))
    points = min(len(e) for e, _ in curves)
    return curves[0][0][:points], np.stack([v[:points] for _, v in curves])


def _labelled(item: str) -> tuple[str, str]:
    label, sep, value = item.partition("=")
    if not sep:
        raise ValueError(f"expected LABEL=PATH, got {item!r}")
    return label, value


def run(args: argparse.Namespace) -> int:
    """``jaxmac overlay``: read the curves, draw them on one axis, print each one's final mean."""
    from jaxmac.plotting import plot_curves, read_eval_curves

    curves = []
    for item in args.run:
        label, path = _labelled(item)
        curves.append((label, *read_eval_curves(os.path.join(path, "metrics.csv"))))
    for item in args.original:
        label, paths = _labelled(item)
        curves.append((label, *read_original(paths.split(","))))
    if not curves:
        raise ValueError("nothing to draw: give --run LABEL=DIR or --original LABEL=DIR[,DIR…]")
    plot_curves(curves, args.out, args.title, args.optimum, pdf=True)
    for label, episodes, values in curves:
        final = values[:, -10:].mean(1)
        print(f"{label}: {values.shape[0]} seeds, {episodes[-1]} episodes; mean of the last 10 evaluations "
              f"{final.mean():.1f} (per seed {' '.join(f'{v:.1f}' for v in final)})")
    print(f"wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``jaxmac overlay ARGS`` from Python."""
    p = argparse.ArgumentParser(prog="jaxmac overlay", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))
