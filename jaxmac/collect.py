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
