"""Several training processes on one machine (``jaxmac train --workers N``).

One JAX process keeps about one CPU core busy, so N processes each ``vmap`` their share of the
seeds into ``RUN/worker{k}`` (an ordinary run folder, resumable on its own); this process
shows one progress bar and, when all are done, merges their metrics, summaries and curve
into ``RUN``. Across machines or accelerators scale with ``jax.sharding`` instead.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from typing import Any

from jaxmac.config import TrainConfig
from jaxmac.runs.folders import lock_run_folder, read_meta, refuse_run_files, write_json_atomic
from jaxmac.runs.loggers import check_new_stream, log_choice, require, with_logger
from jaxmac.runs.loop import extend_budget, extended_meta
from jaxmac.runs.metrics_csv import episodes_per_seed
from jaxmac.runs.resources import check_new_run, say_rounded_budget


def split_seeds(seeds: int, workers: int) -> list[tuple[int, int]]:
    """(seed_offset, count) per worker, counts differing by at most one."""
    if workers < 1 or workers > seeds:
        raise ValueError(f"workers={workers} must be between 1 and seeds={seeds}")
    base, extra = divmod(seeds, workers)
    out, offset = [], 0
    for k in range(workers):
        count = base + (k < extra)
        out.append((offset, count))
        offset += count
    return out


def _worker_dirs(out_dir: str, workers: int) -> list[str]:
    return [os.path.join(out_dir, f"worker{k}") for k in range(workers)]


def train_workers(config: TrainConfig, seeds: int, out_dir: str, workers: int, progress: bool = True,
                  seed_offset: int = 0, checkpoint_seconds: float = 120.0, log: str | None = None) -> dict:
    """Train ``seeds`` seeds (from ``seed_offset``) in ``workers`` processes and merge the results into
    ``out_dir`` (locked by this process meanwhile; each worker locks its own folder). ``log``: each worker logs its
    seeds to a stream of its own in its folder (``jaxmac.runs.loggers``)."""
    shares = [(seed_offset + offset, count) for offset, count in split_seeds(seeds, workers)]
    check_new_run(config, seeds)  # budget and memory (the workers share this machine), before anything is written
    with lock_run_folder(out_dir, "train --workers"):
        refuse_run_files(out_dir)
        log = log_choice(log)
        check_new_stream(log, out_dir)
        write_json_atomic(os.path.join(out_dir, "config.json"),
                          {"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset, "workers": workers,
                           "shares": shares, **({"log": log} if log else {})})
        jobs = []
        for d, (offset, count) in zip(_worker_dirs(out_dir, workers), shares):
            os.makedirs(d, exist_ok=True)
            write_json_atomic(os.path.join(d, "job.json"),
                              {"config": config.to_dict(), "seeds": count, "seed_offset": offset,
                               **({"log": log} if log else {})})
            jobs.append(d)
        return _run_and_merge(out_dir, jobs, resume=False, progress=progress, total_episodes=config.episodes * seeds,
                              checkpoint_seconds=checkpoint_seconds)


def resume_workers(out_dir: str, progress: bool = True, episodes: int | None = None,
                   checkpoint_seconds: float = 120.0, log: str | None = None) -> dict:
    """Continue a worker run; ``episodes`` raises its budget first (see ``jaxmac.runs.loop.extend_budget``), after
    every folder's budget was checked; ``log`` changes where every worker logs (default: as recorded)."""
    with lock_run_folder(out_dir, "train --resume --workers"):
        meta = read_meta(out_dir)
        jobs = _worker_dirs(out_dir, meta["workers"])
        require(meta.get("log") if log is None else log)
        if log is not None:
            _change_logger(out_dir, meta, jobs, log_choice(log))
            meta = read_meta(out_dir)
        if episodes is not None:
            extended = extended_meta(out_dir, meta, episodes)
            for d in jobs:  # every budget checked before any is written
                if os.path.exists(os.path.join(d, "config.json")):
                    extended_meta(d, read_meta(d), episodes)
            write_json_atomic(os.path.join(out_dir, "config.json"), extended)
            meta = extended
            say_rounded_budget(TrainConfig.from_dict(meta["config"]))  # once for the run, not once per worker
            for d in jobs:
                if os.path.exists(os.path.join(d, "config.json")):
                    extend_budget(d, episodes, say=False)
                job_path = os.path.join(d, "job.json")
                with open(job_path) as f:
                    job = json.load(f)
                write_json_atomic(job_path, dict(job, config=meta["config"]))
        return _run_and_merge(out_dir, jobs, resume=True, progress=progress,
                              total_episodes=meta["config"]["episodes"] * meta["seeds"],
                              checkpoint_seconds=checkpoint_seconds)


def _change_logger(out_dir: str, meta: dict, jobs: list[str], log: str | None) -> None:
    """Record ``log`` in the run's config.json, its workers' job.json and (where a worker started) config.json."""
    entry = {"log": log} if log else {}
    for d in jobs:
        job_path = os.path.join(d, "job.json")
        with open(job_path) as f:
            job = json.load(f)
        write_json_atomic(job_path, dict({k: v for k, v in job.items() if k != "log"}, **entry))
        if os.path.exists(os.path.join(d, "config.json")):
            with lock_run_folder(d, "train --resume --log"):
                write_json_atomic(os.path.join(d, "config.json"), with_logger(read_meta(d), log))
    write_json_atomic(os.path.join(out_dir, "config.json"),
                      dict({k: v for k, v in meta.items() if k != "log"}, **entry))


def is_worker_run(out_dir: str) -> bool:
    if not os.path.exists(os.path.join(out_dir, "config.json")):
        return False
    return "workers" in read_meta(out_dir)


def _episodes_done(job_dir: str) -> int:
    """Episodes trained so far in a worker folder (from its metrics.csv), summed over its seeds."""
    return sum(episodes_per_seed(os.path.join(job_dir, "metrics.csv")).values())


def _finished(job_dir: str) -> bool:
    """The worker wrote its summary for its current budget (a budget raised later makes it unfinished)."""
    summary_path, config_path = (os.path.join(job_dir, name) for name in ("summary.json", "config.json"))
    if not (os.path.exists(summary_path) and os.path.exists(config_path)):
        return False
    with open(summary_path) as f, open(config_path) as g:
        return json.load(f)["episodes"] >= json.load(g)["config"]["episodes"]


def _run_and_merge(out_dir: str, jobs: list[str], resume: bool, progress: bool, total_episodes: int,
                   checkpoint_seconds: float = 120.0) -> dict:
    from tqdm import tqdm

    start = time.perf_counter()
    procs = []
    for d in jobs:
        if _finished(d):
            continue  # this worker had finished before the interruption
        cmd = [sys.executable, "-m", "jaxmac.runs.workers", d, "--checkpoint-every",
               repr(float(checkpoint_seconds))] + (["--resume"] if resume else [])
        log = open(os.path.join(d, "worker.log"), "a")
        procs.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log, d))
    bar = tqdm(total=total_episodes, unit="ep", desc=f"{len(jobs)} workers", disable=not progress,
               dynamic_ncols=True)
    while any(p.poll() is None for p, _, _ in procs):
        time.sleep(2.0)
        bar.n = sum(_episodes_done(d) for d in jobs)
        bar.refresh()
    bar.n = sum(_episodes_done(d) for d in jobs)
    bar.close()
    failed = [(d, p.returncode) for p, log, d in procs if p.returncode != 0]
    for _, log, _ in procs:
        log.close()
    if failed:
        raise RuntimeError(f"worker(s) failed: {failed}; see worker.log in each folder; "
                           f"jaxmac train --resume {out_dir} continues")
    return merge(out_dir, jobs, time.perf_counter() - start)


def merge(out_dir: str, jobs: list[str], wall_seconds: float) -> dict[str, Any]:
    """Concatenate the workers' metrics and summaries (ordered by seed) and plot the curve.

    ``wall_seconds`` is this call's wall time; a resumed run reports the longest worker's accumulated
    time if that is larger (workers run side by side and each counts its own time across resumes)."""
    from jaxmac.plotting import plot_learning_curve

    summaries = []
    rows: list[list[str]] = []
    header = None
    for d in jobs:
        with open(os.path.join(d, "summary.json")) as f:
            summaries.append(json.load(f))
        with open(os.path.join(d, "metrics.csv"), newline="") as f:
            reader = csv.reader(f)
            header = next(reader)
            rows.extend(reader)
    with open(os.path.join(out_dir, "metrics.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    first = summaries[0]
    summary = {k: first[k] for k in ("scenario", "algorithm", "episodes", "discount", "optimal_return")}
    for key in ("final_greedy_return", "final_greedy_return_undiscounted"):
        summary[key] = [v for s in summaries for v in s[key]]
        summary[key + "_mean"] = sum(summary[key]) / len(summary[key])
    wall_seconds = max([wall_seconds] + [s["wall_seconds"] for s in summaries if "wall_seconds" in s])
    summary.update(seeds=len(summary["final_greedy_return"]), seed_offset=first.get("seed_offset", 0),
                   workers=len(jobs), wall_seconds=wall_seconds)
    write_json_atomic(os.path.join(out_dir, "summary.json"), summary)
    plot_learning_curve(os.path.join(out_dir, "metrics.csv"), os.path.join(out_dir, "curve.png"),
                        f"{summary['algorithm']} on {summary['scenario']}", summary["optimal_return"],
                        label=summary["algorithm"])
    return summary


def _main(argv: list[str]) -> int:
    """Worker entry point: ``python -m jaxmac.runs.workers JOB_DIR [--checkpoint-every SECONDS] [--resume]``."""
    from jaxmac.runs.loop import resume_run, train_run
    from jaxmac.runs.resources import enable_compilation_cache

    enable_compilation_cache()
    job_dir = argv[0]
    seconds = float(argv[argv.index("--checkpoint-every") + 1]) if "--checkpoint-every" in argv else 120.0
    if "--resume" in argv and os.path.exists(os.path.join(job_dir, "config.json")):
        resume_run(job_dir, progress=False, checkpoint_seconds=seconds)
        return 0
    with open(os.path.join(job_dir, "job.json")) as f:
        job = json.load(f)
    train_run(TrainConfig.from_dict(job["config"]), job["seeds"], job_dir, seed_offset=job["seed_offset"],
              progress=False, checkpoint_seconds=seconds, log=job.get("log"))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
