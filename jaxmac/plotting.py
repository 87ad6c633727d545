"""Learning curves from a run's ``metrics.csv`` (mean ± standard error over seeds)."""

from __future__ import annotations

import csv
import json
import math
import os
from collections import defaultdict

import numpy as np


def read_eval_curves(csv_path: str, column: str = "eval_disc_return") -> tuple[np.ndarray, np.ndarray]:
    """Evaluation points of every seed: ``episodes [P]`` and ``values [seeds, P]``."""
    per_seed: dict[int, list[tuple[int, float]]] = defaultdict(list)
    with open(csv_path, newline="") as f:
        for row in csv.DictReader(f):
            value = float(row[column])
            if not math.isnan(value):
                per_seed[int(row["seed"])].append((int(row["episodes"]), value))
    if not per_seed:
        return np.zeros(0), np.zeros((0, 0))
    seeds = sorted(per_seed)
    points = min(len(per_seed[s]) for s in seeds)
    episodes = np.array([e for e, _ in per_seed[seeds[0]][:points]])
    values = np.array([[v for _, v in per_seed[s][:points]] for s in seeds])
    return episodes, values


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over the last ``window`` points (DECISIONS D15), per row."""
    if window <= 1 or values.shape[-1] == 0:
        return values
    c = np.cumsum(np.pad(values, [(0, 0)] * (values.ndim - 1) + [(1, 0)]), axis=-1)
    idx = np.arange(values.shape[-1])
    lo = np.maximum(idx + 1 - window, 0)
    return (c[..., idx + 1] - c[..., lo]) / (idx + 1 - lo)


def mean_and_standard_error(values: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean over seeds (axis 0) and its standard error (``None`` for a single seed)."""
    values = np.asarray(values, dtype=np.float64)
    mean = values.mean(0)
    if values.shape[0] < 2:
        return mean, None
    return mean, values.std(0, ddof=1) / np.sqrt(values.shape[0])


def return_label(discount: float | None, what: str = "evaluation return") -> str:
    """The y-axis label of a return: which measure it is (the curves plot ``eval_disc_return``, Σ_t γ^t r_t)."""
    if discount is None:
        return f"{what} (discounted, Σ γ^t r_t)"
    if discount == 1.0:
        return f"{what} (γ = 1: undiscounted)"
    return f"{what} (discounted, γ = {discount:g})"


def run_discount(csv_path: str) -> float | None:
    """The discount of the run whose ``metrics.csv`` this is (its ``summary.json``), None if not written yet."""
    try:
        with open(os.path.join(os.path.dirname(os.path.abspath(csv_path)), "summary.json")) as f:
            value = json.load(f).get("discount")
    except (OSError, ValueError, AttributeError):
        return None
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def plot_curves(curves: list[tuple[str, np.ndarray, np.ndarray]], png_path: str, title: str,
                optimum: float | None = None, window: int = 10, pdf: bool = False,
                ylabel: str | None = None, discount: float | None = None) -> None:
    """Several learning curves on one axis: for each ``(label, episodes [P], values [seeds, P])`` the mean ± s.e.
    over seeds of the trailing ``window``-point moving average (DECISIONS D15; capped at a tenth of the points, so
    that a short run's last evaluations are not averaged with its first); ``pdf`` also writes a PDF. The
    evaluation return is greedy for the value learners and sampled from the policy for the actor-critics (as
    their originals evaluate). The y-axis names the measure: ``ylabel``, else ``return_label(discount)``."""
    from matplotlib.figure import Figure  # its own Agg canvas: never touches pyplot's backend or figure list

    points = max((len(episodes) for _, episodes, _ in curves), default=0)
    window = max(1, min(window, points // 10))
    fig = Figure(figsize=(6.4, 4.0), dpi=120)
    ax = fig.subplots()
    for label, episodes, values in curves:
        if not values.size:
            continue
        sm = smooth(values, window)
        mean, se = mean_and_standard_error(sm)
        se = np.zeros_like(mean) if se is None else se
        (line,) = ax.plot(episodes, mean, label=f"{label} ({sm.shape[0]} seeds)")
        ax.fill_between(episodes, mean - se, mean + se, alpha=0.25, color=line.get_color())
    if optimum is not None:
        ax.axhline(optimum, color="k", ls="--", lw=1, label=f"optimal ({optimum:.1f})")
    label_episode_axis(ax)
    ax.set_ylabel(ylabel or return_label(discount))
    smoothing = f"{window}-point moving average" if window > 1 else "not smoothed"
    ax.set_title(f"{title}\nmean ± s.e. over seeds, {smoothing}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, png_path, pdf)


def label_episode_axis(ax) -> None:
    """Name ``ax``'s x-axis "training episodes" and write its ticks in thousands ("40K"): six-digit tick labels of
    the paper's 100K-episode budgets run into each other on a narrow panel."""
    from matplotlib.ticker import FuncFormatter

    ax.set_xlabel("training episodes")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}K" if abs(x) >= 1000 else f"{x:g}"))


def save_figure(fig, png_path: str, pdf: bool = False) -> None:
    """Write ``fig`` to ``png_path`` and, with ``pdf``, beside it as PDF without a creation date, so that the same
    data give the same bytes (committed figures change only when their data do)."""
    fig.savefig(png_path)
    if pdf:
        fig.savefig(png_path.rsplit(".", 1)[0] + ".pdf", metadata={"CreationDate": None})


def plot_learning_curve(csv_path: str, png_path: str, title: str, optimum: float | None = None,
                        window: int = 10, label: str = "greedy return", discount: float | None = None) -> None:
    """Mean ± s.e. over seeds of the smoothed greedy evaluation return (discounted, ``eval_disc_return``) of one
    run's ``metrics.csv``; the y-axis names γ (``discount``, else the run's ``summary.json`` beside the CSV)."""
    episodes, values = read_eval_curves(csv_path)
    discount = run_discount(csv_path) if discount is None else discount
    plot_curves([(label, episodes, values)], png_path, title, optimum, window, discount=discount)
