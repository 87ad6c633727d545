"""A run from start to end: ``train_run`` (a new run), ``resume_run`` (continue from the newest usable checkpoint),
``finish_run`` (end where it stands), ``extend_budget`` and ``change_diverged_settings``; the host loop that calls the
compiled chunks, appends metrics, checkpoints and stops a diverging run (``_loop``); and the end of a run: the final
greedy evaluation, summary.json and the learning-curve plot (``_finish``).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.config import TrainConfig
from jaxmac.runs.checkpoints import (
    Start,
    checkpointer,
    drop_checkpoints_after,
    save_checkpoint,
    say_skipped,
    skipped_text,
    start_point,
)
from jaxmac.runs.divergence import (
    DIVERGED_FILE,
    OUT_OF_BOUNDS_COLUMN,
    RunDiverged,
    check_finite,
    flag_out_of_bounds,
    out_of_bounds_message,
    set_aside_diverged,
    value_bounds_of,
)
from jaxmac.runs.folders import (
    LOCK_FILE,
    cut_back,
    is_finished,
    lock_run_folder,
    read_meta,
    read_progress,
    refuse_run_files,
    run_files,
    size_of,
    write_json_atomic,
)
from jaxmac.runs.loggers import (
    Guarded,
    check_new_stream,
    open_logger,
    require,
    rounds_of_chunks,
    rounds_of_metrics_file,
    with_logger,
)
from jaxmac.runs.metrics_csv import append_chunks, cut_metrics
from jaxmac.runs.programs import programs_for
from jaxmac.runs.resources import (abstract_state, check_budget, check_memory, check_whole_chunks, placed,
                                   say_rounded_budget, seed_sharding)
from jaxmac.scenarios import OPTIMAL_DISC_RETURN

# --- training, resuming, finishing ----------------------------------------------------------------------------------

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
    log: str | None = None,
    end_early=None,
) -> dict[str, Any] | None:
    """Train ``seeds`` seeds (``seed_offset … seed_offset+seeds-1``) into ``out_dir``, their states sharded over
    ``devices`` devices (``seed_sharding``). ``log``: ``"tensorboard"``, ``"wandb"`` or ``"wandb:online"`` also
    logs the metrics there (``jaxmac.runs.loggers``; recorded in config.json, so a resume goes on logging).

    ``out_dir`` is locked for the call (``lock_run_folder``) and must hold no file of a run. ``stop_after_chunks``
    stops early (as if killed) after that many chunks of this call, checkpointing first — used by tests of resume.
    ``end_early``: a callable of the metrics.csv path (e.g. ``early_end.SettledRule(...).reason``) asked after every
    checkpoint; a sentence ends the run there (final evaluation, summary with ``ended_early``, plot).
    Returns the summary (None if stopped).
    """
    if seeds < 1:
        raise ValueError(f"seeds={seeds!r} must be >= 1")
    sharding = seed_sharding(seeds, devices)
    check_budget(config)
    if rounds_per_chunk is not None:  # the default divides the run's rounds
        check_whole_chunks(config, rounds_per_chunk)
    say_rounded_budget(config)
    created = not os.path.exists(out_dir)
    with lock_run_folder(out_dir, "train"):
        try:
            refuse_run_files(out_dir)
            check_new_stream(log, out_dir)
            programs = programs_for(config, rounds_per_chunk)
            check_memory(programs, seeds, devices)
            meta = with_logger({"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset,
                                "rounds_per_chunk": programs.trainer.rounds_per_chunk, "jax": jax.__version__}, log)
            write_json_atomic(os.path.join(out_dir, "config.json"), meta)
        except BaseException:
            if created:
                _remove_if_empty(out_dir)
            raise
        try:
            keys = jax.vmap(jax.random.key)(jnp.arange(seed_offset, seed_offset + seeds))
            state = programs.init(keys)
            return _loop(programs, state, 0, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, 0.0,
                         sharding, end_early)
        except BaseException as err:
            if not isinstance(err, OSError):  # a full disk: the folder stays, for the resume its message suggests
                _forget_unstarted(out_dir, created)
            raise


def _remove_if_empty(out_dir: str) -> None:
    """Remove ``out_dir`` if it holds nothing but (our) lock file."""
    try:
        if not set(os.listdir(out_dir)) - {LOCK_FILE}:
            shutil.rmtree(out_dir, ignore_errors=True)
    except OSError:
        pass


def _forget_unstarted(out_dir: str, created: bool) -> None:
    """After a new run this process started failed before it recorded anything (no checkpoint, no metrics row: e.g.
    out of memory while compiling), remove the config.json it wrote (and the folder if it created it), so that the
    same --out can be used again."""
    found = run_files(out_dir)
    checkpoints = os.path.join(out_dir, "checkpoints")
    if any(f not in ("config.json", "checkpoints") for f in found):
        return
    try:
        if os.path.isdir(checkpoints) and os.listdir(checkpoints):
            return
        if os.path.isdir(checkpoints):
            os.rmdir(checkpoints)
        if "config.json" in found:
            os.remove(os.path.join(out_dir, "config.json"))
    except OSError:
        return
    if created:
        _remove_if_empty(out_dir)


def load_run(out_dir: str):
    """``(trainer, state, chunks_done, meta)`` of the run in ``out_dir`` at its newest checkpoint that restores
    (an older one, saying so on stderr, if the newest is damaged; a fresh state and 0 chunks if it has none).
    ``state`` leaves are ``[seeds, ...]``. Reads only."""
    programs, state, step, meta = _load(out_dir)
    return programs.trainer, state, step, meta


def _load(out_dir: str):
    """``load_run`` with the run's ``Programs`` in place of its trainer."""
    meta = read_meta(out_dir, trainable=True)
    programs = programs_for(TrainConfig.from_dict(meta["config"]), meta["rounds_per_chunk"])
    start = start_point(out_dir, programs, meta, need_rows=False)
    say_skipped(out_dir, start, "using")
    return programs, start.state, start.chunk, meta


def extended_meta(out_dir: str, meta: dict, episodes: int) -> dict:
    """``meta`` with a budget raised to ``episodes`` per seed (validated; nothing written)."""
    current = meta["config"]["episodes"]
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < current:
        raise ValueError(f"episodes={episodes!r}: a run can only be extended; {out_dir} already has a budget of "
                         f"{current} episodes per seed (give an integer >= {current})")
    config = TrainConfig.from_dict(meta["config"]).override(episodes=episodes)
    if "rounds_per_chunk" in meta:  # a run of one process (workers' runs are extended folder by folder)
        check_whole_chunks(config, meta["rounds_per_chunk"])
    return dict(meta, config=config.to_dict())


def extend_budget(out_dir: str, episodes: int, say: bool = True) -> None:
    """Raise the training budget of the run in ``out_dir`` to ``episodes`` per seed (its config.json,
    rewritten atomically). Nothing else of the config changes — the ε schedule counts episodes from
    the start — so resuming afterwards ends exactly where a run started with that budget would. A budget of partial
    rounds is said on stderr (``say``), as a new run says it."""
    with lock_run_folder(out_dir, "train --episodes") if os.path.isdir(out_dir) else _no_lock():
        meta = extended_meta(out_dir, read_meta(out_dir), episodes)
        write_json_atomic(os.path.join(out_dir, "config.json"), meta)
    if say:
        say_rounded_budget(TrainConfig.from_dict(meta["config"]))


class _no_lock:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None


def finish_run(out_dir: str) -> dict[str, Any]:
    """End the run in ``out_dir`` where its newest checkpoint stands, without training the rest of its budget (for a
    curve that has been flat for long): the final greedy evaluation, summary.json (with ``stopped_at`` =
    the episodes trained and ``budget``) and the plot, exactly as a run with that budget would end — the ε schedule
    counts episodes from the start, so it does not depend on the budget."""
    with lock_run_folder(out_dir, "train --finish") if os.path.isdir(out_dir) else _no_lock():
        if is_finished(out_dir):
            raise ValueError(f"{out_dir} has already finished (summary.json exists)")
        meta = read_meta(out_dir, trainable=True)
        programs = programs_for(TrainConfig.from_dict(meta["config"]), meta["rounds_per_chunk"])
        start = start_point(out_dir, programs, meta, need_rows=True)
        if start.chunk == 0:
            raise ValueError(f"{out_dir} has no usable checkpoint yet{skipped_text(start)}: nothing to finish "
                             "(resume it instead)")
        say_skipped(out_dir, start, "finishing at")
        drop_checkpoints_after(out_dir, start)
        cut_metrics(os.path.join(out_dir, "metrics.csv"), start.metrics,
                     start.chunk * programs.trainer.rounds_per_chunk)
        wall = _wall_seconds(out_dir)
        budget = programs.trainer.config.episodes
        summary = _finish(programs, start.state, out_dir, meta, wall)
        summary.update(stopped_at=summary["episodes"], budget=budget)
        write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
        return summary


def _wall_seconds(out_dir: str) -> float:
    try:
        return float((read_progress(out_dir) or {})["wall_seconds"])
    except (KeyError, TypeError, ValueError):
        return 0.0


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


def settings_keeping_shapes(out_dir: str, meta: dict, assignments: list[str], who: str) -> TrainConfig:
    """The run's settings with ``assignments`` (``--set`` strings) applied, refused when they change the shapes of the
    training state (its checkpoints would not fit: network sizes, ring, seeds' batch) — ``who`` names the runs that
    may change settings, for the message. Nothing written."""
    old = TrainConfig.from_dict(meta["config"])
    new = old.override_strings(assignments)
    if new.num_envs != old.num_envs:  # keeps the shapes, but chunks count rounds of num_envs episodes
        raise ValueError(f"--set num_envs={new.num_envs}: the checkpoints of {out_dir} count rounds of "
                         f"num_envs={old.num_envs} episodes per seed, so another value would misnumber the episodes "
                         "trained (the ε schedule, metrics.csv, the budget); nothing was changed")
    before = abstract_state(programs_for(old, meta["rounds_per_chunk"]), meta["seeds"])
    after = abstract_state(programs_for(new, meta["rounds_per_chunk"]), meta["seeds"])
    differ = _shape_changes(before, after)
    if differ:
        raise ValueError(f"--set {' '.join(assignments)} changes the shapes of the training state ({differ}): the "
                         f"checkpoint of {out_dir} would not fit. {who} only with settings that keep them (learning "
                         "rates, schedules, loss weights); nothing was changed")
    return new


def _changed_settings(out_dir: str, meta: dict, assignments: list[str]) -> dict:
    """``meta`` with ``assignments`` (``--set`` strings) applied to a diverged run, validated against its checkpoint
    (the training state must keep its shapes); nothing written."""
    if not os.path.exists(os.path.join(out_dir, DIVERGED_FILE)):
        raise ValueError(f"{out_dir} did not diverge: --resume continues a run as it was configured "
                         "(--set is only for a diverged run; jaxmac fork starts a new run from a checkpoint with "
                         "other settings)")
    new = settings_keeping_shapes(out_dir, meta, assignments, "A diverged run continues")
    changed = dict(meta, config=new.to_dict())
    changed["changed_after_divergence"] = list(meta.get("changed_after_divergence", [])) + list(assignments)
    return changed


def _shape_changes(before, after, limit: int = 3) -> str:
    flat_before, tree_before = jax.tree_util.tree_flatten_with_path(before)
    flat_after, tree_after = jax.tree_util.tree_flatten_with_path(after)
    if tree_before != tree_after:
        return "its structure differs"
    out = [f"{jax.tree_util.keystr(path)}: {tuple(a.shape)} {a.dtype} -> {tuple(b.shape)} {b.dtype}"
           for (path, a), (_, b) in zip(flat_before, flat_after) if (a.shape, a.dtype) != (b.shape, b.dtype)]
    return "; ".join(out[:limit]) + (f"; and {len(out) - limit} more" if len(out) > limit else "")


def change_diverged_settings(out_dir: str, assignments: list[str]) -> None:
    """Change settings (``key=value`` strings, as ``--set``) of a run that stopped because it diverged, so
    that it continues from its last good checkpoint with them. The parameter shapes must stay the same
    (learning rates, schedules, loss weights: yes; network sizes: no — the checkpoint would not fit); a refused
    change writes nothing."""
    with lock_run_folder(out_dir, "train --resume --set") if os.path.isdir(out_dir) else _no_lock():
        meta = _changed_settings(out_dir, read_meta(out_dir, trainable=True), assignments)
        write_json_atomic(os.path.join(out_dir, "config.json"), meta)
        set_aside_diverged(out_dir)


def _record(out_dir: str, start: Start) -> list[str]:
    """What of a run's record a start over would erase: metrics rows, summaries, a checkpoint once written."""
    found = []
    rows = len(start.metrics.rows)
    diverged_before_any_checkpoint = (os.path.exists(os.path.join(out_dir, DIVERGED_FILE))
                                      and not os.path.exists(os.path.join(out_dir, "progress.json")))
    if rows and not diverged_before_any_checkpoint:
        found.append(f"{rows} rows of metrics.csv")
    found += [n for n in run_files(out_dir) if n.startswith("summary")]
    if os.path.exists(os.path.join(out_dir, "progress.json")) and not start.steps:
        found.append("progress.json (a checkpoint was saved)")
    return found


def resume_run(out_dir: str, checkpoint_seconds: float = 120.0, progress: bool = True,
               stop_after_chunks: int | None = None, episodes: int | None = None,
               assignments: list[str] | None = None, devices: int = 1,
               log: str | None = None, end_early=None) -> dict[str, Any] | None:
    """Continue the run in ``out_dir`` from its newest usable checkpoint, on ``devices`` devices (any number that
    divides its seeds: where the seeds run does not change the result).

    ``episodes`` raises its budget first (``extend_budget``), so a finished run can be trained further;
    ``assignments`` change the settings of a diverged run (``change_diverged_settings``); ``log`` (``"none"``,
    ``"tensorboard"``, ...) changes where its metrics are logged besides metrics.csv (default: as recorded in its
    config.json; a stream turned on mid-run starts with the rows trained so far). Everything is checked
    before anything is written: the folder's lock, the settings (against the checkpoint's shapes), the checkpoint.
    A damaged newest checkpoint (or one whose rows metrics.csv lacks) falls back to an older one, saying so on
    stderr; a run without a checkpoint starts over only if it has no record to lose (no metrics rows, no summary).
    ``end_early``: as in ``train_run``.
    """
    with lock_run_folder(out_dir, "train --resume") if os.path.isdir(out_dir) else _no_lock():
        meta = read_meta(out_dir, trainable=True)
        new_meta = meta
        if assignments:
            new_meta = _changed_settings(out_dir, new_meta, assignments)
        if episodes is not None:
            new_meta = extended_meta(out_dir, new_meta, episodes)
        if log is not None:
            new_meta = with_logger(new_meta, log)
        require(new_meta.get("log"))
        programs = programs_for(TrainConfig.from_dict(new_meta["config"]), new_meta["rounds_per_chunk"])
        sharding = seed_sharding(new_meta["seeds"], devices)
        start = start_point(out_dir, programs, new_meta, need_rows=True)
        rounds_done = start.chunk * programs.trainer.rounds_per_chunk
        twice = start.metrics.duplicate(rounds_done)
        if twice is not None:
            raise ValueError(f"{os.path.join(out_dir, 'metrics.csv')} holds two rows of seed {twice[0]}, round "
                             f"{twice[1]}: two trainings were mixed in this folder, which cannot be resumed; "
                             "start a new run with another --out")
        if start.chunk == 0:
            record = _record(out_dir, start)
            if record:
                why = skipped_text(start).lstrip("; ") or (
                    "checkpoints/ is missing" if not start.steps else "it has none")
                raise ValueError(f"{out_dir} has no checkpoint to resume from ({why}) but holds a record "
                                 f"({', '.join(record)}): resuming would start it over and erase it. Nothing was "
                                 "changed; start a new run with another --out to train this configuration again")
        # --- everything checked: from here on the run's files change
        say_skipped(out_dir, start, "resuming from")
        if new_meta != meta:
            write_json_atomic(os.path.join(out_dir, "config.json"), new_meta)
        if assignments:
            set_aside_diverged(out_dir)
        _set_aside_early_summary(out_dir, start.chunk < programs.trainer.total_chunks)
        drop_checkpoints_after(out_dir, start)
        wall = _wall_seconds(out_dir) if start.chunk else 0.0
        cut_metrics(os.path.join(out_dir, "metrics.csv"), start.metrics, rounds_done)
        return _loop(programs, start.state, start.chunk, out_dir, new_meta, checkpoint_seconds, progress,
                     stop_after_chunks, wall, sharding, end_early)


def _loop(programs, state, chunk, out_dir, meta, checkpoint_seconds, progress, stop_after_chunks, wall_before,
          sharding=None, end_early=None):
    from tqdm import tqdm

    state = placed(state, sharding)
    trainer = programs.trainer
    config = trainer.config
    seed_ids = list(range(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    mngr = checkpointer(out_dir)
    metrics_path = os.path.join(out_dir, "metrics.csv")
    total = trainer.total_chunks
    episodes_per_chunk = trainer.rounds_per_chunk * config.num_envs
    bar = tqdm(total=total * episodes_per_chunk, initial=chunk * episodes_per_chunk, unit="ep",
               desc=f"{config.algorithm} on {config.scenario}, {meta['seeds']} seeds (episodes per seed)", disable=not progress, dynamic_ncols=True)
    start = time.perf_counter()
    last_ckpt = time.perf_counter()
    last_eval = float("nan")
    done_here = 0
    ended = None  # why the run ends before its budget (end_early), if it does
    bounds = value_bounds_of(config, trainer.env)
    # the metrics of the chunks since the last checkpoint: their rows are written with the checkpoint that covers
    # them, so metrics.csv never runs ahead of the run's checkpoints (but for a crash between the two)
    pending: list[tuple[dict[str, np.ndarray], int]] = []
    advice = (f"{out_dir} keeps its last checkpoint: free space, then `jaxmac train --resume {out_dir}` continues "
              "from it")
    # --log: the rows a checkpoint covers go on to TensorBoard / W&B once it is saved; first those of metrics.csv
    # the stream lacks (a resumed run, a stream turned on mid-run)
    logger = open_logger(out_dir, meta)
    logging = Guarded(logger) if logger is not None else None
    try:
        if logging is not None:
            logging.log_rows(rounds_of_metrics_file(metrics_path, logger.last_step))
        while chunk < total:
            state, metrics = programs.chunk(state)
            metrics = dict(jax.device_get(metrics))
            flags = flag_out_of_bounds(metrics, bounds)
            if flags is not None:
                metrics[OUT_OF_BOUNDS_COLUMN] = flags
            first_round = chunk * trainer.rounds_per_chunk
            pending.append((metrics, first_round))
            problem = check_finite(metrics, seed_ids, first_round)
            outside = out_of_bounds_message(metrics, seed_ids, first_round, bounds)
            if outside and not config.divergence_guard:
                bar.set_postfix_str(f"value out of bounds: {outside.split(' is outside')[0]}")
            if problem or (outside and config.divergence_guard):
                # never checkpoint a diverged state: the newest checkpoint stays the last good one. The rows up to
                # the diverged chunk are written to show where it happened (a resume drops them).
                append_chunks(metrics_path, pending, seed_ids, advice)
                last_good = mngr.latest_step()
                write_json_atomic(os.path.join(out_dir, DIVERGED_FILE), {
                    "problem": problem or outside, "kind": "non-finite" if problem else "value out of bounds",
                    "chunk": chunk, "last_good_checkpoint": last_good})
                kept = (f"{out_dir} keeps its last good checkpoint (chunk {last_good})" if last_good is not None else
                        f"{out_dir} has no checkpoint from before it (resuming starts the run again)")
                what = f"training diverged at {problem}" if problem else (
                    f"the value estimate diverged at {outside} (set divergence_guard=false to train on regardless)")
                raise RunDiverged(f"{what}; stopped. {kept}: continue with other settings, e.g. "
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
                size = size_of(metrics_path)
                append_chunks(metrics_path, pending, seed_ids, advice)  # fsynced before the checkpoint
                covered, pending = pending, []
                try:
                    save_checkpoint(mngr, chunk, state, out_dir, advice)
                except BaseException:
                    cut_back(metrics_path, size)  # no rows without the checkpoint that covers them
                    raise
                write_json_atomic(os.path.join(out_dir, "progress.json"),
                                  {"chunks_done": chunk, "wall_seconds": wall_before + time.perf_counter() - start})
                last_ckpt = time.perf_counter()
                if logging is not None:
                    logging.log_rows(rounds_of_chunks(metrics_path, covered, seed_ids))
                ended = end_early(metrics_path) if end_early is not None and chunk < total else None
                if ended:
                    break
            if stopping:
                return None
    finally:
        bar.close()
        if logging is not None:
            logging.close()
        try:
            mngr.close()
        except Exception:  # a failed save may fail again here; the first error is the one to report
            pass
    wall = wall_before + time.perf_counter() - start
    return _finish(programs, state, out_dir, meta, wall, ended if chunk < total else None)


def _finish(programs, state, out_dir, meta, wall_seconds, ended_early: str | None = None):
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
    if ended_early:
        summary["ended_early"] = ended_early
    if trainer.evaluate_greedy:  # the stochastic evaluation policy of the originals (sampled, un-mixed)
        sampled, sampled_undisc = programs.sampled_returns(state.params, keys)
        summary.update(final_sampled_return=sampled.tolist(), final_sampled_return_mean=float(sampled.mean()),
                       final_sampled_return_undiscounted_mean=float(sampled_undisc.mean()))
    write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
    plot_learning_curve(os.path.join(out_dir, "metrics.csv"), os.path.join(out_dir, "curve.png"),
                        f"{config.algorithm} on {config.scenario}", OPTIMAL_DISC_RETURN.get(config.scenario),
                        label=config.algorithm)
    return summary
