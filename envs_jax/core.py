"""The environment API shared by every jaxmac benchmark.

An environment is a plain Python object holding only static configuration; all dynamic
quantities live in an ``EnvState`` pytree. ``reset`` and ``step`` are pure and jittable:

    state, ts = env.reset(key)
    state, ts = env.step(key, state, actions)      # actions: int32[n_agents]

Agents are stacked along the leading axis of every per-agent array (never keyed by
name). Heterogeneous agents (Warehouse) are padded to the per-env maxima
``spec.obs_dim`` / ``spec.max_actions`` and described by ``spec.obs_sizes`` /
``spec.num_actions`` and the ``avail_actions`` mask.

Macro-action bookkeeping common to all domains is done here, once:

* the *effective* action of an agent is the one it sent if it was free (its previous
  macro-action terminated), otherwise its running macro-action: entries of busy agents
  are ignored, exactly as in the original environments;
* ``obs_macro`` is the MacDec-POMDP macro-observation (refreshed only where the agent's
  macro-action just ended), ``obs_real`` the same observation function evaluated every
  primitive step (docs/decisions.md D1);
* ``t_m`` is the progress of the macro-action executed during the step (0 on its first
  primitive step), so a segment ending at ``t`` started at ``t - t_m[t]``;
* ``truncated`` marks the step at which the horizon is reached without termination.

A domain implements the ``_core_*`` hooks below on its own state (``core``).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, Generic, TypeVar

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

Core = TypeVar("Core")


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """Static metadata of an environment (hashable, safe to close over in ``jit``)."""

    name: str
    num_agents: int
    num_actions: tuple[int, ...]  # true action count per agent
    action_names: tuple[tuple[str, ...], ...]  # per agent, length num_actions[i]
    obs_sizes: tuple[int, ...]  # true observation size per agent
    state_dim: int
    horizon: int
    discount: float
    agent_names: tuple[str, ...]

    @property
    def obs_dim(self) -> int:
        """Padded observation width (max over agents)."""
        return max(self.obs_sizes)

    @property
    def max_actions(self) -> int:
        """Padded action count (max over agents)."""
        return max(self.num_actions)


@struct.dataclass
class TimeStep:
    """What one ``reset``/``step`` emits. ``n`` agents, padded sizes ``O``, ``A``, ``S``."""

    obs_macro: chex.Array  # f32[n, O] macro-observation (frozen while a macro-action runs)
    obs_real: chex.Array  # f32[n, O] observation function at the current state
    mac_done: chex.Array  # bool[n] macro-action terminated at this step (all True at reset)
    avail_actions: chex.Array  # bool[n, A] actions an agent may choose next
    mac: chex.Array  # i32[n] macro-action executed during this step (-1 at reset)
    t_m: chex.Array  # i32[n] its progress: 0 on its first primitive step
    state: chex.Array  # f32[S] global state vector
    reward: chex.Array  # f32[] team reward of this step (0 at reset)
    terminated: chex.Array  # bool[] the task is done
    truncated: chex.Array  # bool[] the horizon was reached without termination
    t: chex.Array  # i32[] primitive steps taken in the episode

    @property
    def done(self) -> chex.Array:
        """Episode over (terminated or truncated)."""
        return jnp.logical_or(self.terminated, self.truncated)


@dataclasses.dataclass(frozen=True)
class RewardBounds:
    """What any episode of an env can pay, from its reward weights (not from experience).

    ``step_min``: the lowest team reward of one primitive step; ``episode_max``: the most positive reward one
    episode can collect in total. Together they bound every value: ``value_bounds``."""

    step_min: float
    episode_max: float


def value_bounds(bounds: RewardBounds, discount: float, horizon: int) -> tuple[float, float]:
    """(low, high) bounds on the discounted return from any state of an episode of at most ``horizon`` steps:
    at worst every remaining step pays ``step_min`` (low = min(0, step_min) · Σ_{t<H} γ^t); at best the episode
    still collects all its positive reward undiscounted (high = episode_max). A value estimate outside them is
    wrong whatever the policy."""
    steps = horizon if discount == 1.0 else (1.0 - discount ** horizon) / (1.0 - discount)
    return min(0.0, bounds.step_min) * steps, max(0.0, bounds.episode_max)


@struct.dataclass
class EnvState(Generic[Core]):
    """Full dynamic state: domain core plus the macro-action bookkeeping."""

    core: Any  # domain-specific pytree
    obs_macro: chex.Array  # f32[n, O] observation memory
    mac: chex.Array  # i32[n] current (or last) macro-action, -1 after reset
    mac_done: chex.Array  # bool[n] free: chooses a new macro-action at the next step
    t_m: chex.Array  # i32[n] progress of ``mac`` at the last step
    t: chex.Array  # i32[] primitive steps taken


@struct.dataclass
class CoreStep:
    """What a domain's primitive step returns to the shared bookkeeping."""

    core: Any
    mac: chex.Array  # i32[n] macro-action each agent executed this step
    mac_done: chex.Array  # bool[n] terminated at the end of this step
    reward: chex.Array  # f32[]
    terminated: chex.Array  # bool[]


class MacroEnv(abc.ABC, Generic[Core]):
    """Base class of the macro-action environments (see module docstring)."""

    spec: EnvSpec

    # --- domain hooks -------------------------------------------------------------------
    @abc.abstractmethod
    def _core_reset(self, key: chex.PRNGKey) -> Core:
        """Initial domain state."""

    @abc.abstractmethod
    def _core_step(
        self, key: chex.PRNGKey, core: Core, actions: chex.Array, free: chex.Array, mac: chex.Array
    ) -> CoreStep:
        """One primitive step. ``actions`` are effective actions (busy agents: running one);
        ``free`` (bool[n]) says who started a new macro-action, ``mac`` is the previous one."""

    @abc.abstractmethod
    def _core_obs(self, core: Core) -> chex.Array:
        """Observation function at the current state, f32[n, O] (zero padded)."""

    @abc.abstractmethod
    def _core_global_state(self, core: Core) -> chex.Array:
        """Global state vector, f32[S]."""

    def _core_avail_actions(self, core: Core) -> chex.Array:
        """Available actions, bool[n, A]; default: every true action of every agent."""
        return jnp.asarray(self.action_mask)

    def _core_reset_obs(self, core: Core) -> chex.Array:
        """Observation emitted by ``reset``; domains with a fixed reset observation override."""
        return self._core_obs(core)

    def reward_bounds(self) -> RewardBounds:
        """Bounds on what a step and an episode can pay (``RewardBounds``), from the configured reward weights."""
        raise NotImplementedError(f"{type(self).__name__} declares no reward bounds")

    def render(self, state: EnvState) -> str:
        """Text picture of a (single, unbatched) state."""
        raise NotImplementedError(f"{type(self).__name__} has no text rendering")

    # --- shared API ---------------------------------------------------------------------
    @property
    def num_agents(self) -> int:
        return self.spec.num_agents

    @property
    def action_mask(self) -> np.ndarray:
        """bool[n, A]: True for the true actions of each agent (padding is False)."""
        a = np.arange(self.spec.max_actions)[None, :]
        return a < np.asarray(self.spec.num_actions)[:, None]

    def reset(self, key: chex.PRNGKey) -> tuple[EnvState, TimeStep]:
        core = self._core_reset(key)
        n = self.spec.num_agents
        obs = self._core_reset_obs(core).astype(jnp.float32)
        state = EnvState(
            core=core,
            obs_macro=obs,
            mac=jnp.full((n,), -1, jnp.int32),
            mac_done=jnp.ones((n,), bool),
            t_m=jnp.zeros((n,), jnp.int32),
            t=jnp.zeros((), jnp.int32),
        )
        return state, self._timestep(
            state, self._core_obs(core).astype(jnp.float32), jnp.zeros((), jnp.float32),
            jnp.zeros((), bool),
        )

    def step(self, key: chex.PRNGKey, state: EnvState, actions: chex.Array) -> tuple[EnvState, TimeStep]:
        actions = self.check_actions(actions, state)
        free = state.mac_done
        effective = jnp.where(free, actions, state.mac)
        out = self._core_step(key, state.core, effective, free, state.mac)
        obs_real = self._core_obs(out.core).astype(jnp.float32)
        new_state = EnvState(
            core=out.core,
            obs_macro=jnp.where(out.mac_done[:, None], obs_real, state.obs_macro),
            mac=out.mac.astype(jnp.int32),
            mac_done=out.mac_done,
            t_m=jnp.where(free, 0, state.t_m + 1).astype(jnp.int32),
            t=state.t + 1,
        )
        return new_state, self._timestep(
            new_state, obs_real, out.reward.astype(jnp.float32), out.terminated
        )

    def observe(self, state: EnvState) -> TimeStep:
        """The timestep an agent would see at ``state`` (reward 0, flags recomputed)."""
        return self._timestep(
            state, self._core_obs(state.core).astype(jnp.float32), jnp.zeros((), jnp.float32),
            jnp.zeros((), bool),
        )

    def _timestep(self, state: EnvState, obs_real, reward, terminated) -> TimeStep:
        terminated = jnp.asarray(terminated, bool)
        return TimeStep(
            obs_macro=state.obs_macro,
            obs_real=obs_real,
            mac_done=state.mac_done,
            avail_actions=self._core_avail_actions(state.core),
            mac=state.mac,
            t_m=state.t_m,
            state=self._core_global_state(state.core).astype(jnp.float32),
            reward=reward,
            terminated=terminated,
            truncated=jnp.logical_and(state.t >= self.spec.horizon, ~terminated),
            t=state.t,
        )

    def check_actions(self, actions: chex.Array, state: EnvState | None = None) -> chex.Array:
        """Validate a joint action and return it as int32[n].

        Shape and dtype are checked always (before tracing). Values can only be checked when
        they are concrete (outside ``jit``): every free agent's action must be one of its
        available actions. Busy agents' entries are ignored, so any integer is accepted there.
        """
        n = self.spec.num_agents
        shape = tuple(np.shape(actions))
        if shape != (n,):
            raise ValueError(
                f"{self.spec.name}: actions must have shape ({n},) (one macro-action per agent), got {shape}"
            )
        dtype = jnp.asarray(actions).dtype if not isinstance(actions, jax.core.Tracer) else actions.dtype
        if not jnp.issubdtype(dtype, jnp.integer):
            raise ValueError(f"{self.spec.name}: actions must be integers, got dtype {dtype}")
        if state is not None and not _is_traced(actions, state.mac_done, state.core):
            a = np.asarray(actions)
            free = np.asarray(state.mac_done)
            avail = np.asarray(self._core_avail_actions(state.core))
            for i in np.flatnonzero(free):
                if not (0 <= a[i] < self.spec.num_actions[i]) or not avail[i, a[i]]:
                    valid = [int(k) for k in np.flatnonzero(avail[i])]
                    raise ValueError(
                        f"{self.spec.name}: agent {i} is free and sent action {int(a[i])}, "
                        f"valid choices are {valid} ({', '.join(self.spec.action_names[i][k] for k in valid)})"
                    )
        return jnp.asarray(actions, jnp.int32)


def _is_traced(*trees) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(trees))
