"""The thin host loop around the compiled trainer: seeds, progress, metrics, checkpoints, plots.

``train_run(config, seeds, out_dir)`` vmaps the trainer over ``seeds`` seeds and calls its
compiled chunk repeatedly; between chunks it appends the per-round metrics to
``metrics.csv``, saves an orbax checkpoint (atomic: written aside, then renamed) and updates
the progress bar. ``resume_run(out_dir)`` continues a killed run from its newest checkpoint
and ends with the same result as an uninterrupted run. A run folder holds::

    config.json     resolved TrainConfig + seeds + chunking (the resume source of truth)
    metrics.csv     one row per seed and round
    curve.png       learning curve: greedy discounted return, mean ± s.e. over seeds
    summary.json    final greedy evaluation per seed (discounted and undiscounted)
    checkpoints/    orbax checkpoints of the whole training state
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import json
import os
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.buckets import SEED_AXIS
from jaxmac.config import TrainConfig

# The first columns of metrics.csv; every other metric the trainer and the algorithm report follows, by name.
METRIC_COLUMNS = ("seed", "round", "episodes", "epsilon", "train_return", "train_disc_return", "train_length",
                  "eval_disc_return", "eval_return", "loss")
# Metrics that must stay finite in every round with a gradient step (and param_norm in every round).
WATCHED = ("loss", "grad_norm", "param_norm")
# The value learners' mean value estimates, each a (mixed or per-agent) estimate of a discounted team return: they
# must stay inside the env's value bounds (``value_bounds``); the divergence guard watches them.
VALUE_METRICS = ("q_tot_mean", "cen_q_mean", "dec_q_mean")
OUT_OF_BOUNDS_COLUMN = "value_out_of_bounds"

# Discounted optimal returns (SPEC §13 / BASELINES §3.2) drawn on the curves.
OPTIMAL_DISC_RETURN = {
    "boxpushing-6x6": 270.605, "boxpushing-8x8": 259.691, "boxpushing-10x10": 244.125,
    "boxpushing-12x12": 229.475, "boxpushing-14x14": 215.686,
}


def enable_compilation_cache(path: str | None = None) -> None:
    """JAX's persistent compilation cache: a re-run skips most compilation."""
    path = path or os.environ.get("JAXMAC_CACHE", os.path.expanduser("~/.cache/jaxmac/xla"))
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def use_host_devices(count: int) -> None:
    """Let a CPU-only JAX split into ``count`` host devices (one per core) so that seeds can be sharded over them.
    Must run before JAX starts its backend (the first computation); on an accelerator it changes nothing."""
    if count > 1:
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={count}".strip()


def seed_sharding(seeds: int, devices: int):
    """The ``NamedSharding`` that splits a state's leading seed axis over the first ``devices`` devices (a mesh
    axis named ``SEED_AXIS``), or None for one device. One jitted program then runs every device's seeds (the same
    command on one GPU, several GPUs, or ``jax.distributed`` hosts)."""
    if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
        raise ValueError(f"devices={devices!r} must be a positive integer")
    if devices == 1:
        return None
    available = jax.devices()
    if devices > len(available):
        raise ValueError(f"devices={devices}: JAX sees {len(available)} device(s) ({available[0].platform}); on a CPU "
                         f"use `jaxmac train --devices N` (it splits the host into N devices before JAX starts)")
    if seeds % devices:
        raise ValueError(f"seeds={seeds} cannot be split evenly over devices={devices}: use a number of seeds that "
                         f"is a multiple of the devices, or fewer devices")
    mesh = jax.sharding.Mesh(np.array(available[:devices]), (SEED_AXIS,))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(SEED_AXIS))


@dataclasses.dataclass(frozen=True)
class _Programs:
    """A trainer and the jitted programs the host loop runs, seeds vmapped (state leaves ``[seeds, ...]``)."""
    trainer: Any  # jaxmac.trainer.Trainer
    init: Callable  # keys [seeds] -> TrainState
    chunk: Callable  # TrainState -> (TrainState, metrics [seeds, rounds]); donates the state it is given
    # (params, keys [seeds]) -> (discounted, undiscounted) mean final-evaluation returns [seeds]
    greedy_returns: Callable  # the greedy policy: the value learners' own, the actor-critics' greedy_act
    sampled_returns: Callable  # the policy ``evaluate`` runs (the actor-critics' sampled one)


@functools.lru_cache(maxsize=4)
def _programs(config: TrainConfig, rounds_per_chunk: int | None) -> _Programs:
    """Built once per setting in a process: a resumed, extended or finished run, or a test that trains the same
    configuration several times, reuses the traced and compiled programs instead of tracing them again."""
    from jaxmac.algos import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.trainer import make_train

    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env), rounds_per_chunk)

    def final_returns(evaluate):
        run = jax.jit(jax.vmap(lambda p, k: evaluate(p, k, config.eval_episodes), axis_name=SEED_AXIS))

        def returns(params, keys):
            stats = run(params, keys)
            return np.asarray(stats["disc_return"]).mean(-1), np.asarray(stats["return"]).mean(-1)

        return returns

    sampled = final_returns(trainer.evaluate)
    return _Programs(trainer, jax.jit(jax.vmap(trainer.init)), jax.jit(trainer.seeds_chunk, donate_argnums=0),
                     final_returns(trainer.evaluate_greedy) if trainer.evaluate_greedy else sampled, sampled)


def _checkpointer(out_dir: str):
    import orbax.checkpoint as ocp

    return ocp.CheckpointManager(
        os.path.abspath(os.path.join(out_dir, "checkpoints")),
        options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True),
    )


def _to_saveable(state):
    return state.replace(key=jax.random.key_data(state.key))


def _from_saved(state):
    return state.replace(key=jax.random.wrap_key_data(state.key))


def metric_columns(metrics: dict[str, Any]) -> list[str]:
    """``METRIC_COLUMNS`` then every other reported metric in name order."""
    return list(METRIC_COLUMNS) + sorted(k for k in metrics if k not in METRIC_COLUMNS)


def _write_metrics(path: str, metrics: dict[str, np.ndarray], seed_ids: list[int], first_round: int) -> None:
    """Append one row per seed and round for metrics with leaves [seeds, rounds] (every metric a column)."""
    new = not os.path.exists(path)
    if new:
        columns = metric_columns(metrics)
    else:
        with open(path, newline="") as f:
            columns = next(csv.reader(f))
    seeds, rounds = np.shape(metrics["episodes"])
    with open(path, "a", newline="") as f:
        w = csv.writer(f)
        if new:
            w.writerow(columns)
        for s in range(seeds):
            for r in range(rounds):
                row = [seed_ids[s], first_round + r, int(metrics["episodes"][s, r])]
                for k in columns[3:]:
                    value = metrics[k][s, r] if k in metrics else float("nan")
                    row.append(int(value) if np.issubdtype(np.asarray(value).dtype, np.integer) else float(value))
                w.writerow(row)


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


def _truncate_metrics(path: str, rounds_done: int) -> None:
    """Drop rows of rounds that a resumed run will redo (written after the last checkpoint)."""
    if not os.path.exists(path):
        return
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    keep = [rows[0]] + [r for r in rows[1:] if int(r[1]) < rounds_done]
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as f:
        csv.writer(f).writerows(keep)
    os.replace(tmp, path)


def write_json_atomic(path: str, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` through a temporary file and a rename (never half-written)."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=2)
    os.replace(tmp, path)


def train_run(
    config: TrainConfig,
    seeds: int,
    out_dir: str,
    seed_offset: int = 0,
    rounds_per_chunk: int | None = None,
    checkpoint_seconds: float = 120.0,
    progress: bool = True,
    stop_after_chunks: int | None = None,
    devices: int = 1,
) -> dict[str, Any] | None:
    """Train ``seeds`` seeds (``seed_offset … seed_offset+seeds-1``) into ``out_dir``, their states sharded over
    ``devices`` devices (``seed_sharding``).

    ``stop_after_chunks`` stops early (as if killed) after that many chunks of this call,
    checkpointing first — used by tests of resume. Returns the summary (None if stopped).
    """
    if seeds < 1:
        raise ValueError(f"seeds={seeds!r} must be >= 1")
    sharding = seed_sharding(seeds, devices)
    os.makedirs(out_dir, exist_ok=True)
    if os.path.exists(os.path.join(out_dir, "config.json")):
        raise ValueError(f"{out_dir} already holds a run; use resume (jaxmac train --resume {out_dir}) "
                         "or choose another --out")
    programs = _programs(config, rounds_per_chunk)
    meta = {"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset,
            "rounds_per_chunk": programs.trainer.rounds_per_chunk, "jax": jax.__version__}
    write_json_atomic(os.path.join(out_dir, "config.json"), meta)
    keys = jax.vmap(jax.random.key)(jnp.arange(seed_offset, seed_offset + seeds))
    state = programs.init(keys)
    return _loop(programs, state, 0, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, 0.0, sharding)


def load_run(out_dir: str):
    """``(trainer, state, chunks_done, meta)`` of the run in ``out_dir`` at its newest checkpoint
    (a fresh state and 0 chunks if it has none). ``state`` leaves are ``[seeds, ...]``."""
    programs, state, step, meta = _load(out_dir)
    return programs.trainer, state, step, meta


def _load(out_dir: str):
    """``load_run`` with the run's ``_Programs`` in place of its trainer."""
    path = os.path.join(out_dir, "config.json")
    if not os.path.exists(path):
        raise ValueError(f"{out_dir} holds no run (no config.json)")
    with open(path) as f:
        meta = json.load(f)
    programs = _programs(TrainConfig.from_dict(meta["config"]), meta["rounds_per_chunk"])
    keys = jax.vmap(jax.random.key)(jnp.arange(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    state = programs.init(keys)
    mngr = _checkpointer(out_dir)
    step = mngr.latest_step()
    if step is not None:
        import orbax.checkpoint as ocp

        abstract = jax.eval_shape(_to_saveable, state)
        state = _from_saved(mngr.restore(step, args=ocp.args.StandardRestore(abstract)))
    mngr.close()
    return programs, state, step or 0, meta


def extend_budget(out_dir: str, episodes: int) -> None:
    """Raise the training budget of the run in ``out_dir`` to ``episodes`` per seed (its config.json,
    rewritten atomically). Nothing else of the config changes — the ε schedule counts episodes from
    the start — so resuming afterwards ends exactly where a run started with that budget would."""
    path = os.path.join(out_dir, "config.json")
    if not os.path.exists(path):
        raise ValueError(f"{out_dir} holds no run (no config.json)")
    with open(path) as f:
        meta = json.load(f)
    current = meta["config"]["episodes"]
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < current:
        raise ValueError(f"episodes={episodes!r}: a run can only be extended; {out_dir} already has a budget of "
                         f"{current} episodes per seed (give an integer >= {current})")
    meta["config"] = TrainConfig.from_dict(meta["config"]).override(episodes=episodes).to_dict()  # validated
    write_json_atomic(path, meta)


def finish_run(out_dir: str) -> dict[str, Any]:
    """End the run in ``out_dir`` where its newest checkpoint stands, without training the rest of its budget (for a
    curve that has been flat for long): the final greedy evaluation, summary.json (with ``stopped_at`` =
    the episodes trained and ``budget``) and the plot, exactly as a run with that budget would end — the ε schedule
    counts episodes from the start, so it does not depend on the budget."""
    if is_finished(out_dir):
        raise ValueError(f"{out_dir} has already finished (summary.json exists)")
    programs, state, chunk, meta = _load(out_dir)
    if chunk == 0:
        raise ValueError(f"{out_dir} has no checkpoint yet: nothing to finish (resume it instead)")
    _truncate_metrics(os.path.join(out_dir, "metrics.csv"), chunk * programs.trainer.rounds_per_chunk)
    with open(os.path.join(out_dir, "progress.json")) as f:
        wall = float(json.load(f)["wall_seconds"])
    budget = programs.trainer.config.episodes
    summary = _finish(programs, state, out_dir, meta, wall)
    summary.update(stopped_at=summary["episodes"], budget=budget)
    write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
    return summary


def _set_aside_early_summary(out_dir: str, training_on: bool) -> None:
    """A finished run trained further (ended early by ``finish_run``, or extended) no longer ends where its summary
    says: keep that summary as ``summary.stopped-at-N.json`` (N its episodes per seed), so that the run counts as
    unfinished until it ends again and ``finish_run`` can end it again."""
    path = os.path.join(out_dir, "summary.json")
    if not (training_on and os.path.exists(path)):
        return
    with open(path) as f:
        episodes = json.load(f)["episodes"]
    os.replace(path, os.path.join(out_dir, f"summary.stopped-at-{episodes}.json"))


def is_finished(out_dir: str) -> bool:
    return os.path.exists(os.path.join(out_dir, "summary.json"))


def change_diverged_settings(out_dir: str, assignments: list[str]) -> None:
    """Change settings (``key=value`` strings, as ``--set``) of a run that stopped because it diverged, so
    that it continues from its last good checkpoint with them. The parameter shapes must stay the same
    (learning rates, schedules, loss weights: yes; network sizes: no — the checkpoint would not fit)."""
    if not os.path.exists(os.path.join(out_dir, "diverged.json")):
        raise ValueError(f"{out_dir} did not diverge: --resume continues a run as it was configured "
                         "(--set is only for a diverged run)")
    path = os.path.join(out_dir, "config.json")
    with open(path) as f:
        meta = json.load(f)
    meta["config"] = TrainConfig.from_dict(meta["config"]).override_strings(assignments).to_dict()
    meta.setdefault("changed_after_divergence", []).extend(assignments)
    write_json_atomic(path, meta)
    os.replace(os.path.join(out_dir, "diverged.json"), os.path.join(out_dir, "diverged.previous.json"))


def resume_run(out_dir: str, checkpoint_seconds: float = 120.0, progress: bool = True,
               stop_after_chunks: int | None = None, episodes: int | None = None,
               assignments: list[str] | None = None, devices: int = 1) -> dict[str, Any] | None:
    """Continue the run in ``out_dir`` from its newest checkpoint (or from scratch if none), on ``devices``
    devices (any number that divides its seeds: where the seeds run does not change the result).

    ``episodes`` raises its budget first (``extend_budget``), so a finished run can be trained further;
    ``assignments`` change the settings of a diverged run (``change_diverged_settings``).
    """
    if assignments:
        change_diverged_settings(out_dir, assignments)
    if episodes is not None:
        extend_budget(out_dir, episodes)
    programs, state, chunk, meta = _load(out_dir)
    _set_aside_early_summary(out_dir, chunk < programs.trainer.total_chunks)
    sharding = seed_sharding(meta["seeds"], devices)
    wall = 0.0
    progress_path = os.path.join(out_dir, "progress.json")
    if chunk and os.path.exists(progress_path):
        with open(progress_path) as f:
            wall = float(json.load(f)["wall_seconds"])
    _truncate_metrics(os.path.join(out_dir, "metrics.csv"), chunk * programs.trainer.rounds_per_chunk)
    return _loop(programs, state, chunk, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, wall,
                 sharding)


def placed(state, sharding=None):
    """``state`` committed to its device(s) (``sharding``, or the first device), as a restored checkpoint is: a
    fresh and a resumed run then lower to the same program, and the second one loads it from the persistent
    compilation cache instead of compiling it again (an uncommitted array lowers without a sharding)."""
    return jax.device_put(state, sharding if sharding is not None else jax.devices()[0])


def _loop(programs, state, chunk, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, wall_before,
          sharding=None):
    import orbax.checkpoint as ocp
    from tqdm import tqdm

    state = placed(state, sharding)
    trainer = programs.trainer
    config = trainer.config
    seed_ids = list(range(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    mngr = _checkpointer(out_dir)
    metrics_path = os.path.join(out_dir, "metrics.csv")
    total = trainer.total_chunks
    episodes_per_chunk = trainer.rounds_per_chunk * config.num_envs
    bar = tqdm(total=total * episodes_per_chunk, initial=chunk * episodes_per_chunk, unit="ep",
               desc=f"{config.algorithm} on {config.scenario}, {meta['seeds']} seeds (episodes per seed)", disable=not progress, dynamic_ncols=True)
    start = time.perf_counter()
    last_ckpt = time.perf_counter()
    last_eval = float("nan")
    done_here = 0
    bounds = value_bounds_of(config, trainer.env)
    while chunk < total:
        state, metrics = programs.chunk(state)
        metrics = dict(jax.device_get(metrics))
        flags = flag_out_of_bounds(metrics, bounds)
        if flags is not None:
            metrics[OUT_OF_BOUNDS_COLUMN] = flags
        first_round = chunk * trainer.rounds_per_chunk
        _write_metrics(metrics_path, metrics, seed_ids, first_round)
        problem = check_finite(metrics, seed_ids, first_round)
        outside = out_of_bounds_message(metrics, seed_ids, first_round, bounds)
        if outside and not config.divergence_guard:
            bar.set_postfix_str(f"value out of bounds: {outside.split(' is outside')[0]}")
        if problem or (outside and config.divergence_guard):
            # never checkpoint a diverged state: the newest checkpoint stays the last good one
            bar.close()
            last_good = mngr.latest_step()
            mngr.close()
            write_json_atomic(os.path.join(out_dir, "diverged.json"), {
                "problem": problem or outside, "kind": "non-finite" if problem else "value out of bounds",
                "chunk": chunk, "last_good_checkpoint": last_good})
            kept = (f"{out_dir} keeps its last good checkpoint (chunk {last_good})" if last_good is not None else
                    f"{out_dir} has no checkpoint from before it (resuming starts the run again)")
            what = f"training diverged at {problem}" if problem else (
                f"the value estimate diverged at {outside} (set divergence_guard=false to train on regardless)")
            raise RuntimeError(f"{what}; stopped. {kept}: continue with other settings, e.g. "
                               f"jaxmac train --resume {out_dir} --set lr=...")
        chunk += 1
        done_here += 1
        evals = metrics["eval_disc_return"]
        if np.isfinite(evals).any():
            last_eval = float(np.nanmean(evals[:, np.isfinite(evals).any(0)][:, -1]))
        bar.update(episodes_per_chunk)
        bar.set_postfix(eval_return=f"{last_eval:.1f}", eps=f"{float(metrics['epsilon'][0, -1]):.2f}")
        stopping = stop_after_chunks is not None and done_here >= stop_after_chunks and chunk < total
        if chunk == total or stopping or time.perf_counter() - last_ckpt >= checkpoint_seconds:
            mngr.save(chunk, args=ocp.args.StandardSave(_to_saveable(state)))
            mngr.wait_until_finished()
            write_json_atomic(os.path.join(out_dir, "progress.json"),
                              {"chunks_done": chunk, "wall_seconds": wall_before + time.perf_counter() - start})
            last_ckpt = time.perf_counter()
        if stopping:
            bar.close()
            mngr.close()
            return None
    bar.close()
    mngr.close()
    wall = wall_before + time.perf_counter() - start
    return _finish(programs, state, out_dir, meta, wall)


def _finish(programs, state, out_dir, meta, wall_seconds):
    """Final greedy evaluation per seed, summary.json and the learning-curve plot."""
    from jaxmac.plotting import plot_learning_curve

    trainer = programs.trainer
    config = trainer.config
    keys = jax.vmap(lambda s: jax.random.fold_in(jax.random.key(10_007), s))(
        jnp.arange(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    # greedy: the value learners' evaluation policy, the actor-critics' greedy_act (their sampled one is kept too)
    disc, undisc = programs.greedy_returns(state.params, keys)
    summary = {
        "scenario": config.scenario,
        "algorithm": config.algorithm,
        "seeds": meta["seeds"],
        "seed_offset": meta["seed_offset"],
        "episodes": int(np.asarray(state.episodes)[0]),
        "wall_seconds": wall_seconds,
        "discount": trainer.env.spec.discount,
        "final_greedy_return": disc.tolist(),
        "final_greedy_return_mean": float(disc.mean()),
        "final_greedy_return_undiscounted": undisc.tolist(),
        "final_greedy_return_undiscounted_mean": float(undisc.mean()),
        "optimal_return": OPTIMAL_DISC_RETURN.get(config.scenario),
    }
    if trainer.evaluate_greedy:  # the stochastic evaluation policy of the originals (sampled, un-mixed)
        sampled, sampled_undisc = programs.sampled_returns(state.params, keys)
        summary.update(final_sampled_return=sampled.tolist(), final_sampled_return_mean=float(sampled.mean()),
                       final_sampled_return_undiscounted_mean=float(sampled_undisc.mean()))
    write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
    plot_learning_curve(os.path.join(out_dir, "metrics.csv"), os.path.join(out_dir, "curve.png"),
                        f"{config.algorithm} on {config.scenario}", OPTIMAL_DISC_RETURN.get(config.scenario),
                        label=config.algorithm)
    return summary


def default_out_dir(config: TrainConfig) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return os.path.join("runs", f"{config.scenario}-{config.algorithm}-{stamp}")


