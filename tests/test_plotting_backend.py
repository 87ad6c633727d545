"""Library plotting never switches matplotlib's global backend (a notebook's inline plots would vanish): figures are
drawn on ``matplotlib.figure.Figure`` objects, which carry their own canvas. Checked in a fresh process whose backend
is set by ``MPLBACKEND`` to one that is not Agg."""

from __future__ import annotations

import os
import subprocess
import sys

SCRIPT = r"""
import csv, os, sys
import matplotlib
before = matplotlib.get_backend()
import jaxmac.runs.evaluation
import jaxmac.plotting

out = sys.argv[1]
metrics = os.path.join(out, "metrics.csv")
with open(metrics, "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["seed", "episodes", "eval_disc_return"])
    for seed in range(2):
        for k in range(12):
            w.writerow([seed, 50 * k, float(k + seed)])
jaxmac.plotting.plot_learning_curve(metrics, os.path.join(out, "curve.png"), "fake run", 12.0, label="greedy return")
jaxmac.runs.evaluation.save_strip([f"step {t}\n.#.\n#.#" for t in range(5)], os.path.join(out, "strip.png"))
print("BACKENDS", before, matplotlib.get_backend())
print("PYPLOT", "matplotlib.pyplot" in sys.modules)
"""


def test_plotting_keeps_the_global_backend(tmp_path):
    env = dict(os.environ, MPLBACKEND="svg")
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path)], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if " " in line)
    assert lines["BACKENDS"].split() == ["svg", "svg"]
    assert lines["PYPLOT"] == "False"  # pyplot (and its global figure list) is never imported
    for name in ("curve.png", "strip.png"):
        with open(tmp_path / name, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n", name


def test_episode_axis_ticks_are_written_in_thousands():
    from matplotlib.figure import Figure

    from jaxmac.plotting import label_episode_axis

    ax = Figure().subplots()
    label_episode_axis(ax)
    tick = ax.xaxis.get_major_formatter()
    assert [tick(x, 0) for x in (0, 500, 2500, 40000, 120000)] == ["0", "500", "2.5K", "40K", "120K"]
    assert ax.get_xlabel() == "training episodes"
