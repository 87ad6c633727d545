"""The compiled, algorithm-agnostic training program.

``make_train(config, env, algorithm)`` returns pure functions

    init(key) -> TrainState
    train_chunk(state) -> (state, metrics)      # ``rounds_per_chunk`` rounds in one lax.scan
    evaluate(params, key, episodes) -> stats    # evaluation episodes with ``algorithm.act`` at ε = 0
    evaluate_greedy(params, key, episodes)      # with ``algorithm.greedy_act`` (None when it has none)

A *round* is: collect ``num_envs`` episodes with the behaviour policy (vmapped envs) → write them into
the episode ring → training steps (``updates_per_round`` of them, or one per ``train_every_steps`` env
steps collected) on batches from the algorithm's data source, once the ring holds ``batch_size`` (or
``start_train_episodes``) episodes → target update (Polyak after every step when ``target_polyak`` > 0,
else a hard copy every ``target_update_episodes`` episodes or ``target_update_steps`` env steps) → a greedy
evaluation every ``eval_every_episodes`` (DECISIONS D13, D15). Metrics are reduced inside the scan, one
row per round: the trainer's counters and returns plus every metric the algorithm's update reports.
``Trainer.seeds_chunk`` (``jax.vmap(train_chunk, axis_name=SEED_AXIS)``) runs several seeds at once; with the
axis named, the decisions every seed shares (evaluate this round? train yet? which length bucket?) stay unbatched
and each ``lax.cond`` runs one branch, where a batched predicate would run both.

An *algorithm* (``jaxmac.algos.base.Algorithm``) supplies networks, acting, loss, optimiser, update and
data source; the rollout, ring, schedule, evaluation and target updates here are shared by all of them.
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
from jaxmac.algos.acting import epsilon_schedule
from jaxmac.algos.base import Algorithm, Progress
from jaxmac.buffer import ring as ring_lib
from jaxmac.buffer.episode import SlotConfig, empty_slot, write_episode
from jaxmac.buffer.sources import episode_source
from jaxmac.collect import episode_returns, run_episodes, run_episodes_first_finished
from jaxmac.config import TrainConfig
from jaxmac.seeds import SEED_AXIS, any_seed


@struct.dataclass
class TrainState:
    params: Any
    target_params: Any
    opt_state: Any
    ring: ring_lib.RingState
    key: chex.PRNGKey
    episodes: chex.Array  # i32[] training episodes collected
    env_steps: chex.Array  # i32[] primitive env steps of those episodes
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
    evaluate_greedy: Callable[[Any, chex.PRNGKey, int], dict[str, chex.Array]] | None = None

    @property
    def total_chunks(self) -> int:
        return math.ceil(self.total_rounds / self.rounds_per_chunk)

    def seeds_chunk(self, state: TrainState):
        """``train_chunk`` of several seeds (leaves of ``state`` ``[seeds, ...]``), vmapped over ``SEED_AXIS``."""
        return jax.vmap(self.train_chunk, axis_name=SEED_AXIS)(state)


def default_rounds_per_chunk(config: TrainConfig) -> int:
    """The rounds one compiled chunk runs: about one evaluation period (``eval_every_episodes``), as a divisor of the
    run's rounds (the one nearest that period, at most twice it) so that the last chunk ends exactly at the budget: a
    chunk always runs all its rounds."""
    total_rounds = config.rounds
    target = max(1, min(total_rounds, math.ceil(max(config.eval_every_episodes, config.num_envs) / config.num_envs)))
    divisors = [n for n in range(1, min(2 * target, total_rounds) + 1) if total_rounds % n == 0]
    return min(divisors, key=lambda n: (abs(math.log(n / target)), n))


def make_train(
    config: TrainConfig, env: MacroEnv, algorithm: Algorithm, rounds_per_chunk: int | None = None
) -> Trainer:
    """Build the compiled trainer. ``rounds_per_chunk`` defaults to about one evaluation period, a divisor of the
    run's rounds (``default_rounds_per_chunk``); metrics and checkpoints happen between chunks."""
    E = config.num_envs
    if E > config.buffer_episodes:
        raise ValueError(f"num_envs={E} must be <= buffer_episodes={config.buffer_episodes}")
    total_rounds = config.rounds
    if rounds_per_chunk is None:
        rounds_per_chunk = default_rounds_per_chunk(config)
    if not isinstance(rounds_per_chunk, int) or rounds_per_chunk < 1:
        raise ValueError(f"rounds_per_chunk={rounds_per_chunk!r} must be a positive integer")
    slot_config = SlotConfig.from_spec(env.spec)
    optimizer = algorithm.optimizer
    sample = algorithm.sample or episode_source(config.batch_size)
    store = algorithm.store
    behaviour = algorithm.behaviour_act or (lambda p, c, ts, k, eps, episodes: algorithm.act(p, c, ts, k, eps))
    gamma = env.spec.discount
    # the ring must hold a batch of episodes, or start_train episodes where the data source sets that
    min_episodes = config.start_train_episodes or config.batch_size
    if min_episodes > config.buffer_episodes:
        raise ValueError(f"training starts when the ring holds {min_episodes} episodes (start_train_episodes="
                         f"{config.start_train_episodes}, or batch_size={config.batch_size} when that is 0), more than "
                         f"buffer_episodes={config.buffer_episodes}")
    polyak = config.target_polyak

    def init(key: chex.PRNGKey) -> TrainState:
        key, k_params = jax.random.split(key)
        params = algorithm.init_params(k_params)
        zero = jnp.zeros((), jnp.int32)
        return TrainState(
            params=params,
            target_params=jax.tree_util.tree_map(jnp.copy, params),
            opt_state=optimizer.init(params),
            ring=ring_lib.init(store(empty_slot(slot_config)) if store else slot_config, config.buffer_episodes),
            key=key, episodes=zero, env_steps=zero, updates=zero, rounds=zero,
        )

    def episodes_of(act, params, key, epsilon, count: int):
        """``count`` episodes of ``act``: ``(reset_ts, traj)`` as ``config.collection`` selects them."""
        if config.collection == "first_finished":
            return run_episodes_first_finished(env, act, algorithm.init_carry, params, key, epsilon, E, count)
        reset_ts, traj, _ = run_episodes(env, act, algorithm.init_carry, params, key, epsilon, count)
        return reset_ts, traj

    def evaluate_with(act):
        def evaluate(params, key, episodes: int) -> dict[str, chex.Array]:
            _, traj = episodes_of(act, params, key, 0.0, episodes)
            return episode_returns(traj, gamma)

        return evaluate

    evaluate = evaluate_with(algorithm.act)
    evaluate_greedy = evaluate_with(algorithm.greedy_act) if algorithm.greedy_act else None

    def periodic_evaluation(run_eval, params, key) -> dict[str, chex.Array]:
        """Mean evaluation returns when ``run_eval``, NaN otherwise (one row per round)."""
        runs = {"eval": evaluate}
        if evaluate_greedy and config.eval_greedy:
            runs["eval_greedy"] = evaluate_greedy
        out = {}
        for name, fn in runs.items():
            stats = jax.lax.cond(
                run_eval,
                lambda fn=fn: fn(params, key, config.eval_episodes),
                lambda fn=fn: jax.tree_util.tree_map(
                    lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(lambda: fn(params, key, config.eval_episodes))),
            )
            nan = jnp.full((), jnp.nan, jnp.float32)
            out[f"{name}_disc_return"] = jnp.where(run_eval, stats["disc_return"].mean(), nan)
            out[f"{name}_return"] = jnp.where(run_eval, stats["return"].mean(), nan)
        return out

    def gradient_step(carry, key):
        params, target_params, opt_state, ring, fresh, progress = carry
        k_sample, k_loss = jax.random.split(key)
        batch = sample(ring, fresh, k_sample)
        params, opt_state, metrics = algorithm.update(params, target_params, opt_state, batch, k_loss, progress)
        if polyak:  # Polyak averaging after every step (hard copies happen per round below)
            target_params = optax.incremental_update(params, target_params, polyak)
        progress = progress.replace(updates=progress.updates + 1)
        return (params, target_params, opt_state, ring, fresh, progress), metrics

    def one_round(state: TrainState, _):
        key, k_collect, k_update, k_eval = jax.random.split(state.key, 4)
        eps = epsilon_schedule(config, state.episodes)
        act = lambda p, c, ts, k, e: behaviour(p, c, ts, k, e, state.episodes)  # noqa: E731
        reset_ts, traj = episodes_of(act, state.params, k_collect, eps, E)
        slots = jax.vmap(write_episode, in_axes=(None, 0, 0))(slot_config, reset_ts, traj)
        ring = ring_lib.add(state.ring, jax.vmap(store)(slots) if store else slots)
        collected = episode_returns(traj, gamma)
        episodes = state.episodes + E
        env_steps = state.env_steps + collected["length"].sum().astype(jnp.int32)
        progress = Progress(episodes=state.episodes, env_steps=state.env_steps, updates=state.updates)
        carry = (state.params, state.target_params, state.opt_state, ring, slots, progress)
        if config.train_every_steps:  # one step per train_every_steps env steps: a count that varies per round
            every = config.train_every_steps
            n_updates = env_steps // every - state.env_steps // every
        else:
            n_updates = jnp.asarray(config.updates_per_round, jnp.int32)

        def fixed_updates(carry):
            carry, metrics = jax.lax.scan(gradient_step, carry, jax.random.split(k_update, config.updates_per_round))
            return carry, jax.tree_util.tree_map(jnp.mean, metrics)

        def counted_updates(carry, count):
            shapes = jax.eval_shape(lambda c: gradient_step(c, k_update)[1], carry)
            zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

            def body(i, loop):
                carry, sums = loop
                carry, metrics = gradient_step(carry, jax.random.fold_in(k_update, i))
                return carry, jax.tree_util.tree_map(jnp.add, sums, metrics)

            carry, sums = jax.lax.fori_loop(0, count, body, (carry, zeros))
            nan = jnp.full((), jnp.nan)
            return carry, jax.tree_util.tree_map(
                lambda x: jnp.where(count > 0, x / jnp.maximum(count, 1).astype(x.dtype), nan.astype(x.dtype)), sums)

        def skip_updates(carry):
            shapes = jax.eval_shape(fixed_updates, carry)[1]
            return carry, jax.tree_util.tree_map(lambda s: jnp.full(s.shape, jnp.nan, s.dtype), shapes)

        ready = jnp.logical_and(ring.count >= min_episodes, n_updates > 0)
        if config.train_every_steps:
            # a loop of zero iterations before training starts, not a cond: the update count differs per seed,
            # and under vmap a cond with a batched predicate would run the gradient steps of not-ready seeds too
            carry, loss_metrics = counted_updates(carry, jnp.where(ready, n_updates, 0))
        else:
            ready = any_seed(ready)  # the same for every seed (all collect E episodes a round): unbatched
            carry, loss_metrics = jax.lax.cond(ready, fixed_updates, skip_updates, carry)
        params, target_params, opt_state = carry[:3]
        if not polyak:
            if config.target_update_steps:
                period, before, after = config.target_update_steps, state.env_steps, env_steps
            else:
                period, before, after = config.target_update_episodes, state.episodes, episodes
            copy_target = after // period > before // period if period else True  # 0: after every round
            target_params = jax.tree_util.tree_map(lambda p, t: jnp.where(copy_target, p, t), params, target_params)
        run_eval = episodes // config.eval_every_episodes > state.episodes // config.eval_every_episodes
        run_eval = any_seed(run_eval)  # the same for every seed: unbatched
        updates = state.updates + jnp.where(ready, n_updates, 0)
        metrics = {
            "episodes": episodes,
            "env_steps": env_steps,
            "updates": updates,
            "round_updates": jnp.where(ready, n_updates, 0),
            "epsilon": eps,
            "train_return": collected["return"].mean(),
            "train_disc_return": collected["disc_return"].mean(),
            "train_length": collected["length"].mean(),
            **periodic_evaluation(run_eval, params, k_eval),
            "param_norm": optax.tree.norm(params),
            **loss_metrics,
        }
        new_state = TrainState(
            params=params, target_params=target_params, opt_state=opt_state, ring=ring, key=key,
            episodes=episodes, env_steps=env_steps, updates=updates, rounds=state.rounds + 1,
        )
        return new_state, metrics

    def train_chunk(state: TrainState):
        return jax.lax.scan(one_round, state, None, rounds_per_chunk)

    return Trainer(
        config=config, env=env, algorithm=algorithm, slot_config=slot_config,
        rounds_per_chunk=rounds_per_chunk, total_rounds=total_rounds,
        init=init, train_chunk=train_chunk, evaluate=evaluate, evaluate_greedy=evaluate_greedy,
    )
