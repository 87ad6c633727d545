"""The compiled, algorithm-agnostic training program.

``make_train(config, algorithm)`` returns pure functions

    init(key) -> TrainState
    train_chunk(state) -> (state, metrics)      # ``rounds_per_chunk`` rounds in one lax.scan
    evaluate(params, key, episodes) -> stats    # greedy decentralised episodes

A *round* is: collect ``num_envs`` episodes with the ε-greedy policy (vmapped envs) →
write them into the Mac-SJERT ring → ``updates_per_round`` gradient steps on batches sampled
from it (once it holds a batch) → hard target copy every ``target_update_episodes`` → a
greedy evaluation every ``eval_every_episodes`` (DECISIONS D13, D15). Metrics are reduced
inside the scan, one row per round. ``jax.vmap(train_chunk)`` runs several seeds at once.

An *algorithm* supplies networks, acting and the loss (``Algorithm``); the rollout, ring,
schedule, evaluation and target updates here are shared by all of them.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import chex
import jax
import jax.numpy as jnp
import optax
from flax import struct

from envs_jax.core import MacroEnv
from jaxmac import ring as ring_lib
from jaxmac.collect import Act, episode_returns, run_episodes
from jaxmac.config import TrainConfig
from jaxmac.episode import EpisodeSlot, SlotConfig, write_episode


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """What an algorithm plugs into the trainer.

    init_params(key) -> params
    init_carry(num_agents) -> per-env policy carry (e.g. GRU states, previous actions)
    act(params, carry, ts, key, epsilon) -> (carry, actions i32[n]) — decentralised acting
    loss(params, target_params, batch, key) -> (scalar, metrics dict of scalars);
        ``batch`` is an EpisodeSlot with leaves [B, ...] sampled from the ring.
    """

    name: str
    init_params: Callable[[chex.PRNGKey], Any]
    init_carry: Callable[[int], Any]
    act: Act
    loss: Callable[[Any, Any, EpisodeSlot, chex.PRNGKey], tuple[chex.Array, dict[str, chex.Array]]]


@struct.dataclass
class TrainState:
    params: Any
    target_params: Any
    opt_state: Any
    ring: ring_lib.RingState
    key: chex.PRNGKey
    episodes: chex.Array  # i32[] training episodes collected
    updates: chex.Array  # i32[] gradient steps taken
    rounds: chex.Array  # i32[] rounds done


@dataclasses.dataclass(frozen=True)
class Trainer:
    config: TrainConfig
    env: MacroEnv
    algorithm: Algorithm
    slot_config: SlotConfig
    rounds_per_chunk: int
    total_rounds: int
    init: Callable[[chex.PRNGKey], TrainState]
    train_chunk: Callable[[TrainState], tuple[TrainState, dict[str, chex.Array]]]
    evaluate: Callable[[Any, chex.PRNGKey, int], dict[str, chex.Array]]

    @property
    def total_chunks(self) -> int:
        return math.ceil(self.total_rounds / self.rounds_per_chunk)


def epsilon_schedule(config: TrainConfig, episodes: chex.Array) -> chex.Array:
    """Linear decay from eps_start to eps_end over eps_decay_episodes training episodes."""
    frac = jnp.clip(episodes / max(config.eps_decay_episodes, 1), 0.0, 1.0)
    return config.eps_start + frac * (config.eps_end - config.eps_start)


def make_optimizer(config: TrainConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(config.grad_clip), optax.adam(config.lr))


def make_train(
    config: TrainConfig, env: MacroEnv, algorithm: Algorithm, rounds_per_chunk: int | None = None
) -> Trainer:
    """Build the compiled trainer. ``rounds_per_chunk`` defaults to about one evaluation
    period; metrics and checkpoints happen between chunks."""
    E = config.num_envs
    if E > config.buffer_episodes:
        raise ValueError(f"num_envs={E} must be <= buffer_episodes={config.buffer_episodes}")
    total_rounds = math.ceil(config.episodes / E)
    if rounds_per_chunk is None:
        rounds_per_chunk = max(1, min(total_rounds, math.ceil(max(config.eval_every_episodes, E) / E)))
    if not isinstance(rounds_per_chunk, int) or rounds_per_chunk < 1:
        raise ValueError(f"rounds_per_chunk={rounds_per_chunk!r} must be a positive integer")
    slot_config = SlotConfig.from_spec(env.spec)
    optimizer = make_optimizer(config)
    gamma = env.spec.discount

    def init(key: chex.PRNGKey) -> TrainState:
        key, k_params = jax.random.split(key)
        params = algorithm.init_params(k_params)
        return TrainState(
            params=params,
            target_params=jax.tree_util.tree_map(jnp.copy, params),
            opt_state=optimizer.init(params),
            ring=ring_lib.init(slot_config, config.buffer_episodes),
            key=key,
            episodes=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
            rounds=jnp.zeros((), jnp.int32),
        )

    def evaluate(params, key, episodes: int) -> dict[str, chex.Array]:
        _, traj, _ = run_episodes(env, algorithm.act, algorithm.init_carry, params, key, 0.0, episodes)
        return episode_returns(traj, gamma)

    def gradient_step(carry, key):
        params, target_params, opt_state, ring = carry
        k_sample, k_loss = jax.random.split(key)
        batch, _ = ring_lib.sample(ring, k_sample, config.batch_size)
        (loss, metrics), grads = jax.value_and_grad(algorithm.loss, has_aux=True)(
            params, target_params, batch, k_loss
        )
        updates, opt_state = optimizer.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        metrics = dict(metrics, loss=loss, grad_norm=optax.tree.norm(grads))
        return (params, target_params, opt_state, ring), metrics

    def one_round(state: TrainState, _):
        key, k_collect, k_update, k_eval = jax.random.split(state.key, 4)
        eps = epsilon_schedule(config, state.episodes)
        reset_ts, traj, _ = run_episodes(env, algorithm.act, algorithm.init_carry, state.params, k_collect, eps, E)
        slots = jax.vmap(write_episode, in_axes=(None, 0, 0))(slot_config, reset_ts, traj)
        ring = ring_lib.add(state.ring, slots)
        collected = episode_returns(traj, gamma)

        def do_updates(operand):
            params, opt_state = operand
            carry = (params, state.target_params, opt_state, ring)
            (params, _, opt_state, _), metrics = jax.lax.scan(
                gradient_step, carry, jax.random.split(k_update, config.updates_per_round)
            )
            return params, opt_state, jax.tree_util.tree_map(jnp.mean, metrics)

        def skip_updates(operand):
            params, opt_state = operand
            shapes = jax.eval_shape(do_updates, operand)[2]
            return params, opt_state, jax.tree_util.tree_map(lambda s: jnp.full(s.shape, jnp.nan, s.dtype), shapes)

        ready = ring_lib.can_sample(ring, config.batch_size)
        params, opt_state, loss_metrics = jax.lax.cond(ready, do_updates, skip_updates, (state.params, state.opt_state))
        episodes = state.episodes + E
        copy_target = episodes // config.target_update_episodes > state.episodes // config.target_update_episodes
        target_params = jax.tree_util.tree_map(
            lambda p, t: jnp.where(copy_target, p, t), params, state.target_params
        )
        run_eval = episodes // config.eval_every_episodes > state.episodes // config.eval_every_episodes
        nan = jnp.full((), jnp.nan, jnp.float32)
        eval_stats = jax.lax.cond(
            run_eval,
            lambda: evaluate(params, k_eval, config.eval_episodes),
            lambda: jax.tree_util.tree_map(
                lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(lambda: evaluate(params, k_eval, config.eval_episodes))
            ),
        )
        metrics = {
            "episodes": episodes,
            "epsilon": eps,
            "train_return": collected["return"].mean(),
            "train_disc_return": collected["disc_return"].mean(),
            "train_length": collected["length"].mean(),
            "eval_disc_return": jnp.where(run_eval, eval_stats["disc_return"].mean(), nan),
            "eval_return": jnp.where(run_eval, eval_stats["return"].mean(), nan),
            **loss_metrics,
        }
        new_state = TrainState(
            params=params, target_params=target_params, opt_state=opt_state, ring=ring, key=key,
            episodes=episodes, updates=state.updates + jnp.where(ready, config.updates_per_round, 0),
            rounds=state.rounds + 1,
        )
        return new_state, metrics

    def train_chunk(state: TrainState):
        return jax.lax.scan(one_round, state, None, rounds_per_chunk)

    return Trainer(
        config=config, env=env, algorithm=algorithm, slot_config=slot_config,
        rounds_per_chunk=rounds_per_chunk, total_rounds=total_rounds,
        init=init, train_chunk=train_chunk, evaluate=evaluate,
    )
