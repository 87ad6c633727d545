"""The ``jaxmac`` command line.

    jaxmac rollout --env boxpushing-6x6 --episodes 1000   # random-policy rollouts + rendering
    jaxmac train --preset quickstart                      # ToMacVF learning Box Pushing 6x6 in a few minutes
    jaxmac train --scenario boxpushing-6x6 --seeds 8      # ToMacVF with the paper's settings, run folder
    jaxmac train --algorithm maccen_ddrqn --seeds 4       # a baseline with its original settings
    jaxmac train --scenario boxpushing-6x6 --seeds 4:8 --devices 2   # seeds 4-7, sharded over 2 devices
    jaxmac train --resume runs/RUN_DIR                    # continue a killed run
    jaxmac train --finish runs/RUN_DIR                    # end a run where it stands (a curve flat for long)
    jaxmac fork runs/RUN_DIR --out runs/NEW --set lr=1e-4 # a new run from its checkpoint, other settings
    jaxmac eval runs/RUN_DIR                              # greedy episode: text + PNG strip
    jaxmac sweep ablation --protocol cpu                  # one of the paper's experiments, cell by cell
    jaxmac results experiments/sweeps/cpu                 # its results page -> experiments/sweeps/cpu/results/
    jaxmac table runs/RUN_DIR ...                         # a Markdown table of finished runs
    jaxmac calibrate --pairs tomacvf@overcooked-B         # measured rates for `jaxmac sweep --dry-run --rates`
    jaxmac overlay --out fig.png --run "A=runs/RUN" ...   # curves of several runs (and originals) on one figure
    jaxmac qtot runs/RUN_DIR                              # ToMacVF's Q_tot along a greedy episode vs the return
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import numpy as np


def cmd_rollout(args) -> int:
    import envs_jax
    from jaxmac.collect import episode_returns, random_policy, run_episodes

    env = envs_jax.make(args.env)
    init_carry, act = random_policy()

    @jax.jit
    def rollouts(key):
        _, traj, final_state = run_episodes(env, act, init_carry, None, key, 0.0, args.episodes)
        return episode_returns(traj, env.spec.discount), final_state

    t0 = time.perf_counter()
    stats, final_state = jax.block_until_ready(rollouts(jax.random.key(args.seed)))
    seconds = time.perf_counter() - t0
    stats = {k: np.asarray(v) for k, v in stats.items()}
    first = jax.tree_util.tree_map(lambda x: x[0], final_state)
    print(f"{env.spec.name}: final state of random episode 0 (after {int(stats['length'][0])} steps)")
    print(env.render(first))
    legend = getattr(env, "render_legend", ())  # (symbol, meaning) pairs, beside each env's render
    if legend:
        width = max(len(symbol) for symbol, _ in legend)
        print("legend:")
        for symbol, meaning in legend:
            print(f"  {symbol.ljust(width)}  {meaning}")
    print()
    print(f"{args.episodes} uniform-random episodes (seed {args.seed}, {seconds:.1f} s including compilation):")
    print(f"  discounted return (gamma={env.spec.discount}): mean {stats['disc_return'].mean():.3f}"
          f" ± {stats['disc_return'].std(ddof=1) / np.sqrt(args.episodes):.3f} (s.e.)")
    print(f"  undiscounted return: mean {stats['return'].mean():.3f}")
    print(f"  episode length: mean {stats['length'].mean():.1f}; task completed in "
          f"{100 * stats['terminated'].mean():.1f}% of episodes")
    return 0


def cmd_train(args) -> int:
    from jaxmac.config import parse_assignments
    from jaxmac.presets import preset_config, scenario_config
    from jaxmac.runs import default_out_dir, enable_compilation_cache, finish_run, resume_run, train_run, use_host_devices
    from jaxmac.runs.workers import is_worker_run, resume_workers, train_workers

    if args.list_settings:
        from jaxmac.config_files import load_config_file, settings_listing

        loaded = load_config_file(args.config, args.algorithm) if args.config is not None else None
        print(settings_listing(args.algorithm or (loaded and (loaded.config or loaded).algorithm) or "tomacvf"))
        return 0
    if args.config is not None and (args.resume or args.finish or args.preset is not None):
        raise ValueError(f"--config {args.config} starts a new run from a file; --resume, --finish and --preset "
                         "cannot be combined with it")
    devices = 1 if args.devices is None else args.devices
    if devices > 1 and args.workers not in (None, 1):
        raise ValueError(f"--devices {devices} and --workers {args.workers}: choose one way to split the seeds "
                         "(--devices: one process, seeds sharded over devices; --workers: several processes)")
    use_host_devices(devices)  # before JAX starts: on a CPU, split the host into that many devices
    enable_compilation_cache()
    if args.finish:
        if args.resume or any(v is not None for v in (args.scenario, args.seeds, args.preset, args.workers,
                                                       args.algorithm, args.episodes, args.out, args.log)) \
                or args.set or args.tiny or args.paper:
            raise ValueError("--finish ends a run as it stands and takes no other option than --devices")
        if is_worker_run(args.finish):
            raise ValueError(f"--finish {args.finish}: a run of several worker processes cannot be finished early "
                             "(finish each worker's folder under it instead)")
        summary = finish_run(args.finish)
        print(f"finished at {summary['stopped_at']} of {summary['budget']} episodes per seed")
        out = args.finish
    elif args.resume:
        from jaxmac.runs import diverged_record

        diverged = diverged_record(args.resume) is not None
        ignored = [flag for flag, given in (("--scenario", args.scenario is not None), ("--seeds", args.seeds is not None),
                                            ("--preset", args.preset is not None),
                                            ("--set", bool(args.set) and not diverged), ("--tiny", args.tiny), ("--paper", args.paper),
                                            ("--out", args.out is not None), ("--workers", args.workers is not None),
                                            ("--algorithm", args.algorithm is not None)) if given]
        if ignored:
            raise ValueError(f"--resume continues the run as it was configured; {', '.join(ignored)} cannot change it "
                             "(only --episodes, to train it further, --set for a run that diverged, and --log)")
        if is_worker_run(args.resume):
            summary = resume_workers(args.resume, progress=not args.no_progress, episodes=args.episodes,
                                     checkpoint_seconds=args.checkpoint_every, log=args.log)
        else:
            summary = resume_run(args.resume, progress=not args.no_progress, episodes=args.episodes,
                                 assignments=args.set, devices=devices, checkpoint_seconds=args.checkpoint_every,
                                 log=args.log)
        out = args.resume
    else:
        if args.preset is not None:
            clash = [flag for flag, given in (("--scenario", args.scenario is not None), ("--tiny", args.tiny),
                                              ("--algorithm", args.algorithm is not None), ("--paper", args.paper))
                     if given]
            if clash:
                raise ValueError(f"--preset {args.preset} fixes the scenario, learner and sizes; {', '.join(clash)} "
                                 "cannot be combined with it (--seeds, --episodes and --set can)")
            config, preset = preset_config(args.preset)
            print(f"preset {args.preset}: {preset.about}")
            if args.seeds is None:
                args.seeds = (0, preset.seeds)
            if args.episodes is not None:
                config = config.override(episodes=args.episodes)
            config = config.override_strings(args.set)
        elif args.config is not None:  # a file (or a run's config.json), then --episodes/--set on top
            from jaxmac.config_files import config_from_file

            config, loaded = config_from_file(args.config, args.scenario, args.algorithm, args.tiny, args.paper,
                                              args.set, args.episodes)
            print(f"config {args.config}" + (f": {loaded.about}" if loaded.about else ""))
            if args.seeds is None and loaded.seeds is not None:
                args.seeds = loaded.seeds
        else:
            algorithm = args.algorithm or "tomacvf"
            overrides = parse_assignments(args.set, algorithm)
            if args.episodes is not None:
                overrides["episodes"] = args.episodes
            config = scenario_config(args.scenario or "boxpushing-6x6", algorithm, tiny=args.tiny, paper=args.paper,
                                     overrides=overrides)
        out = args.out or default_out_dir(config)
        offset, seeds = (0, 1) if args.seeds is None else args.seeds
        workers = 1 if args.workers is None else args.workers
        if workers != 1:  # train_workers validates the count
            summary = train_workers(config, seeds, out, workers, progress=not args.no_progress, seed_offset=offset,
                                    checkpoint_seconds=args.checkpoint_every, log=args.log)
        else:
            summary = train_run(config, seeds, out, seed_offset=offset, progress=not args.no_progress,
                                devices=devices, checkpoint_seconds=args.checkpoint_every, log=args.log)
    if summary is not None:
        print(f"run folder: {out}")
        print(f"final greedy return ({summary['scenario']}, gamma={summary['discount']}): "
              f"mean {summary['final_greedy_return_mean']:.3f} over {summary['seeds']} seeds "
              f"(undiscounted {summary['final_greedy_return_undiscounted_mean']:.3f}); "
              f"{summary['episodes']} episodes per seed in {summary['wall_seconds']:.0f} s")
    return 0


def cmd_eval(args) -> int:
    from jaxmac.runs.evaluation import evaluate_run
    from jaxmac.runs import enable_compilation_cache

    enable_compilation_cache()
    txt, png, stats = evaluate_run(args.run_dir, args.seed_index, args.episodes, args.gif)
    with open(txt) as f:
        print(f.read())
    per, n, gamma = stats["episodes"], len(stats["keys"]), stats["discount"]
    print(f"greedy policy of seed {args.seed_index} (checkpoint after {stats['chunks_trained']} chunks), {n} "
          f"episode{'s' if n > 1 else ''} (episode e from jax.random.key({stats['keys'][0]} + e)):")
    print(f"  episode  steps  task done  discounted (gamma={gamma})  undiscounted")
    for e in range(n):
        print(f"  {e:7d}  {per['length'][e]:5d}  {'yes' if per['terminated'][e] else 'no':>9}  "
              f"{per['disc_return'][e]:{20 + len(str(gamma))}.3f}  {per['return'][e]:12.3f}")
    disc, undisc = np.asarray(per["disc_return"]), np.asarray(per["return"])
    se = (lambda x: f" ± {x.std(ddof=1) / np.sqrt(n):.3f} (s.e.)") if n > 1 else (lambda x: "")
    print(f"  mean over {n} episodes: discounted {disc.mean():.3f}{se(disc)}, undiscounted "
          f"{undisc.mean():.3f}{se(undisc)}")
    if n > 1 and len(set(per["disc_return"])) == 1 and len(set(per["length"])) == 1:
        print(f"  (all {n} episodes alike: without noise in the env, a greedy policy plays the same episode from "
              "every key)")
    width, height = stats["png_size"]
    print(f"wrote {txt} (episode 0 as text), {png} (episode 0 drawn, {width} x {height} px)"
          + (f" and {stats['gif']} ({stats['gif_frames']} frames)" if stats["gif"] else ""))
    return 0


def seed_range(text: str) -> tuple[int, int]:
    """``--seeds`` as (first seed, count): ``"4"`` -> (0, 4), ``"4:8"`` -> (4, 4)."""
    try:
        if ":" in text:
            first, end = (int(v) for v in text.split(":"))
        else:
            first, end = 0, int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: give a count N (seeds 0..N-1) or a range A:B "
                                         "(seeds A..B-1)") from None
    if first < 0 or end <= first:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: need 0 <= A < B (seeds A..B-1) or N >= 1")
    return first, end - first


def cmd_sweep(args) -> int:
    from jaxmac.runs import enable_compilation_cache, live_holder, use_host_devices
    from jaxmac.runs.resources import default_devices, fit_devices
    from jaxmac.study.stats import own_rate, trained_episodes
    from jaxmac.study.sweep import (PROTOCOLS, cell_status, diverged_text, estimate_seconds, fit_to_existing,
                                    load_rates, not_run_cells, plan, run_sweep)

    methods = None
    if args.config is not None:  # a method file: methods added to (or replacing) the experiment's
        from jaxmac.config_files import sweep_methods

        methods = sweep_methods(args.config, args.experiment)
    out = args.out or os.path.join("experiments", "sweeps", args.protocol)
    # seeds that seed-range folders of a cell already hold are taken from them, not trained again
    cells = fit_to_existing(plan(args.experiment, args.protocol, args.seeds, args.only, methods), out)
    # by default one process shards each cell's seeds over every core it may use (faster than a process per core)
    if args.devices is not None:
        devices = args.devices
    else:
        local = args.cluster != "ray" and not args.dry_run
        devices = default_devices([c.seeds for c in cells]) if local else 1
    use_host_devices(devices)  # before JAX starts
    if args.devices is None and devices > 1:
        devices = fit_devices(devices, [c.seeds for c in cells])
    print(f"sweep {args.experiment}, protocol {args.protocol} ({PROTOCOLS[args.protocol].about}): {len(cells)} cells "
          f"into {out}" + (f", each cell's seeds sharded over {devices} devices" if devices > 1 else ""))
    if args.dry_run:
        rates = load_rates(args.rates)
        total, unknown, own = 0.0, 0, 0
        for cell in cells:
            status = cell_status(out, cell)
            trained = trained_episodes(os.path.join(out, cell.path), cell.seeds) if status != "new" else 0
            rate = own_rate(os.path.join(out, cell.path)) if status != "new" else None
            if status == "diverged":
                print(f"  {cell.path}: {cell.episodes} episodes per seed, diverged at {trained} "
                      f"({diverged_text(os.path.join(out, cell.path))}), not rerun: nothing left to run")
                continue
            if rate is not None:  # a started cell's own pace beats another scenario's
                own += status != "done"
                estimate = (cell.seeds * (cell.episodes - trained) / rate, "its own rate so far")
            else:
                estimate = estimate_seconds(cell, rates, cell.episodes - trained)
            if status == "done":
                cost = "nothing left to run"
            elif estimate is None:
                unknown += 1
                cost = "cost not measured"
            else:
                total += estimate[0]
                cost = (f"~{estimate[0] / 3600:.1f} core-h{' left' if trained else ''} "
                        + (f"({estimate[1]})" if rate is not None else f"(rate of {estimate[1]})"))
            holder = live_holder(os.path.join(out, cell.path)) if status != "done" else None
            if holder:  # its seeds' folder is a live process's now: say so rather than "interrupted"
                status = f"running (pid {holder['pid']}, since {holder.get('since', '?')})"
            print(f"  {cell.path}: {cell.episodes} episodes per seed, {status}"
                  + (f" at {trained}" if trained and status != "done" else "") + f", {cost}")
        for scenario, method, why in not_run_cells(args.experiment, args.protocol):
            print(f"  {scenario}/{method}: not run under this protocol: {why}")
        print(f"estimated {total / 3600:.1f} core-hours left at the measured rates of {args.rates}"
              + (f" ({own} started cell{'s' if own > 1 else ''} at {'their' if own > 1 else 'its'} own rate so far)"
                 if own else "")
              + (f"; {unknown} cells not measured" if unknown else ""))
        return 0
    if args.cluster == "ray":
        return _sweep_on_ray(args, cells, out)
    if args.ray_address or args.gpus_per_cell or args.cpus_per_cell != 1.0 or args.shared_fs != "auto":
        raise ValueError("--ray-address, --cpus-per-cell, --gpus-per-cell and --shared-fs are options of "
                         "--cluster ray")
    enable_compilation_cache()
    run_sweep(cells, out, devices=devices, progress=not args.no_progress, checkpoint_seconds=args.checkpoint_every)
    return 0


def _sweep_on_ray(args, cells, out) -> int:
    """``jaxmac sweep --cluster ray``: every cell a Ray task (jaxmac/study/cluster.py)."""
    try:
        import ray  # noqa: F401  (an optional extra)
    except ImportError as err:
        raise ValueError(f"--cluster ray needs Ray ({err}): pip install -e \".[cluster]\"") from None
    from jaxmac.study.cluster import run_sweep_ray
    from jaxmac.study.sweep import load_rates

    shared = {"auto": None, "yes": True, "no": False}[args.shared_fs]
    try:
        done = run_sweep_ray(cells, out, devices=args.devices, progress=not args.no_progress,
                             checkpoint_seconds=args.checkpoint_every, address=args.ray_address,
                             cpus_per_cell=args.cpus_per_cell, gpus_per_cell=args.gpus_per_cell, retries=args.retries,
                             shared=shared, rates=load_rates(args.rates))
    except KeyboardInterrupt:
        return 130
    failed = {path: what for path, what in done.items() if what.startswith("failed")}
    finished = sum(what in ("trained", "resumed", "extended", "skipped") for what in done.values())
    print(f"{finished} of {len(cells)} cells finished" + (f"; {len(failed)} failed: {', '.join(failed)}" if failed
                                                            else ""))
    return 1 if failed else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxmac", description="Asynchronous macro-action MARL in JAX.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("rollout", help="random-policy rollouts of an env, with a text rendering and returns")
    p.add_argument("--env", default="boxpushing-6x6", help="envs_jax.make name, e.g. boxpushing-6x6")
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_rollout)

    from jaxmac.algos.registry import REGISTRY
    from jaxmac.presets import PRESETS
    from jaxmac.scenarios import SCENARIOS

    p = sub.add_parser("train", help="train a learner (default ToMacVF) on a scenario, vmapped over seeds")
    p.add_argument("--preset", default=None, choices=list(PRESETS),
                   help="a named configuration (scenario, learner, settings, seeds): " + "; ".join(
                       f"{name}: {preset.about}" for name, preset in PRESETS.items()))
    p.add_argument("--scenario", default=None, choices=list(SCENARIOS), help="default: boxpushing-6x6")
    p.add_argument("--algorithm", default=None, choices=list(REGISTRY),
                   help="default: tomacvf; each starts from its original script's settings for the scenario")
    p.add_argument("--seeds", type=seed_range, default=None, metavar="N|A:B",
                   help="N: seeds 0..N-1; A:B: seeds A..B-1, e.g. 4:8 adds four seeds to a run of --seeds 4 (vmapped "
                        "in one process; default 1)")
    p.add_argument("--episodes", type=int, default=None, help="training episodes per seed (default: the paper's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config value (--list-settings lists the keys)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="start from a config file: TOML, YAML or JSON naming a scenario, an algorithm, seeds and "
                        "settings (experiments/configs/), or a run's config.json (or its folder) to repeat that run; "
                        "--episodes, --seeds and --set apply on top")
    p.add_argument("--list-settings", action="store_true",
                   help="print every setting key (shared, and the --algorithm's block) with its type, default and "
                        "meaning, and exit")
    p.add_argument("--tiny", action="store_true", help="tiny networks and budgets (smoke runs)")
    p.add_argument("--paper", action="store_true",
                   help="the publication's settings where jaxmac's defaults differ (ToMacVF on Overcooked and "
                        "Warehouse: docs/tomacvf-settings.md says what and why)")
    p.add_argument("--out", default=None, help="run folder (default: runs/SCENARIO-ALGO-TIME)")
    p.add_argument("--finish", default=None, metavar="RUN_DIR",
                   help="end a run where its newest checkpoint stands (final evaluation, summary, plot) without "
                        "training the rest of its budget")
    p.add_argument("--resume", default=None, metavar="RUN_DIR", help="continue a killed run (with --episodes N: train a run further, to N episodes per seed)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes, each vmapping its share of the seeds (one JAX process uses about one core; default 1)")
    p.add_argument("--devices", type=int, default=None,
                   help="devices to shard the seeds over, in one process (jax.sharding; on a CPU the host is split "
                        "into that many devices; default 1); the seeds must be a multiple of it")
    p.add_argument("--checkpoint-every", type=float, default=120.0, metavar="SECONDS",
                   help="save a checkpoint (and the metrics rows it covers) at most every SECONDS of training "
                        "(default 120; 0 = after every chunk, for a flaky machine)")
    p.add_argument("--log", default=None, choices=["none", "tensorboard", "wandb", "wandb:online"],
                   help="also log the metrics, as checkpoints cover them, to TensorBoard event files in the run folder "
                        "(pip install -e \".[tensorboard]\") or to a W&B run, offline unless wandb:online or "
                        "WANDB_MODE says otherwise (\".[wandb]\"); kept by --resume, which can also change it "
                        "(default none; docs/training.md)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)

    from jaxmac.study.sweep import EXPERIMENTS, PROTOCOLS

    p = sub.add_parser("sweep", help="run one of the paper's experiments: every (method, scenario) cell x seeds into "
                                     "one folder, skipping finished cells and resuming interrupted ones")
    p.add_argument("experiment", choices=list(EXPERIMENTS))
    p.add_argument("--protocol", default="cpu", choices=list(PROTOCOLS),
                   help="; ".join(f"{name}: {proto.about}" for name, proto in PROTOCOLS.items()).replace("%", "%%"))
    p.add_argument("--seeds", type=seed_range, default=None, metavar="N|A:B",
                   help="seeds of every cell instead of the protocol's count (A:B adds seeds A..B-1)")
    p.add_argument("--out", default=None, help="sweep folder (default: experiments/sweeps/PROTOCOL, shared by the "
                                               "experiments so that a cell two of them need runs once)")
    p.add_argument("--only", default=None, metavar="TEXT", help="only the cells whose path contains TEXT")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="a TOML (YAML, JSON) file of [[method]] tables (name, algorithm, label, settings, "
                        "scenario_settings) added to the experiment's methods, replacing one of the same name "
                        "(replace = true: instead of them); experiments/configs/sweep-methods.toml")
    p.add_argument("--devices", type=int, default=None,
                   help="devices to shard each cell's seeds over (as train; default: one per core this process may "
                        "use when every cell's seeds split evenly over them, else 1 — `taskset -c 0` makes it 1)")
    p.add_argument("--dry-run", action="store_true",
                   help="list the cells, their status and estimated cost, run nothing")
    p.add_argument("--rates", default=os.path.join("experiments", "protocol_rates.json"),
                   help="with --dry-run (and --cluster ray's ETA): measured rates (`jaxmac calibrate`) "
                        "to estimate cell costs")
    p.add_argument("--checkpoint-every", type=float, default=120.0, metavar="SECONDS",
                   help="checkpoint each cell at most every SECONDS of training (as train; default 120)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--cluster", default=None, choices=["ray"],
                   help="run every cell as a task on a Ray cluster (pip install -e \".[cluster]\"): retried when its "
                        "worker dies, resumed from its checkpoint; docs/sweeps.md")
    p.add_argument("--ray-address", default=None, metavar="ADDRESS",
                   help="with --cluster ray: the cluster to join (auto: the one this node belongs to; HOST:6379; "
                        "ray://HOST:10001); default: as ray.init(), the cluster in RAY_ADDRESS or started on this "
                        "machine, else a new local Ray instance on every core")
    p.add_argument("--cpus-per-cell", type=float, default=1.0, metavar="N",
                   help="with --cluster ray: CPUs each cell's task asks for (default 1)")
    p.add_argument("--gpus-per-cell", type=float, default=0.0, metavar="N",
                   help="with --cluster ray: GPUs each cell's task asks for (default 0; with N >= 1 the cell's seeds "
                        "are sharded over its N GPUs as --devices N; a fraction shares a GPU between cells)")
    p.add_argument("--retries", type=int, default=3, metavar="N",
                   help="with --cluster ray: times a cell whose worker or node died is run again, resuming from its "
                        "checkpoint (default 3; a cell's own error is never retried)")
    p.add_argument("--shared-fs", default="auto", choices=["auto", "yes", "no"],
                   help="with --cluster ray: whether the workers see the sweep folder (auto: each task looks); where "
                        "not, a cell trains on its node and its files come back to this process")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("eval", help="greedy episodes of a trained run: their returns, and the first one as text, "
                                    "a picture of its frames (PNG) and optionally a GIF")
    p.add_argument("run_dir")
    p.add_argument("--seed-index", type=int, default=0, help="which of the run's seeds")
    p.add_argument("--episodes", type=int, default=1,
                   help="greedy episodes to play (vmapped; episode e from jax.random.key(e)); each one's discounted "
                        "and undiscounted return is printed, and their mean (default 1)")
    p.add_argument("--gif", action="store_true", help="also write greedy_seedI.gif, one frame per step of episode 0")
    p.set_defaults(func=cmd_eval)

    from jaxmac.study.sweep import EXPERIMENTS, PROTOCOLS

    p = sub.add_parser("results", help="the results page of a sweep folder: figures, tables, statistics (RESULTS.md)")
    p.add_argument("sweep_dir", metavar="SWEEP_DIR", help="a folder of `jaxmac sweep` (e.g. experiments/sweeps/cpu)")
    p.add_argument("--out", default=None, help="folder of RESULTS.md and the figures (default: SWEEP_DIR/results)")
    p.add_argument("--experiments", nargs="+", default=list(EXPERIMENTS), choices=list(EXPERIMENTS),
                   help="the experiments on the page (default: all)")
    p.add_argument("--protocol", default=None, choices=list(PROTOCOLS),
                   help="the sweep's protocol (default: the folder's name if it is one, else the protocol the cells' "
                        "configurations match)")
    p.add_argument("--rates", default=os.path.join("experiments", "protocol_rates.json"),
                   help="measured training rates (`jaxmac calibrate`): what the cells not finished still cost")
    p.set_defaults(func=cmd_results)

    p = sub.add_parser("table", help="a Markdown table of finished run folders: final returns, settings, wall time")
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="finished run folders")
    p.set_defaults(func=cmd_table)

    from jaxmac.runs import fork, qtot
    from jaxmac.study import calibrate, overlay

    for name, module, func, about in (
            ("fork", fork, cmd_fork, ("a new run folder from a checkpoint of another run, with other settings that "
                                      "keep its shapes or another budget (train it with --resume)")),
            ("calibrate", calibrate, cmd_calibrate, ("measure what a sweep cell costs here (episodes/s per method "
                                                     "and scenario) into the rates file of `jaxmac sweep --rates`")),
            ("overlay", overlay, cmd_overlay, ("one figure overlaying the learning curves of jaxmac runs and of "
                                               "original MacroMARL runs")),
            ("qtot", qtot, cmd_qtot, "ToMacVF's Q_tot along one greedy episode of a run, beside the return-to-go")):
        p = sub.add_parser(name, help=about, description=module.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(func=func)
    return parser


def cmd_results(args) -> int:
    from jaxmac.study.results_page import write_page

    if not os.path.isdir(args.sweep_dir):
        raise ValueError(f"{args.sweep_dir}: no such sweep folder")
    out = args.out or os.path.join(args.sweep_dir, "results")
    from jaxmac.study.sweep import load_rates

    path = write_page(args.sweep_dir, out, args.experiments, args.protocol, load_rates(args.rates))
    print(f"wrote {path} (beside it a figure per experiment with a finished cell)")
    return 0


def cmd_table(args) -> int:
    import pathlib

    from jaxmac.study.results_table import table

    print(table([pathlib.Path(r) for r in args.runs]))
    return 0


def cmd_calibrate(args) -> int:
    from jaxmac.study.calibrate import run

    return run(args)


def cmd_overlay(args) -> int:
    from jaxmac.study.overlay import run

    return run(args)


def cmd_fork(args) -> int:
    from jaxmac.runs.fork import run

    return run(args)


def cmd_qtot(args) -> int:
    from jaxmac.runs.qtot import run

    return run(args)


def os_error_line(err: OSError) -> str:
    """One line for an expected OSError (a full disk, an unwritable path): what failed, on which file."""
    message = str(err)
    if type(err) is OSError or not message.startswith("cannot"):  # a plain OSError: "[Errno 28] ..." made readable
        what = err.strerror or message
        where = f" ({err.filename})" if err.filename else ""
        message = f"{what}{where}"
    return " ".join(message.split())


def main(argv: list[str] | None = None) -> int:
    """The CLI; an expected failure (a refused command, a broken file, a full disk) is one line on stderr and exit
    status 2, never a traceback."""
    args = build_parser().parse_args(argv)
    if any(v is not None and v < 1 for v in (getattr(args, "episodes", None), getattr(args, "devices", None))):
        print("jaxmac: --episodes and --devices must be >= 1", file=sys.stderr)
        return 2
    every = getattr(args, "checkpoint_every", None)
    if every is not None and not every >= 0:
        print(f"jaxmac: --checkpoint-every {every}: give a number of seconds >= 0", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except (ValueError, RuntimeError) as err:
        print(f"jaxmac: {' '.join(str(err).split())}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"jaxmac: {os_error_line(err)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
