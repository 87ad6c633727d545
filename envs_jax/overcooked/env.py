"""Macro-action Overcooked (maps A/B/C, 3 agents, task 6) as a ``MacroEnv`` (SPEC §4).

One ``step`` is one primitive time step:

1. adopt: free agents start the macro-action they sent (done by ``MacroEnv``);
2. controllers turn running macro-actions into primitive actions (pre-physics state, belief maps
   from the previous step);
3. physics;
4. belief update from the post-physics positions;
5. post-step termination checks;
6. observations (``obs_macro`` refreshed only for agents whose macro-action ended, by ``MacroEnv``).

The environment has no randomness: ``key`` arguments are accepted and ignored.
"""

from __future__ import annotations

import dataclasses

import chex
import jax.numpy as jnp

from envs_jax.core import CoreStep, EnvSpec, EnvState, MacroEnv, RewardBounds
from envs_jax.overcooked import controllers, layouts, physics, plan_table, world
from envs_jax.overcooked.world import OvercookedState


@dataclasses.dataclass(frozen=True)
class OvercookedConfig:
    """Overridable settings (``envs_jax.make("overcooked-A", horizon=300, reward_wrong=-10.0)``).

    Defaults are the MacroMARL experiment settings (SPEC header, docs/decisions.md D14)."""

    horizon: int = 200  # primitive steps before truncation (the training loop's env_terminate_step)
    discount: float = 0.99
    reward_step: float = -0.1  # every primitive step, once for the team
    reward_chop: float = 10.0  # a food reaches 3 chops
    reward_correct: float = 200.0  # lettuce-onion-tomato salad delivered (terminates)
    reward_wrong: float = -5.0  # anything else brought to the delivery counter
    obs_radius: int = 2  # Chebyshev view radius (5×5 view); also drives the beliefs

    def __post_init__(self):
        if self.horizon < 1:
            raise ValueError(f"overcooked: horizon={self.horizon!r} must be >= 1")
        if not 0.0 < self.discount <= 1.0:
            raise ValueError(f"overcooked: discount={self.discount!r} must be in (0, 1]")
        if not 1 <= self.obs_radius <= layouts.N - 1:
            raise ValueError(f"overcooked: obs_radius={self.obs_radius!r} must be in [1, {layouts.N - 1}]")


class Overcooked(MacroEnv[OvercookedState]):
    """Macro-action Overcooked on one map; build it with ``envs_jax.make("overcooked-A")``.

    ``fast_planner=False`` plans by running the search for every agent at every step instead of
    the precomputed table (same answers, much slower; for debugging)."""

    def __init__(self, map_name: str, config: OvercookedConfig = OvercookedConfig(), fast_planner: bool = True):
        name = f"overcooked-{map_name}"
        self.layout = layouts.build_layout(map_name)
        self.config = config
        n = layouts.N_AGENTS
        self.spec = EnvSpec(
            name=name,
            num_agents=n,
            num_actions=(self.layout.num_actions,) * n,
            action_names=(self.layout.action_names,) * n,
            obs_sizes=(world.OBS_DIM,) * n,
            state_dim=world.OBS_DIM,
            horizon=config.horizon,
            discount=config.discount,
            agent_names=tuple(f"agent{i + 1}" for i in range(n)),
        )
        if fast_planner:
            self._plan = plan_table.make_planner(plan_table.build_table(map_name), self.layout.floor)
        else:  # the plain search for every agent (reference for tests)
            self._plan = plan_table.make_exact_planner(self.layout.floor)

    # --- MacroEnv hooks -----------------------------------------------------------------------
    def _core_reset(self, key: chex.PRNGKey) -> OvercookedState:
        del key  # deterministic
        return world.initial_state()

    def _core_step(self, key, core: OvercookedState, actions, free, mac) -> CoreStep:
        del key, free, mac  # deterministic; ``actions`` already are the running macro-actions
        radius = self.config.obs_radius
        prim, done, chop_ctr = controllers.controllers(self.layout, core, actions, self._plan, radius)
        nxt, ev = physics.physics(self.layout, core.replace(chop_ctr=chop_ctr), prim)
        nxt = nxt.replace(belief=world.update_beliefs(nxt, radius))
        done = done | controllers.post_step_done(self.layout, nxt, actions)
        return CoreStep(core=nxt, mac=actions, mac_done=done, reward=self.reward(ev), terminated=ev.correct > 0)

    def reward_bounds(self) -> RewardBounds:
        """Each food is chopped through once, the first correct salad ends the episode, and each agent can bring
        at most one thing to the delivery counter per step."""
        cfg, n = self.config, self.spec.num_agents
        step_min = (cfg.reward_step + n * min(0.0, cfg.reward_wrong) + layouts.N_FOODS * min(0.0, cfg.reward_chop)
                    + min(0.0, cfg.reward_correct))
        per_step = max(0.0, cfg.reward_step) + n * max(0.0, cfg.reward_wrong)
        once = layouts.N_FOODS * max(0.0, cfg.reward_chop) + max(0.0, cfg.reward_correct)
        return RewardBounds(step_min, cfg.horizon * per_step + once)

    def reward(self, ev: physics.Events) -> chex.Array:
        """Team reward (f32[]) of one step's events, with the configured weights (SPEC §10)."""
        cfg = self.config
        return (
            jnp.float32(cfg.reward_step)
            + ev.chops.astype(jnp.float32) * cfg.reward_chop
            + ev.wrong.astype(jnp.float32) * cfg.reward_wrong
            + ev.correct.astype(jnp.float32) * cfg.reward_correct
        )

    def _core_obs(self, core: OvercookedState) -> chex.Array:
        return world.observations(core, self.config.obs_radius)

    def _core_global_state(self, core: OvercookedState) -> chex.Array:
        return world.global_state(core)

    # --- extras ---------------------------------------------------------------------------------
    def true_grid(self, state: EnvState) -> chex.Array:
        """int32[7, 7] cell codes of the true map (SPEC §3.1)."""
        return world.true_grid(self.layout, state.core)

    def belief_maps(self, state: EnvState) -> chex.Array:
        """int32[3, 7, 7] each agent's belief map (SPEC §6)."""
        return world.belief_maps(self.layout, state.core).reshape(-1, layouts.N, layouts.N)

    @property
    def render_legend(self) -> tuple[tuple[str, str], ...]:
        """What ``render`` prints, symbol by symbol: (symbol, meaning) pairs."""
        from envs_jax.overcooked.render import RENDER_LEGEND

        return RENDER_LEGEND

    def render(self, state: EnvState) -> str:
        from envs_jax.overcooked.render import render

        return render(self, state)
