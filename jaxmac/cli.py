"""The ``jaxmac`` command line.

    jaxmac rollout --env boxpushing-6x6 --episodes 1000   # random-policy rollouts + rendering
"""

from __future__ import annotations

import argparse
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
    print()
    print(f"{args.episodes} uniform-random episodes (seed {args.seed}, {seconds:.1f} s including compilation):")
    print(f"  discounted return (gamma={env.spec.discount}): mean {stats['disc_return'].mean():.3f}"
          f" ± {stats['disc_return'].std(ddof=1) / np.sqrt(args.episodes):.3f} (s.e.)")
    print(f"  undiscounted return: mean {stats['return'].mean():.3f}")
    print(f"  episode length: mean {stats['length'].mean():.1f}; task completed in "
          f"{100 * stats['terminated'].mean():.1f}% of episodes")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxmac", description="Asynchronous macro-action MARL in JAX.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("rollout", help="random-policy rollouts of an env, with a text rendering and returns")
    p.add_argument("--env", default="boxpushing-6x6", help="envs_jax.make name, e.g. boxpushing-6x6")
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_rollout)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "episodes", 1) < 1:
        print(f"jaxmac: --episodes must be >= 1, got {args.episodes}", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except ValueError as err:
        print(f"jaxmac: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
