"""Ending a run before its budget once its learning curves have settled (the ``full`` sweep protocol's rule).

A run *has settled* when it has trained at least ``min_episodes`` episodes per seed and, for every seed, each
evaluation of the last ``window`` episodes lies within ``tolerance`` of that seed's level — the mean of those same
evaluations — relative to the level's magnitude (at least 1). ``settled_reason`` reads ``metrics.csv`` and returns
a sentence saying so (what the run folder's ``summary.json`` records as ``ended_early``), or None.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxmac.plotting import read_eval_curves


@dataclasses.dataclass(frozen=True)
class SettledRule:
    """End a run once every seed's evaluations of the last ``window`` episodes stay within ``tolerance`` of their
    mean, after at least ``min_episodes`` episodes per seed. ``column``: the metrics.csv column read."""

    min_episodes: int = 40_000
    window: int = 20_000
    tolerance: float = 0.02
    column: str = "eval_disc_return"

    def __post_init__(self):
        if not (isinstance(self.min_episodes, int) and isinstance(self.window, int) and 0 < self.window
                and self.window <= self.min_episodes):
            raise ValueError(f"SettledRule: need integers 0 < window ({self.window!r}) <= min_episodes "
                             f"({self.min_episodes!r})")
        if not 0 < self.tolerance < 1:
            raise ValueError(f"SettledRule: tolerance={self.tolerance!r} must lie in (0, 1), e.g. 0.02 for 2 %")

    def reason(self, metrics_csv: str) -> str | None:
        """Why the run in ``metrics_csv`` may end now, or None while it may not."""
        episodes, values = read_eval_curves(metrics_csv, self.column)
        if values.size == 0 or episodes[-1] < self.min_episodes:
            return None
        recent = episodes > episodes[-1] - self.window
        if episodes[0] > episodes[-1] - self.window:  # fewer evaluations than the window covers
            return None
        window = values[:, recent]
        level = window.mean(axis=1, keepdims=True)
        spread = np.max(np.abs(window - level) / np.maximum(np.abs(level), 1.0), axis=1)
        if np.all(spread <= self.tolerance):
            return (f"settled at {int(episodes[-1])} episodes per seed: every seed's evaluations of the last "
                    f"{self.window} episodes within {spread.max():.1%} of their mean (rule: {self.tolerance:.0%} "
                    f"after {self.min_episodes})")
        return None
