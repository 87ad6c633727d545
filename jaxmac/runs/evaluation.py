"""Greedy decentralised episodes of a trained run: their returns, and the first one rendered as text, drawn as a
grid of frames (PNG) and, optionally, animated (GIF)."""

from __future__ import annotations

import dataclasses
import os
from typing import Any

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


@dataclasses.dataclass
class GreedyEpisodes:
    """``episodes`` greedy episodes of one seed of a trained run: episode ``e`` starts from key
    ``jax.random.key(key + e)`` (as ``jaxmac.collect.run_episode`` takes it). ``stats``: per episode (numpy
    ``[episodes]``) ``length``, ``return`` (undiscounted), ``disc_return`` (Σ_t γ^t r_t) and ``terminated``; episode
    0's trajectory is kept for its pictures (``reset_ts``, ``traj`` and ``states``, the env state after every step,
    leaves ``[H, ...]``)."""

    env: Any
    algo: Any
    params: Any
    keys: np.ndarray  # int[episodes]: the seed of each episode's jax.random.key
    stats: dict[str, np.ndarray]
    reset_state: Any
    reset_ts: Any
    traj: Any
    states: Any
    chunks_trained: int
    _frames: list | None = dataclasses.field(default=None, repr=False)

    @property
    def length(self) -> int:
        """Primitive steps of episode 0."""
        return int(self.stats["length"][0])

    def frame_states(self) -> list:
        """Episode 0's states: the reset state, then the state after every step until it ends (length + 1)."""
        if self._frames is None:
            states = jax.device_get(self.states)
            after = [jax.tree_util.tree_map(lambda x, t=t: x[t], states) for t in range(self.length)]
            self._frames = [jax.device_get(self.reset_state)] + after
        return self._frames

    def frame_titles(self) -> list[str]:
        """``reset (t=0)``, then ``after step t: r ±x (Σ ±y)`` (the step's team reward and the undiscounted sum)."""
        rewards = np.asarray(self.traj.reward, np.float64)[: self.length]
        total = np.cumsum(rewards)
        return ["reset (t=0)"] + [f"after step {t}: r {rewards[t]:+.1f} (Σ {total[t]:+.1f})"
                                  for t in range(self.length)]

    def summary(self) -> str:
        """One line on episode 0: env, steps, returns."""
        s, gamma = self.stats, self.env.spec.discount
        end = "task done" if s["terminated"][0] else "time limit"
        return (f"{self.env.spec.name}, greedy episode 0 (key {int(self.keys[0])}): {self.length} steps ({end}), "
                f"return {float(s['disc_return'][0]):.2f} discounted (γ={gamma}), {float(s['return'][0]):.2f} "
                f"undiscounted")

    def frame_captions(self) -> list[str]:
        """Each agent's macro-action in each frame (``*``: done, the agent chooses again at the next step)."""
        from jaxmac.drawing import agent_labels

        labels, names = agent_labels(self.env), self.env.spec.action_names
        captions = []
        for state in self.frame_states():
            mac, done = np.asarray(state.mac), np.asarray(state.mac_done)
            parts = [f"{labels[i]}: {names[i][int(mac[i])] if mac[i] >= 0 else '-'}{'*' if done[i] else ''}"
                     for i in range(len(mac))]
            captions.append("  ".join(parts))
        return captions


CAPTION_NOTE = "under each frame: every agent's macro-action (* = done: the agent chooses again next step)"


def greedy_policy(algo):
    """The policy ``jaxmac eval`` plays: an actor-critic's ``greedy_act`` (the argmax of its actor), else the
    learner's ``act`` at ε = 0 (the value learners' greedy policy) — as ``jaxmac.api.Policy(greedy=True)``."""
    return algo.greedy_act or algo.act


def episode_keys(key: int, episodes: int) -> jax.Array:
    """The PRNG keys of ``episodes`` episodes: ``jax.random.key(key + e)`` for episode ``e``."""
    return jax.vmap(jax.random.key)(key + jnp.arange(episodes))


def play_greedy(out_dir: str, seed_index: int = 0, episodes: int = 1, key: int = 0) -> GreedyEpisodes:
    """``episodes`` greedy episodes of the given seed's newest checkpoint, vmapped in one jitted program."""
    from jaxmac.runs.loop import load_run

    if episodes < 1:
        raise ValueError(f"episodes={episodes}: give at least 1")
    trainer, state, chunks, meta = load_run(out_dir)
    if chunks == 0:
        raise ValueError(f"{out_dir} has no checkpoint (none saved yet, or none that restores): there is no trained "
                         f"policy to show; train it further first (jaxmac train --resume {out_dir})")
    if not 0 <= seed_index < meta["seeds"]:
        raise ValueError(f"seed_index={seed_index} is out of range; the run has seeds 0..{meta['seeds'] - 1}")
    env, algo = trainer.env, trainer.algorithm
    params = jax.tree_util.tree_map(lambda x: x[seed_index], state.params)
    act = greedy_policy(algo)

    @jax.jit
    def play(params, keys):
        reset_ts, traj, states = jax.vmap(
            lambda k: run_episode(env, act, algo.init_carry, params, k, 0.0, record_states=True))(keys)
        return reset_ts, traj, states, episode_returns(traj, env.spec.discount)

    reset_ts, traj, states, stats = play(params, episode_keys(key, episodes))

    def first(tree):
        return jax.tree_util.tree_map(lambda x: x[0], tree)

    reset_state, _ = env.reset(jax.random.split(jax.random.key(key))[0])  # run_episode's reset of episode 0
    return GreedyEpisodes(env=env, algo=algo, params=params, keys=np.arange(key, key + episodes),
                          stats={k: np.asarray(v) for k, v in stats.items()}, reset_state=reset_state,
                          reset_ts=first(reset_ts), traj=first(traj), states=first(states), chunks_trained=chunks)


def text_frames(play: GreedyEpisodes) -> list[str]:
    """Episode 0 as text (``env.render``): reset and every step until the episode ends. For learners with per-agent
    utilities (``Algorithm.values``), each frame after a choice lists every free agent's best available
    macro-actions with their Q_i — what the greedy choice was made from."""
    env, algo = play.env, play.algo
    frames = [f"t=0 (reset)\n{env.render(play.reset_state)}"]
    rewards, names = np.asarray(play.traj.reward), env.spec.action_names
    if algo.values is not None:
        chosen_on = decision_timesteps(play.reset_ts, play.traj)
        q = values_along(algo, play.params, chosen_on)
        free, avail = np.asarray(chosen_on.mac_done), np.asarray(chosen_on.avail_actions)
    for t, frame_state in enumerate(play.frame_states()[1:]):
        frame = f"after step {t} (reward {rewards[t]:+.1f})\n{env.render(frame_state)}"
        if algo.values is not None:
            frame += "".join(f"\nagent {i} chose at step {t} from {values_line(names[i], q[t, i], avail[t, i])}"
                             for i in range(env.spec.num_agents) if free[t, i])
        frames.append(frame)
    return frames


def greedy_episode_frames(out_dir: str, seed_index: int = 0, key: int = 0) -> tuple[list[str], dict]:
    """Text frames (reset and every step until the episode ends) of one greedy episode of the given seed's newest
    checkpoint (``text_frames``), and that episode's returns."""
    play = play_greedy(out_dir, seed_index, 1, key)
    stats = {k: float(v[0]) for k, v in play.stats.items()}
    stats["chunks_trained"] = play.chunks_trained
    return text_frames(play), stats


def panel_indices(frames: int, max_panels: int = 12) -> np.ndarray:
    """Evenly spaced frame indices, first and last included, at most ``max_panels``."""
    return np.unique(np.linspace(0, frames - 1, min(max_panels, frames)).round().astype(int))


def save_frames_png(play: GreedyEpisodes, png_path: str, max_panels: int = 12) -> tuple[int, int]:
    """Episode 0 drawn (``jaxmac.drawing``): evenly spaced frames, first and last included, at most
    ``max_panels``, four to a row, each titled with its step and reward. Returns the PNG's size in pixels."""
    from jaxmac.drawing import frames_figure

    states, titles, captions = play.frame_states(), play.frame_titles(), play.frame_captions()
    idx = panel_indices(len(states), max_panels)
    fig = frames_figure(play.env, [states[i] for i in idx], [titles[i] for i in idx], [captions[i] for i in idx],
                        title=f"{play.summary()}\n{len(idx)} of its {len(states)} frames, evenly spaced; {CAPTION_NOTE}")
    fig.savefig(png_path)
    width, height = fig.canvas.get_width_height(physical=True)
    return int(width), int(height)


def save_gif(play: GreedyEpisodes, gif_path: str, fps: float = 2.0) -> int:
    """Episode 0 as a GIF, one frame per state (reset, then every step): returns the number of frames."""
    from jaxmac.drawing import write_gif

    return write_gif(play.env, play.frame_states(), play.frame_titles(), gif_path, play.frame_captions(), fps=fps,
                     note=f"{play.summary()}\n{CAPTION_NOTE}")


def save_strip(frames: list[str], png_path: str, max_panels: int = 8) -> None:
    """Evenly spaced text frames (first and last included) side by side in monospace text (``jaxmac eval`` now
    draws its PNG with ``save_frames_png``)."""
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


def evaluate_run(out_dir: str, seed_index: int = 0, episodes: int = 1, gif: bool = False,
                 key: int = 0) -> tuple[str, str, dict]:
    """Play ``episodes`` greedy episodes (``play_greedy``) and write episode 0 into the run folder as
    ``greedy_seed{i}.txt`` (text frames), ``greedy_seed{i}.png`` (a grid of drawn frames) and, with ``gif``,
    ``greedy_seed{i}.gif``. Returns ``(txt, png, stats)``: ``stats`` holds episode 0's ``length``, ``return``,
    ``disc_return``, ``terminated`` and ``chunks_trained`` (as before) and, for all episodes, ``episodes`` (lists per
    statistic), ``keys``, ``discount``, ``png_size`` (pixels), ``gif`` (its path or None) and ``gif_frames``."""
    play = play_greedy(out_dir, seed_index, episodes, key)
    txt = os.path.join(out_dir, f"greedy_seed{seed_index}.txt")
    png = os.path.join(out_dir, f"greedy_seed{seed_index}.png")
    with open(txt, "w") as f:
        f.write("\n\n".join(text_frames(play)) + "\n")
    png_size = save_frames_png(play, png)
    gif_path = os.path.join(out_dir, f"greedy_seed{seed_index}.gif") if gif else None
    gif_frames = save_gif(play, gif_path) if gif else 0
    stats: dict[str, Any] = {k: float(v[0]) for k, v in play.stats.items()}
    stats.update(chunks_trained=play.chunks_trained, discount=float(play.env.spec.discount),
                 episodes={k: v.tolist() for k, v in play.stats.items()}, keys=play.keys.tolist(),
                 png_size=png_size, gif=gif_path, gif_frames=gif_frames)
    return txt, png, stats
