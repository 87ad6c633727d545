"""Greedy decentralised episodes of a trained run, rendered as text and as a PNG strip."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.collect import episode_returns, run_episode


def decision_timesteps(reset_ts, traj):
    """The timestep each step's actions were chosen on (reset, then the first H − 1 of ``traj``): leaves [H, ...]."""
    return jax.tree_util.tree_map(lambda first, rest: jnp.concatenate([first[None], rest[:-1]]), reset_ts, traj)


def values_along(algo, params, chosen_on) -> np.ndarray:
    """f32[H, n, A]: ``algo.values`` at every step of a greedy episode, given the timesteps its choices were made on
    (``decision_timesteps``), with the carry stepped by ``act`` as while acting."""

    def body(carry, ts):
        q = algo.values(params, carry, ts)
        carry, _ = algo.act(params, carry, ts, jax.random.key(0), 0.0)
        return carry, q

    return np.asarray(jax.lax.scan(body, algo.init_carry(chosen_on.mac.shape[1]), chosen_on)[1])


def values_line(names: tuple[str, ...], q: np.ndarray, avail: np.ndarray) -> str:
    """``Q: Push 1.10  GT_BB1 1.02 ...``: an agent's available macro-actions and their Q_i, best first."""
    order = [int(a) for a in np.argsort(-q, kind="stable") if avail[a]]
    return "Q: " + "  ".join(f"{names[a]} {q[a]:.2f}" for a in order)


def greedy_episode_frames(out_dir: str, seed_index: int = 0, key: int = 0) -> tuple[list[str], dict]:
    """Text frames (reset and every step until the episode ends) of one greedy episode of the
    given seed's newest checkpoint, and that episode's returns. For learners with per-agent utilities
    (``Algorithm.values``), each frame after a choice lists every free agent's best available macro-actions with
    their Q_i — what the greedy choice was made from."""
    from jaxmac.run import load_run

    trainer, state, chunks, meta = load_run(out_dir)
    if chunks == 0:
        raise ValueError(f"{out_dir} has no checkpoint (none saved yet, or none that restores): there is no trained "
                         f"policy to show; train it further first (jaxmac train --resume {out_dir})")
    if not 0 <= seed_index < meta["seeds"]:
        raise ValueError(f"seed_index={seed_index} is out of range; the run has seeds 0..{meta['seeds'] - 1}")
    env, algo = trainer.env, trainer.algorithm
    params = jax.tree_util.tree_map(lambda x: x[seed_index], state.params)
    run = jax.jit(lambda p, k: run_episode(env, algo.act, algo.init_carry, p, k, 0.0, record_states=True))
    reset_ts, traj, states = run(params, jax.random.key(key))
    stats = {k: float(v) for k, v in episode_returns(traj, env.spec.discount).items()}
    length = int(stats["length"])
    reset_state, _ = env.reset(jax.random.key(key))
    frames = [f"t=0 (reset)\n{env.render(reset_state)}"]
    rewards, names = np.asarray(traj.reward), env.spec.action_names
    if algo.values is not None:
        chosen_on = decision_timesteps(reset_ts, traj)
        q = values_along(algo, params, chosen_on)
        free, avail = np.asarray(chosen_on.mac_done), np.asarray(chosen_on.avail_actions)
    for t in range(length):
        frame_state = jax.tree_util.tree_map(lambda x, t=t: x[t], states)
        frame = f"after step {t} (reward {rewards[t]:+.1f})\n{env.render(frame_state)}"
        if algo.values is not None:
            frame += "".join(f"\nagent {i} chose at step {t} from {values_line(names[i], q[t, i], avail[t, i])}"
                             for i in range(env.spec.num_agents) if free[t, i])
        frames.append(frame)
    stats["chunks_trained"] = chunks
    return frames, stats


def save_strip(frames: list[str], png_path: str, max_panels: int = 8) -> None:
    """Evenly spaced frames (first and last included) side by side in monospace text."""
    from matplotlib.figure import Figure  # its own Agg canvas: never touches pyplot's backend or figure list

    idx = np.unique(np.linspace(0, len(frames) - 1, min(max_panels, len(frames))).round().astype(int))
    lines = max(f.count("\n") + 1 for f in frames)
    width = max(len(line) for f in frames for line in f.splitlines())
    cols = min(4, len(idx))
    rows = -(-len(idx) // cols)
    fig = Figure(figsize=(0.075 * width * cols + 0.5, 0.16 * lines * rows + 0.5), dpi=110)
    axes = fig.subplots(rows, cols)
    axes = np.atleast_1d(axes).ravel()
    for ax in axes:
        ax.axis("off")
    for ax, i in zip(axes, idx):
        ax.text(0.0, 1.0, frames[i], family="monospace", fontsize=8, va="top", ha="left", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(png_path)


def evaluate_run(out_dir: str, seed_index: int = 0) -> tuple[str, str, dict]:
    """Write ``greedy_seed{i}.txt`` and ``greedy_seed{i}.png`` into the run folder."""
    frames, stats = greedy_episode_frames(out_dir, seed_index)
    txt = os.path.join(out_dir, f"greedy_seed{seed_index}.txt")
    png = os.path.join(out_dir, f"greedy_seed{seed_index}.png")
    with open(txt, "w") as f:
        f.write("\n\n".join(frames) + "\n")
    save_strip(frames, png)
    return txt, png, stats
