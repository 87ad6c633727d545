"""One figure overlaying learning curves (mean ± s.e. over seeds) of jaxmac runs and of original MacroMARL runs.

    python experiments/overlay_curves.py --out fig.png [--title T] [--optimum 270.6] \\
        --run "Mac-Cen-DDRQN (jaxmac)=experiments/results/RUN" \\
        --original "MacCen-Q (original)=/path/orig/s0,/path/orig/s1"

``--run LABEL=DIR`` reads a run folder's ``metrics.csv`` (its evaluation return: greedy for the value learners,
sampled from the policy for the actor-critics); ``--original LABEL=DIR,DIR`` reads ``test_returns.csv`` of each
seed's folder written by ``shared/reference/originals/run_macromarl.py`` (columns eval, episodes, return — the
original's logged evaluation return, discounted with the training γ). A label ends at its first ``=``. Every curve is smoothed over 10 evaluation points (DECISIONS D15) and
cut to the evaluations all its seeds reached. Writes PNG and PDF.
"""

from __future__ import annotations

import argparse
import csv
import os

import numpy as np

from jaxmac.plotting import plot_curves, read_eval_curves


def read_original(dirs: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``episodes [P]`` and ``values [seeds, P]`` of original runs (one folder per seed)."""
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
        raise SystemExit(f"expected LABEL=PATH, got {item!r}")
    return label, value


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", action="append", default=[], metavar="LABEL=DIR")
    p.add_argument("--original", action="append", default=[], metavar="LABEL=DIR[,DIR…]")
    p.add_argument("--out", required=True)
    p.add_argument("--title", default="")
    p.add_argument("--optimum", type=float, default=None)
    args = p.parse_args(argv)
    curves = []
    for item in args.run:
        label, path = _labelled(item)
        curves.append((label, *read_eval_curves(os.path.join(path, "metrics.csv"))))
    for item in args.original:
        label, paths = _labelled(item)
        curves.append((label, *read_original(paths.split(","))))
    plot_curves(curves, args.out, args.title, args.optimum, pdf=True)
    for label, episodes, values in curves:
        final = values[:, -10:].mean(1)
        print(f"{label}: {values.shape[0]} seeds, {episodes[-1]} episodes; mean of the last 10 evaluations "
              f"{final.mean():.1f} (per seed {' '.join(f'{v:.1f}' for v in final)})")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
