"""Wrappers for rollouts inside ``lax.scan``."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.core import EnvState, MacroEnv, TimeStep


@struct.dataclass
class AutoResetState:
    """State of an auto-resetting env.

    ``env_state`` / ``timestep`` are what the policy acts from: after an episode ends they
    already belong to the fresh episode (its reset), while ``step`` returns the true final
    timestep of the finished one.
    """

    env_state: EnvState
    timestep: TimeStep


class AutoReset:
    """Resets the wrapped env as soon as an episode terminates or is truncated.

    ``step`` returns ``(state, timestep)`` where ``timestep`` is the real outcome of the
    step (reward, ``terminated``/``truncated`` and observations of the final state when the
    episode ended) and ``state.timestep`` is the timestep to act from next.
    """

    def __init__(self, env: MacroEnv):
        self.env = env
        self.spec = env.spec

    def reset(self, key: chex.PRNGKey) -> tuple[AutoResetState, TimeStep]:
        env_state, ts = self.env.reset(key)
        return AutoResetState(env_state, ts), ts

    def step(
        self, key: chex.PRNGKey, state: AutoResetState, actions: chex.Array
    ) -> tuple[AutoResetState, TimeStep]:
        key_step, key_reset = jax.random.split(key)
        env_state, ts = self.env.step(key_step, state.env_state, actions)
        reset_state, reset_ts = self.env.reset(key_reset)
        done = ts.done
        pick = lambda fresh, cont: jnp.where(done, fresh, cont)  # noqa: E731
        next_state = AutoResetState(
            env_state=jax.tree_util.tree_map(pick, reset_state, env_state),
            timestep=jax.tree_util.tree_map(pick, reset_ts, ts),
        )
        return next_state, ts
