"""The divergence guard's checks of a chunk's metrics: non-finite losses and norms (``check_finite``) and value
estimates outside the bounds every discounted return of the env lies in (``value_bounds_of``, ``flag_out_of_bounds``,
``out_of_bounds_message``). The run loop (``jaxmac.runs.loop``) stops a run they name (``RunDiverged``), keeping its last
good checkpoint and writing ``diverged.json`` (``diverged_record``).
"""

from __future__ import annotations

import json
import os

import numpy as np

from jaxmac.config import TrainConfig

# Metrics that must stay finite in every round with a gradient step (and param_norm in every round).
WATCHED = ("loss", "grad_norm", "param_norm")
# The value learners' mean value estimates, each a (mixed or per-agent) estimate of a discounted team return: they
# must stay inside the env's value bounds (``value_bounds``); the divergence guard watches them.
VALUE_METRICS = ("q_tot_mean", "cen_q_mean", "dec_q_mean")
OUT_OF_BOUNDS_COLUMN = "value_out_of_bounds"
DIVERGED_FILE = "diverged.json"  # in a run folder the guard stopped: what diverged, the chunk, the last good checkpoint
# The record of a diverged run that was resumed with other settings: kept beside the run, no longer a stop.
DIVERGED_PREVIOUS_FILE = "diverged.previous.json"


class RunDiverged(RuntimeError):
    """The divergence guard stopped a run: a metric went non-finite or a value estimate left the env's bounds. The
    run folder keeps ``diverged.json`` and its last good checkpoint; an exact resume would diverge again, so only a
    resume with other settings (``jaxmac train --resume RUN --set ...``) continues it."""


def set_aside_diverged(run_dir: str) -> None:
    """Rename the run folder ``run_dir``'s ``diverged.json`` to ``diverged.previous.json``: the run goes on with other
    settings, so it is no longer stopped, and what stopped it stays on record."""
    os.replace(os.path.join(run_dir, DIVERGED_FILE), os.path.join(run_dir, DIVERGED_PREVIOUS_FILE))


def diverged_record(run_dir: str) -> dict | None:
    """The guard's record of the run folder ``run_dir`` (``problem``, ``kind``, ``chunk``, ``last_good_checkpoint``),
    or None when the run did not diverge (or was resumed since with other settings)."""
    path = os.path.join(run_dir, DIVERGED_FILE)
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def check_finite(metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int) -> str | None:
    """A message naming the first seed, round and metric that went non-finite (None if all are finite).

    Loss and gradient norm count only in rounds where gradient steps ran (they are NaN by design otherwise);
    the parameter norm counts in every round."""
    stepped = np.asarray(metrics["round_updates"]) > 0
    for r in range(stepped.shape[1]):
        for s in range(stepped.shape[0]):
            for k in WATCHED:
                if k not in metrics:
                    continue
                value = float(metrics[k][s, r])
                if (k == "param_norm" or stepped[s, r]) and not np.isfinite(value):
                    return f"seed {seed_ids[s]}, round {first_round + r}: {k} = {value}"
    return None


def value_bounds_of(config: TrainConfig, env) -> tuple[float, float]:
    """The interval the guard holds value estimates to: the env's bounds on a discounted return from any state
    (``envs_jax.core.value_bounds``, with the learning discount) widened by ``divergence_margin`` of each bound's
    own size."""
    from envs_jax.core import value_bounds

    low, high = value_bounds(env.reward_bounds(), env.spec.discount, env.spec.horizon)
    margin = config.divergence_margin
    return low - margin * abs(low), high + margin * abs(high)


def flag_out_of_bounds(metrics: dict[str, np.ndarray], bounds: tuple[float, float]) -> np.ndarray | None:
    """f32[seeds, rounds]: 1 where a watched value metric (``VALUE_METRICS``) left ``bounds`` in that round, else 0
    (None if the learner reports none of them). NaN values (rounds without a gradient step) are not flagged."""
    names = [k for k in VALUE_METRICS if k in metrics]
    if not names:
        return None
    low, high = bounds
    values = np.stack([np.asarray(metrics[k], np.float64) for k in names])
    with np.errstate(invalid="ignore"):
        out = ((values < low) | (values > high)).any(0)
    return out.astype(np.float32)


def out_of_bounds_message(metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int,
                          bounds: tuple[float, float]) -> str | None:
    """The first seed and round (in round order) whose watched value metric left ``bounds``, or None."""
    flags = metrics.get(OUT_OF_BOUNDS_COLUMN)
    if flags is None or not np.any(flags):
        return None
    seed, rnd = min(zip(*np.nonzero(flags)), key=lambda sr: (sr[1], sr[0]))
    name, value = next((k, float(metrics[k][seed, rnd])) for k in VALUE_METRICS
                       if k in metrics and not bounds[0] <= float(metrics[k][seed, rnd]) <= bounds[1])
    return (f"seed {seed_ids[seed]}, round {first_round + rnd} (episode {int(metrics['episodes'][seed, rnd])}): "
            f"{name} = {value:.6g} is outside the value bounds [{bounds[0]:.6g}, {bounds[1]:.6g}] that every return "
            f"of this env lies in (widened by divergence_margin)")
