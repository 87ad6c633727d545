"""ToMacVF's Q_tot along one greedy episode of a trained run, against the discounted return that episode received
(``jaxmac qtot``).

    jaxmac qtot RUN_FOLDER [--seed-index I] [--key K]

Plays one greedy episode of seed I at the run's newest checkpoint, writes it into an episode slot as training
does, and prints (to the terminal; nothing is written to the run folder) for rows 0 … H the Q_tot of the greedy
joint action (conditional on busy agents, D9) beside the discounted return-to-go from that row. Row H of a truncated
episode is the time-limit bootstrap: a target of the last step, never itself a prediction. A seed whose values are
right shows the two columns close; an over-valued convention shows Q_tot far above what the episode pays.
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``jaxmac qtot``'s arguments (the CLI's subcommand and ``main`` share them)."""
    p.add_argument("run_dir", metavar="RUN_FOLDER", help="a run folder of ToMacVF (algorithm tomacvf)")
    p.add_argument("--seed-index", type=int, default=0, help="which of the run's seeds")
    p.add_argument("--key", type=int, default=0, help="the episode's PRNG key")


def qtot_along_episode(run_dir: str, seed_index: int = 0, key: int = 0):
    """``qtot_rows`` of one greedy episode (PRNG key ``key``) of a run's seed at its newest checkpoint."""
    import jax

    from jaxmac.collect import run_episode
    from jaxmac.runs.loop import load_run

    trainer, state, _, _ = load_run(run_dir)
    config, env, algo = trainer.config, trainer.env, trainer.algorithm
    if config.algorithm != "tomacvf":
        raise ValueError(f"{run_dir} trains {config.algorithm!r}; this reads ToMacVF's mixer (algorithm 'tomacvf')")
    seeds = jax.tree_util.tree_leaves(state.params)[0].shape[0]
    if not 0 <= seed_index < seeds:
        raise ValueError(f"--seed-index {seed_index}: {run_dir} has {seeds} seeds (indices 0 to {seeds - 1})")
    params = jax.tree_util.tree_map(lambda x: x[seed_index], state.params)
    reset_ts, traj, _ = jax.jit(lambda p, k: run_episode(env, algo.act, algo.init_carry, p, k, 0.0))(
        params, jax.random.key(key))
    return qtot_rows(config, env, params, reset_ts, traj)


def qtot_rows(config, env, params, reset_ts, traj):
    """(Q_tot f32[H + 1] of the greedy joint action at every row of the episode's slot, the discounted
    return-to-go f32[length] from every step, the episode's length). The rollout is one episode (leaves
    ``[H, ...]``) of ToMacVF's greedy policy with ``params``."""
    import jax
    import numpy as np

    from jaxmac.algos.tomacvf import build_model, greedy_q_tot
    from jaxmac.buffer.episode import SlotConfig, write_episode

    slot_config = SlotConfig.from_spec(env.spec)
    batch = jax.tree_util.tree_map(lambda x: x[None], write_episode(slot_config, reset_ts, traj))
    q_tot = np.asarray(greedy_q_tot(build_model(config, env), params, batch))[0]
    length = int(batch.length[0])
    reward, gamma = np.asarray(traj.reward)[:length], env.spec.discount
    to_go = np.array([np.sum(reward[t:] * gamma ** np.arange(length - t)) for t in range(length)])
    return q_tot, to_go, length


def run(args: argparse.Namespace) -> int:
    """``jaxmac qtot``: print Q_tot beside the return-to-go at a few rows of one greedy episode."""
    q_tot, to_go, length = qtot_along_episode(args.run_dir, args.seed_index, args.key)
    print(f"{args.run_dir}, seed index {args.seed_index}: greedy episode of {length} steps")
    print(" row   Q_tot(greedy)   return-to-go")
    for t in sorted({0, 1, 5, 10, 20, 40, 60, 80, 90, length - 1, length} & set(range(length + 1))):
        suffix = f"{to_go[t]:14.1f}" if t < length else "   (bootstrap row)"
        print(f"{t:4d} {q_tot[t]:15.1f} {suffix}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``jaxmac qtot ARGS`` from Python."""
    p = argparse.ArgumentParser(prog="jaxmac qtot", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))
