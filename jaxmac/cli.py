"""The ``jaxmac`` command line.

    jaxmac rollout --env boxpushing-6x6 --episodes 1000   # random-policy rollouts + rendering
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np


def episode_returns(rewards: np.ndarray, done: np.ndarray, gamma: float) -> dict[str, np.ndarray]:
    """Per-episode returns of fixed-length rollouts without auto-reset.

    rewards, done: [E, T]; steps after the first ``done`` do not count.
    Returns ``length`` [E], ``return`` (undiscounted) and ``disc_return`` (Σ γ^t r_t) [E].
    """
    done = done.astype(bool)
    alive = np.concatenate([np.ones_like(done[:, :1]), ~done[:, :-1]], 1).cumprod(1).astype(bool)
    discount = gamma ** np.arange(rewards.shape[1])
    return {
        "length": alive.sum(1),
        "return": (rewards * alive).sum(1),
        "disc_return": (rewards * alive * discount).sum(1),
    }


def random_rollouts(env, key, episodes: int):
    """``episodes`` vmapped random-policy episodes of ``horizon`` steps (no auto-reset)."""
    from envs_jax.policies import uniform_random_actions

    def one(key):
        state, ts = env.reset(key)

        def body(carry, key):
            state, ts = carry
            k_act, k_step = jax.random.split(key)
            new_state, new_ts = env.step(k_step, state, uniform_random_actions(k_act, ts.avail_actions))
            # Once the episode is over keep its final state (the env itself is not absorbing).
            state, ts = jax.tree_util.tree_map(lambda a, b: jnp.where(ts.done, a, b), (state, ts), (new_state, new_ts))
            return (state, ts), (new_ts.reward, new_ts.terminated, new_ts.truncated)

        keys = jax.random.split(key, env.spec.horizon)
        return jax.lax.scan(body, (state, ts), keys)

    return jax.jit(jax.vmap(one))(jax.random.split(key, episodes))


def cmd_rollout(args) -> int:
    import envs_jax

    env = envs_jax.make(args.env)
    t0 = time.perf_counter()
    (final_state, _), (rewards, terminated, truncated) = random_rollouts(
        env, jax.random.key(args.seed), args.episodes
    )
    jax.block_until_ready(rewards)
    seconds = time.perf_counter() - t0
    terminated, truncated = np.asarray(terminated), np.asarray(truncated)
    stats = episode_returns(np.asarray(rewards), terminated | truncated, env.spec.discount)
    completed = terminated.any(1)  # the first done of every episode is its only terminal step
    first = jax.tree_util.tree_map(lambda x: x[0], final_state)
    print(f"{env.spec.name}: final state of random episode 0 (after {int(stats['length'][0])} steps)")
    print(env.render(first))
    print()
    print(f"{args.episodes} uniform-random episodes (seed {args.seed}, {seconds:.1f} s including compilation):")
    print(f"  discounted return (gamma={env.spec.discount}): mean {stats['disc_return'].mean():.3f}"
          f" ± {stats['disc_return'].std(ddof=1) / np.sqrt(args.episodes):.3f} (s.e.)")
    print(f"  undiscounted return: mean {stats['return'].mean():.3f}")
    print(f"  episode length: mean {stats['length'].mean():.1f}; task completed in "
          f"{100 * completed.mean():.1f}% of episodes")
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
