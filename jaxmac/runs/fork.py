"""``jaxmac fork``: a new run folder that starts from a checkpoint of another run — its seeds' whole training state
at that chunk (parameters, optimiser, replay ring, PRNG keys) — with other settings that keep the state's shapes
and/or another budget, for a probe from the middle of a run ("the last 20K episodes with a lower learning rate")
or an exact replay of a round ("train the fork to the round where the greedy policy collapsed, then `jaxmac
eval` it").

    jaxmac fork RUN_DIR --out NEW [--chunk N] [--episodes E] [--set KEY=VALUE ...]
    jaxmac train --resume NEW          # trains the fork: exactly RUN_DIR's next chunks where nothing was changed

The fork's ``config.json`` records where it came from (``forked_from``: the source folder, the chunk, the episodes
per seed it had trained and the changed settings); its ``metrics.csv`` holds the source's rows up to that chunk, so
its curve and results read as one run. The source is only read: it may be training meanwhile, and it keeps only
its newest two checkpoints, so fork from one of those.
"""

from __future__ import annotations

import os
import shutil

from jaxmac.config import TrainConfig
from jaxmac.runs.checkpoints import checkpoint_steps
from jaxmac.runs.folders import read_meta, refuse_run_files, write_json_atomic
from jaxmac.runs.loop import settings_keeping_shapes
from jaxmac.runs.metrics_csv import cut_metrics, read_metrics_file
from jaxmac.runs.resources import check_whole_chunks


def episodes_at(meta: dict, chunk: int) -> int:
    """The episodes per seed a run (``config.json`` contents ``meta``) had trained after ``chunk`` chunks."""
    return chunk * meta["rounds_per_chunk"] * meta["config"]["num_envs"]


def fork_config(src: str, meta: dict, chunk: int, episodes: int | None, assignments: list[str]) -> TrainConfig:
    """The fork's settings: ``src``'s with ``assignments`` (shapes kept) and budget ``episodes`` (default: the
    source's), which must end on a chunk after ``chunk``. Nothing written."""
    config = (settings_keeping_shapes(src, meta, assignments, "A fork starts from the checkpoint")
              if assignments else TrainConfig.from_dict(meta["config"]))
    rounds_per_chunk = meta["rounds_per_chunk"]
    at = episodes_at(meta, chunk)
    if episodes is not None:
        if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes <= at:
            raise ValueError(f"episodes={episodes!r}: the fork starts where chunk {chunk} of {src} ends, at {at} "
                             f"episodes per seed; give a budget above it")
        config = config.override(episodes=episodes)
    check_whole_chunks(config, rounds_per_chunk)
    if config.rounds <= chunk * rounds_per_chunk:
        raise ValueError(f"the checkpoint after chunk {chunk} of {src} has trained the whole budget of "
                         f"{config.episodes} episodes per seed: give --episodes above {at} to train the fork further")
    return config


def fork_run(src: str, out: str, chunk: int | None = None, episodes: int | None = None,
             assignments: tuple[str, ...] | list[str] = ()) -> dict:
    """Write the fork of ``src`` at its checkpoint after ``chunk`` chunks (default: its newest) into the new folder
    ``out``; returns the fork's ``config.json`` contents. Refused, writing nothing, when ``src`` keeps no such
    checkpoint, a setting changes the training state's shapes, the budget is not above the checkpoint's episodes or
    ends inside a chunk, or ``out`` holds a run's files."""
    from jaxmac.runs.workers import is_worker_run

    if is_worker_run(src):
        raise ValueError(f"{src} is a run of several worker processes: fork one of its workers' folders instead")
    meta = read_meta(src, trainable=True)
    kept = checkpoint_steps(src)
    if not kept:
        raise ValueError(f"{src} keeps no checkpoint: there is no training state to fork from")
    chunk = kept[0] if chunk is None else chunk
    if chunk not in kept:
        raise ValueError(f"chunk={chunk!r}: {src} keeps checkpoints after chunks {', '.join(map(str, sorted(kept)))} "
                         "only (a run keeps its newest two)")
    assignments = list(assignments)
    config = fork_config(src, meta, chunk, episodes, assignments)
    if os.path.abspath(out) == os.path.abspath(src):
        raise ValueError(f"--out {out} is the run being forked: give a new folder")
    refuse_run_files(out)
    created = not os.path.exists(out)
    os.makedirs(out, exist_ok=True)
    forked = dict(meta, config=config.to_dict(), forked_from={"run": os.path.abspath(src), "chunk": chunk,
                                                              "episodes": episodes_at(meta, chunk), "set": assignments})
    try:
        try:
            shutil.copytree(os.path.join(src, "checkpoints", str(chunk)), os.path.join(out, "checkpoints", str(chunk)))
        except OSError as err:
            raise ValueError(f"cannot copy the checkpoint after chunk {chunk} of {src} ({err}); if that run is "
                             "training, it may have just replaced it with a newer one: fork again") from err
        metrics = os.path.join(out, "metrics.csv")
        if os.path.exists(os.path.join(src, "metrics.csv")):
            shutil.copyfile(os.path.join(src, "metrics.csv"), metrics)
            cut_metrics(metrics, read_metrics_file(metrics), chunk * meta["rounds_per_chunk"])
        write_json_atomic(os.path.join(out, "progress.json"), {"chunks_done": chunk, "wall_seconds": 0.0})
        write_json_atomic(os.path.join(out, "config.json"), forked)
    except BaseException:
        for name in ("checkpoints", "metrics.csv", "progress.json", "config.json"):
            path = os.path.join(out, name)
            if os.path.isdir(path):
                shutil.rmtree(path, ignore_errors=True)
            elif os.path.exists(path):
                os.remove(path)
        if created and not os.listdir(out):
            os.rmdir(out)
        raise
    return forked


def add_arguments(p) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="the run to fork (only read)")
    p.add_argument("--out", required=True, help="the new run folder")
    p.add_argument("--chunk", type=int, default=None,
                   help="the checkpoint to start from, by chunks trained (default: the newest the run keeps)")
    p.add_argument("--episodes", type=int, default=None, help="the fork's budget per seed (default: the run's)")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="KEY=VALUE",
                   help="a setting that keeps the training state's shapes (learning rate, schedules, loss weights)")


def run(args) -> int:
    forked = fork_run(args.run_dir, args.out, args.chunk, args.episodes, args.assignments)
    origin = forked["forked_from"]
    changed = f", settings changed: {' '.join(origin['set'])}" if origin["set"] else ""
    print(f"forked {args.run_dir} at chunk {origin['chunk']} ({origin['episodes']} episodes per seed) into {args.out}"
          f"{changed}; budget {forked['config']['episodes']} episodes per seed. Train it with: "
          f"jaxmac train --resume {args.out}")
    return 0
