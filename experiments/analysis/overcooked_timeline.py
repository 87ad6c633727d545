"""Where a trained Overcooked policy spends its steps, against the scripted policy (the ceiling).

For the scripted policy (``envs_jax.overcooked.scripted``) and the greedy policy of each seed of a run folder (its
newest checkpoint, as ``jaxmac eval`` plays it), one episode's reward times: the steps of the three chops (+10 each,
net of the −0.1 step cost) and of the delivery (+200); the plating phase from the last chop to the delivery (the
steps the learned policies lose on Overcooked-C); and when each agent set off for a plate (the step an agent chose
"get plate 1" or "get plate 2").

    python experiments/analysis/overcooked_timeline.py RUN [RUN ...] [--key 0]

Greedy policies and the scripted one are deterministic here, so one episode per seed says it all (``jaxmac eval RUN
--episodes 10`` shows the ten alike).
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

import envs_jax
from envs_jax.overcooked.scripted import scripted_actions
from jaxmac.runs import read_meta
from jaxmac.runs.evaluation import play_greedy


def timeline(rewards: np.ndarray, done: np.ndarray, chosen: np.ndarray, mac: np.ndarray, names: tuple) -> dict:
    """One episode's reward times (1-based steps), its plating phase and its plate fetches.

    ``rewards f32[H]``, ``done bool[H]`` (step t's at index t − 1), ``chosen bool[H, n]`` (agent i chose a
    macro-action for step t), ``mac i32[H, n]`` (the macro-action each agent ran at step t), ``names``: agent 0's
    macro-action names (the same for every agent on Overcooked)."""
    end = int(np.argmax(done)) + 1 if done.any() else len(rewards)
    rewards = rewards[:end]
    chops = [t + 1 for t, r in enumerate(rewards) if 5 < r < 100 for _ in range(round((r + 0.1) / 10))]  # 2 at once: 19.9
    deliveries = [t + 1 for t, r in enumerate(rewards) if r > 100]
    plates = [a for a, name in enumerate(names) if name.startswith("get plate")]
    fetches = [(t + 1, f"A{i + 1}", names[int(mac[t, i])]) for t in range(end) for i in range(mac.shape[1])
               if chosen[t, i] and int(mac[t, i]) in plates]
    out = {"length": end, "return": round(float(rewards.sum()), 1), "chops": chops, "delivery": deliveries}
    if chops and deliveries:
        out["plating_steps"] = deliveries[0] - chops[-1]
    out["plate_fetches"] = fetches
    return out


def choices(reset_mac_done: np.ndarray, mac_done: np.ndarray) -> np.ndarray:
    """bool[H, n]: agent i chose at step t (it was free after step t − 1; every agent chooses at the first step)."""
    return np.concatenate([reset_mac_done[None], mac_done[:-1]], axis=0)


def episode_timeline(env, reset_ts, traj) -> dict:
    """``timeline`` of one episode's ``reset_ts`` and ``traj`` (leaves ``[H, ...]``)."""
    return timeline(np.asarray(traj.reward), np.asarray(traj.done),
                    choices(np.asarray(reset_ts.mac_done), np.asarray(traj.mac_done)), np.asarray(traj.mac),
                    env.spec.action_names[0])


def scripted_episode(scenario: str, key: int) -> dict:
    env = envs_jax.make(scenario)

    def play(key):
        k_reset, k_steps = jax.random.split(key)
        state, ts = env.reset(k_reset)

        def body(carry, k):
            state, ts = carry
            new_state, new_ts = env.step(k, state, scripted_actions(env, state))
            state = jax.tree_util.tree_map(lambda old, new: jnp.where(ts.done, old, new), state, new_state)
            return (state, new_ts), new_ts

        _, traj = jax.lax.scan(body, (state, ts), jax.random.split(k_steps, env.spec.horizon))
        return ts, traj

    return episode_timeline(env, *jax.jit(play)(jax.random.key(key)))


def learned_episodes(run_dir: str, seeds: int, key: int) -> list[dict]:
    """``timeline`` of one greedy episode of each of the run's ``seeds`` seeds, with its discounted return."""
    out = []
    for index in range(seeds):
        play = play_greedy(run_dir, seed_index=index, episodes=1, key=key)
        row = {"seed_index": index, **episode_timeline(play.env, play.reset_ts, play.traj)}
        row["disc_return"] = round(float(play.stats["disc_return"][0]), 1)
        out.append(row)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run folders of an Overcooked scenario, with a checkpoint")
    parser.add_argument("--key", type=int, default=0, help="the episode's key (as jaxmac eval's)")
    args = parser.parse_args(argv)
    try:
        metas = {run_dir: read_meta(run_dir) for run_dir in args.runs}
    except ValueError as err:
        parser.error(str(err))
    scenarios = {meta["config"]["scenario"] for meta in metas.values()}
    bad = sorted(s for s in scenarios if not s.startswith("overcooked-"))
    if bad:
        parser.error(f"scenario {bad}: this analysis reads Overcooked runs only (overcooked-A, -B, -C)")
    for scenario in sorted(scenarios):
        print(f"{scenario} scripted: {scripted_episode(scenario, args.key)}")
    for run_dir in args.runs:
        for row in learned_episodes(run_dir, int(metas[run_dir]["seeds"]), args.key):
            print(f"{run_dir} {row}")


if __name__ == "__main__":
    main()
