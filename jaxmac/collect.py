"""Episode collection with a recurrent policy, for training and evaluation (algorithm-agnostic).

A *policy* is a pair of pure functions supplied by an algorithm:

    init_carry(num_agents) -> carry                       # per-env recurrent state
    act(params, carry, ts, key, epsilon) -> (carry, actions i32[n])

``act`` sees the timestep the agents observe before the step (``ts.mac_done`` says who is
free); it should choose ε-greedily for free agents and may send anything for busy agents,
whose entries the env ignores (DECISIONS D17).

Episodes run for exactly ``horizon`` steps without auto-reset; steps after the first
``terminated``/``truncated`` are masked (the episode writer and ``episode_returns`` do it),
so every env in a batch has the same fixed shapes. The env state is frozen once the episode
is over, so the returned final state is the one at its end.
"""

from __future__ import annotations

from typing import Any, Callable

import chex
import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv, TimeStep
from jaxmac.seeds import any_seed

Act = Callable[[Any, Any, TimeStep, chex.PRNGKey, chex.Array], tuple[Any, chex.Array]]


def run_episode(
    env: MacroEnv, act: Act, init_carry: Callable[[int], Any], params: Any, key: chex.PRNGKey,
    epsilon: chex.Array, record_states: bool = False,
):
    """One episode of ``env.spec.horizon`` steps.

    Returns ``(reset_ts, traj, final_state)``: traj leaves ``[H, ...]``, final_state the env
    state at the episode's end. With ``record_states`` the last element is instead the env
    state after every step (leaves ``[H, ...]``), for rendering.
    """
    key_reset, key_steps = jax.random.split(key)
    state, reset_ts = env.reset(key_reset)

    def body(carry, key):
        state, ts, policy_carry = carry
        k_act, k_step = jax.random.split(key)
        policy_carry, actions = act(params, policy_carry, ts, k_act, epsilon)
        new_state, new_ts = env.step(k_step, state, actions)
        # The env is not absorbing (Box Pushing Q11): keep the final state once done.
        state = jax.tree_util.tree_map(lambda old, new: jnp.where(ts.done, old, new), state, new_state)
        return (state, new_ts, policy_carry), ((new_ts, state) if record_states else new_ts)

    init = (state, reset_ts, init_carry(env.spec.num_agents))
    (final_state, _, _), out = jax.lax.scan(body, init, jax.random.split(key_steps, env.spec.horizon))
    if record_states:
        traj, states = out
        return reset_ts, traj, states
    return reset_ts, out, final_state


def run_episodes(env, act, init_carry, params, key, epsilon, num_episodes: int):
    """``num_episodes`` episodes vmapped over envs: ``(reset_ts, traj, final_state)``, leaves ``[E, ...]``."""
    keys = jax.random.split(key, num_episodes)
    return jax.vmap(lambda k: run_episode(env, act, init_carry, params, k, epsilon))(keys)


def run_episodes_first_finished(env: MacroEnv, act: Act, init_carry: Callable[[int], Any], params: Any,
                                key: chex.PRNGKey, epsilon: chex.Array, num_envs: int, num_episodes: int):
    """The episodes the MacroMARL actor-critic runners collect: the first to *finish* among parallel envs.

    Their runner resets ``num_envs`` envs, steps them in lock-step, restarts an env as soon as its episode ends,
    and stops at the first step where ``num_episodes`` episodes have finished; episodes still running are
    dropped, and of the episodes finished by then it keeps the last ``num_episodes`` (in order of finishing, envs
    in index order within a step: its buffer is a deque of that length). Short episodes are over-represented —
    on Box Pushing those that push a box to the goal. Training batches (``num_episodes = num_envs``) and
    evaluations (10 episodes from ``num_envs`` envs) both come out this way.

    The envs run with auto-reset until ``num_episodes`` have finished (at most ``horizon · ⌈num_episodes / num_envs⌉``
    steps: each finishes an episode at least every ``horizon`` steps); the chosen episodes are cut out of the streams.
    Returns ``(reset_ts, traj)`` shaped as ``run_episodes`` (leaves ``[num_episodes, ...]``, ``[.., H, ...]``).
    """
    if num_episodes < 1 or num_envs < 1:
        raise ValueError(f"first-finished collection needs num_episodes={num_episodes} >= 1 and num_envs={num_envs} >= 1")
    from envs_jax.wrappers import AutoReset

    auto = AutoReset(env)
    horizon = env.spec.horizon
    length = horizon * -(-num_episodes // num_envs)
    reset_keys, stream_keys = jnp.moveaxis(jax.vmap(jax.random.split)(jax.random.split(key, num_envs)), 1, 0)
    step_keys = jax.vmap(lambda k: jax.random.split(k, length))(stream_keys)  # [N, length]: step t of env i
    state, first_ts = jax.vmap(auto.reset)(reset_keys)

    def env_step(state, policy_carry, key):  # one env: the step's timestep and the one acted from next
        k_act, k_step = jax.random.split(key)
        policy_carry, actions = act(params, policy_carry, state.timestep, k_act, epsilon)
        state, ts = auto.step(k_step, state, actions)
        return state, policy_carry, ts, state.timestep

    # the streams stop once every seed has its episodes (the decision is shared by the seeds, see
    # jaxmac.buckets, so that the loop carry is not re-selected per seed at every step); steps not run stay zero
    carry0 = (state, jax.vmap(lambda _: init_carry(env.spec.num_agents))(jnp.arange(num_envs)))
    shapes = jax.eval_shape(jax.vmap(env_step), *carry0, step_keys[:, 0])
    traj0, next0 = (jax.tree_util.tree_map(lambda x: jnp.zeros((num_envs, length) + x.shape[1:], x.dtype), x)
                    for x in shapes[2:])

    def more(loop):
        t, finished = loop[0], loop[1]
        return jnp.logical_and(t < length, any_seed(finished < num_episodes))

    def body(loop):
        t, finished, state, policy_carry, traj, next_ts = loop
        state, policy_carry, ts, ts_next = jax.vmap(env_step)(state, policy_carry, step_keys[:, t])
        write = lambda buf, x: buf.at[:, t].set(x)  # noqa: E731
        traj, next_ts = (jax.tree_util.tree_map(write, b, x) for b, x in ((traj, ts), (next_ts, ts_next)))
        return t + 1, finished + ts.done.sum().astype(jnp.int32), state, policy_carry, traj, next_ts

    zero = jnp.zeros((), jnp.int32)
    *_, traj, next_ts = jax.lax.while_loop(more, body, (zero, zero, *carry0, traj0, next0))
    acted_from = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[:, None], b[:, :-1]], 1), first_ts, next_ts)
    env_index, start = select_first_finished(jnp.logical_or(traj.terminated, traj.truncated), num_episodes)
    # H rows from the start; those after the episode's last step (it has done set) are masked by every consumer
    rows = jnp.minimum(start[:, None] + jnp.arange(horizon)[None, :], length - 1)
    episodes = jax.tree_util.tree_map(lambda x: x[env_index[:, None], rows], traj)
    reset_ts = jax.tree_util.tree_map(lambda x: x[env_index, start], acted_from)
    return reset_ts, episodes


def select_first_finished(done: chex.Array, num_episodes: int) -> tuple[chex.Array, chex.Array]:
    """Which episodes of lock-stepped auto-resetting env streams the MacroMARL actor-critic runner keeps.

    Args:
      done: bool[N, L] env i's episode ends at step t (each env restarts right after).
      num_episodes: how many the runner waits for.
    Returns:
      ``(env_index, start)`` i32[num_episodes] each: the stream and the first step of each kept episode, in
      finishing order. The runner stops after the first step by which ``num_episodes`` episodes have finished
      and keeps the last ``num_episodes`` of them (in order of finishing, envs by index within a step).
    """
    num_envs, length = done.shape
    finished = jnp.cumsum(done.sum(0))  # episodes finished by the end of each step
    stop = jnp.argmax(finished >= num_episodes)  # the runner's last step
    steps = jnp.arange(length)
    order = jnp.logical_and(done, steps[None, :] <= stop).T.reshape(-1)  # step-major, then env
    rank = jnp.cumsum(order) - 1
    keep = jnp.logical_and(order, rank >= finished[stop] - num_episodes)
    flat = jnp.nonzero(keep, size=num_episodes)[0]
    end, env_index = flat // num_envs, flat % num_envs
    # an episode starts after the previous end in its env's stream (or at step 0)
    after_end = jax.lax.cummax(jnp.where(done, steps[None, :] + 1, 0), axis=1)
    start_of = jnp.concatenate([jnp.zeros((num_envs, 1), jnp.int32), after_end[:, :-1].astype(jnp.int32)], axis=1)
    return env_index.astype(jnp.int32), start_of[env_index, end]


def random_policy():
    """``(init_carry, act)`` of the uniform random macro-action policy (no parameters)."""
    from envs_jax.policies import uniform_random_actions

    def act(params, carry, ts, key, epsilon):
        return carry, uniform_random_actions(key, ts.avail_actions)

    return (lambda n: ()), act


def episode_returns(traj: TimeStep, gamma: float) -> dict[str, chex.Array]:
    """Per-episode statistics of fixed-length rollouts (leaves ``[..., H]``).

    Steps after the first done do not count. Returns ``length``, ``return`` (undiscounted),
    ``disc_return`` (Σ_t γ^t r_t, the original experiments' metric) and ``terminated``.
    """
    done = jnp.logical_or(traj.terminated, traj.truncated)
    alive = (jnp.cumsum(done, -1) - done) == 0  # no done strictly before t
    h = done.shape[-1]
    discount = gamma ** jnp.arange(h, dtype=jnp.float32)
    reward = jnp.where(alive, traj.reward, 0.0)
    return {
        "length": alive.sum(-1),
        "return": reward.sum(-1),
        "disc_return": (reward * discount).sum(-1),
        "terminated": jnp.any(traj.terminated & alive, -1),
    }
