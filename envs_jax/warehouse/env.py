"""Warehouse Tool Delivery (MacroMARL "OSD") as a pure-JAX :class:`MacroEnv`.

Behaviour is ``shared/reference/warehouse/SPEC.md``; section numbers below refer to it.
One primitive step (§5) is factored into

    noise = env.sample_noise(key, core)                 # all randomness of the step
    out   = env.transition(core, actions, free, noise)  # deterministic

so a conformance harness can replay recorded draws (:class:`InjectedNoiseEnv`).

Sizes: nT robots, nH humans, n = nT + 1 agents (F last), nW = nH + 2 robot waypoints /
robot actions, nF = 1 + nT + 3 F actions. All internal quantities are integers: robot timers
are kept in hundredths of a step (the reference's ``d - 0.8``), positions as motion-graph
points (``motion.py``) so that everything matches the float64 reference exactly.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax.core import CoreStep, EnvSpec, MacroEnv
from envs_jax.warehouse import variants as V
from envs_jax.warehouse.motion import build_motion_graph, continuous_move


@struct.dataclass
class WarehouseCore:
    """Dynamic state of the domain (the macro-action bookkeeping lives in ``EnvState``)."""

    rb_xy: chex.Array  # f32[nT, 2] robot positions (float32 view of the exact position)
    rb_pt: chex.Array  # i32[nT] motion-graph point (exact mode; unused with motion noise)
    rb_wp: chex.Array  # i32[nT] last waypoint reached (-1 none); kept while travelling (§12.5)
    rb_tau: chex.Array  # i32[nT] robot timer τ in 1/100: >0 travelling, 0 arrived, -100 k waiting k steps
    basket: chex.Array  # i32[nT, 3] tools carried per type
    f_act: chex.Array  # i32[] F's current macro-action (-1 none)
    f_tau: chex.Array  # i32[] F's timer τ_F
    f_failed: chex.Array  # bool[] the running pass is already doomed
    staging: chex.Array  # i32[2] staged tool types, oldest first, -1 padded
    found: chex.Array  # i32[3] successful searches per tool type
    h_phase: chex.Array  # i32[nH] work phase c_h ∈ 0..3
    h_time: chex.Array  # i32[nH] phase timer T_h (<= 0: waiting for its tool)
    h_got: chex.Array  # bool[nH] the tool of the current phase has been handed over
    h_fin: chex.Array  # bool[nH] whole task finished (human frozen)
    served: chex.Array  # bool[nH] has received tool 2
    count_step: chex.Array  # i32[] primitive steps since reset


@struct.dataclass
class Noise:
    """Random draws of one step (zeros when the config has no noise)."""

    move: chex.Array  # f32[nT, 2] motion noise added to a robot's step if it moves
    fetch: chex.Array  # i32[] duration offset η of an F action started this step


class WarehouseEnv(MacroEnv[WarehouseCore]):
    """Warehouse Tool Delivery; build with ``envs_jax.make("warehouse-A")`` … ``"-E"``."""

    def __init__(self, layout: V.Layout, config: V.WarehouseConfig, name: str):
        config.validate(layout, name)
        self.layout, self.config = layout, config
        n_h, n_t = layout.n_humans, layout.n_robots
        self.n_humans, self.n_robots = n_h, n_t
        self.exact_motion = config.move_noise_std == 0.0
        names = V.action_names(layout)
        self.spec = EnvSpec(
            name=name,
            num_agents=n_t + 1,
            num_actions=tuple(len(a) for a in names),
            action_names=names,
            obs_sizes=(V.robot_obs_size(n_h),) * n_t + (V.fetch_obs_size(n_t),),
            state_dim=V.state_size(n_h, n_t),
            horizon=config.horizon,
            discount=1.0,
            agent_names=tuple(f"robot{i}" for i in range(n_t)) + ("fetch",),
        )
        self.graph = build_motion_graph(layout)
        # Constant tables (numpy: closed over as constants by jit).
        self._waypoints = np.array([layout.waypoints(i) for i in range(n_t)], np.float32)  # [nT, nW, 2]
        self._tables = np.array(layout.tables, np.float32)  # [nT, 2]
        self._durations = np.array(config.human_durations, np.int32)  # [nH, 4]
        self._f_dur = np.array(
            [V.WAIT_DURATION] + [V.PASS_DURATION] * n_t + [V.SEARCH_DURATION] * V.N_TOOLS, np.int32
        )
        self.go_tr, self.get_tool = n_h, n_h + 1  # robot action ids
        # The action whose arrival step ends the robot's update early (§5.1, §12.1).
        self._exit_action = self.go_tr if config.arrival_exit_on_go_tr else self.get_tool
        # Passes (F actions 1..this) that are checked when they start (see WarehouseConfig).
        self._checked_passes = n_t if config.check_every_pass else min(n_t, 2)

    # --- reset ------------------------------------------------------------------------
    def _core_reset(self, key: chex.PRNGKey) -> WarehouseCore:
        del key  # the initial state is fixed (§9)
        n_h, n_t = self.n_humans, self.n_robots
        return WarehouseCore(
            rb_xy=jnp.asarray(self.layout.starts, jnp.float32),
            rb_pt=jnp.asarray(self.graph.start),
            rb_wp=jnp.full((n_t,), -1, jnp.int32),
            rb_tau=jnp.zeros((n_t,), jnp.int32),
            basket=jnp.zeros((n_t, V.N_TOOLS), jnp.int32),
            f_act=jnp.full((), -1, jnp.int32),
            f_tau=jnp.zeros((), jnp.int32),
            f_failed=jnp.zeros((), bool),
            staging=jnp.full((V.STAGING_CAPACITY,), -1, jnp.int32),
            found=jnp.zeros((V.N_TOOLS,), jnp.int32),
            h_phase=jnp.zeros((n_h,), jnp.int32),
            h_time=jnp.asarray(self._durations[:, 0]),
            h_got=jnp.zeros((n_h,), bool),
            h_fin=jnp.zeros((n_h,), bool),
            served=jnp.zeros((n_h,), bool),
            count_step=jnp.zeros((), jnp.int32),
        )

    # --- one primitive step -------------------------------------------------------------
    def sample_noise(self, key: chex.PRNGKey, core: WarehouseCore) -> Noise:
        """Draw the step's noise: N(0, σ²) per axis and robot, η uniform on {-1, 0, 1, 2}."""
        del core  # the noise does not depend on the state
        k_move, k_fetch = jax.random.split(key)
        move = jnp.zeros((self.n_robots, 2), jnp.float32)
        if self.config.move_noise_std > 0.0:
            move = self.config.move_noise_std * jax.random.normal(k_move, (self.n_robots, 2), jnp.float32)
        fetch = jnp.zeros((), jnp.int32)
        if self.config.fetch_duration_noise:
            fetch = jax.random.randint(k_fetch, (), -1, 3, jnp.int32)
        return Noise(move=move, fetch=fetch)

    def _core_step(self, key, core, actions, free, mac) -> CoreStep:
        return self.transition(core, actions, free, self.sample_noise(key, core))

    def transition(
        self, core: WarehouseCore, actions: chex.Array, free: chex.Array, noise: Noise
    ) -> CoreStep:
        """Deterministic primitive step (§5) given the effective joint action and the draws.

        ``actions`` i32[n]: effective actions (a busy agent's entry is its running action);
        ``free`` bool[n]: the agent's previous macro-action had terminated (``done`` flags).
        """
        n_t = self.n_robots
        core = core.replace(count_step=core.count_step + 1)
        k_rb, k_f = actions[:n_t], actions[n_t]
        core, rb_done, rb_reward = self._robots_step(core, k_rb, noise.move)
        core, rb_done, f_done, f_reward = self._fetch_step(core, k_rb, rb_done, k_f, free[n_t], noise.fetch)
        core = self._humans_step(core)
        terminated = jnp.all(core.served)
        if self.config.done_at_horizon:
            terminated |= core.count_step == self.config.horizon
        return CoreStep(
            core=core,
            mac=actions,
            mac_done=jnp.concatenate([rb_done, f_done[None]]),
            reward=(V.STEP_REWARD + rb_reward + f_reward).astype(jnp.float32),
            terminated=terminated,
        )

    def _robots_step(self, core: WarehouseCore, k: chex.Array, eps: chex.Array):
        """§5.1 for every robot at once. Returns (core, done bool[nT], reward f32[])."""
        n_h, n_t = self.n_humans, self.n_robots
        rows = jnp.arange(n_t)
        if self.exact_motion:
            d_cents = jnp.asarray(self.graph.dist_cents)[rows, core.rb_pt, k]
            moved_pt = jnp.asarray(self.graph.next)[rows, core.rb_pt, k]
            moved_xy = jnp.asarray(self.graph.xy)[rows, moved_pt]
        else:
            d_cents, moved_xy = continuous_move(core.rb_xy, jnp.asarray(self._waypoints)[rows, k], eps)
            moved_pt = core.rb_pt
        arrive = d_cents <= V.SPEED_CENTS
        travelling = core.rb_tau > 0
        # Arrival step of the "exit" action: stop there, not done, no handover check (§12.1).
        stop = arrive & travelling & (k == self._exit_action)
        tau_arr = jnp.where(travelling, 0, core.rb_tau)
        waiting = tau_arr - 100  # Get-Tool counts one more waiting step
        timeout = waiting <= -100 * V.GET_TOOL_PATIENCE
        is_get_tool = k == self.get_tool
        tau_arr = jnp.where(is_get_tool & ~stop, jnp.where(timeout, -100, waiting), tau_arr)
        done = arrive & ~stop & (~is_get_tool | timeout)
        tau = jnp.where(arrive, tau_arr, d_cents - V.SPEED_CENTS)
        wp = jnp.where(arrive, k, core.rb_wp)
        target_xy = jnp.asarray(self._waypoints)[rows, k]
        xy = jnp.where(arrive[:, None], target_xy, moved_xy)
        pt = jnp.where(arrive, k, moved_pt)

        # Handover to the human at the robot's own work area (robots in index order: the first
        # eligible robot serves, a later one then sees the tool as obtained).
        h = jnp.clip(k, 0, n_h - 1)
        req = jnp.minimum(core.h_phase, 2)[h]  # tool that human wants
        eligible = (
            ~stop
            & (k < n_h)
            & (wp == k)
            & ~core.h_got[h]
            & (jnp.take_along_axis(core.basket, req[:, None], axis=1)[:, 0] > 0)
        )
        earlier_same = (h[None, :] == h[:, None]) & eligible[None, :] & (rows[None, :] < rows[:, None])
        give = eligible & ~earlier_same.any(axis=1)
        late = core.h_time[h] <= 0
        reward = jnp.sum(jnp.where(give, V.HANDOVER_REWARD + jnp.where(late, self.config.delay_penalty, 0.0), 0.0))
        basket = core.basket - (give[:, None] & (jnp.arange(V.N_TOOLS)[None, :] == req[:, None]))
        h_got = core.h_got | (jnp.zeros((n_h,), jnp.int32).at[h].add(give.astype(jnp.int32)) > 0)
        core = core.replace(rb_xy=xy, rb_pt=pt, rb_wp=wp, rb_tau=tau, basket=basket, h_got=h_got)
        return core, done, reward

    def _fetch_step(self, core, k_rb, rb_done, k, free, eta):
        """§5.2: F acts after the robots and may release one of them. Returns
        (core, robot done bool[nT], F done bool[], reward f32[])."""
        n_t = self.n_robots
        tau = core.f_tau - 1
        busy = tau > 0
        start = ~busy & free
        finish = ~busy & ~free
        f_dur = jnp.asarray(self._f_dur)

        # Start k: a pass is doomed at once if its robot is not already waiting at its table.
        j_new = jnp.clip(k - 1, 0, n_t - 1)
        # The reference only checks passes to robots 0 and 1 at their start (see WarehouseConfig).
        starts_pass = start & (k >= 1) & (k <= self._checked_passes)
        not_ready = (core.rb_wp[j_new] != self.get_tool) | (core.rb_tau[j_new] > -100)
        failed = core.f_failed | (starts_pass & not_ready)

        # Finish the running action.
        act = core.f_act
        is_pass = finish & (act >= 1) & (act <= n_t)
        j = jnp.clip(act - 1, 0, n_t - 1)
        success = is_pass & ~failed & (core.rb_tau[j] < 0) & (k_rb[j] == self.get_tool)
        n_staged = jnp.sum(core.staging >= 0)
        give = success & (n_staged > 0)
        robot_j = jnp.arange(n_t) == j
        basket = core.basket + (
            (give & robot_j)[:, None] & (jnp.arange(V.N_TOOLS)[None, :] == core.staging[0])
        )
        popped = jnp.concatenate([core.staging[1:], jnp.full((1,), -1, jnp.int32)])
        staging = jnp.where(give, popped, core.staging)
        rb_done = rb_done | (success & robot_j)
        rb_tau = jnp.where(success & robot_j, 0, core.rb_tau)
        reward = jnp.where(is_pass & ~success, self.config.drop_penalty, 0.0)
        failed = jnp.where(is_pass, False, failed)

        o = jnp.clip(act - 1 - n_t, 0, V.N_TOOLS - 1)
        is_search = finish & (act >= 1 + n_t)
        found_ok = is_search & (n_staged < V.STAGING_CAPACITY) & (core.found[o] < self.config.n_each_obj)
        found = core.found.at[o].add(found_ok.astype(jnp.int32))
        staging = jnp.where(
            found_ok & (jnp.arange(V.STAGING_CAPACITY) == n_staged), o, staging
        )

        tau = jnp.where(start, f_dur[jnp.clip(k, 0, len(self._f_dur) - 1)] - 1 + eta, tau)
        f_act = jnp.where(start, k, act)
        f_done = jnp.where(start, k == 0, free | finish)
        core = core.replace(
            f_act=f_act, f_tau=tau, f_failed=failed, staging=staging, found=found, basket=basket,
            rb_tau=rb_tau,
        )
        return core, rb_done, f_done, reward

    def _humans_step(self, core: WarehouseCore) -> WarehouseCore:
        """§5 items 4–5: served check, then phase timers of the unfinished humans."""
        served = core.served | ((core.h_phase == 2) & core.h_got)
        active = ~core.h_fin
        time = jnp.where(active, core.h_time - 1, core.h_time)
        advance = active & (time <= 0) & core.h_got
        fin = core.h_fin | (advance & (core.h_phase == 3))
        step_up = advance & (core.h_phase < 3)
        phase = core.h_phase + step_up
        next_dur = jnp.take_along_axis(jnp.asarray(self._durations), jnp.minimum(phase, 3)[:, None], 1)[:, 0]
        time = jnp.where(step_up, next_dur, time)
        got = jnp.where(step_up & (phase <= 2), False, core.h_got)
        return core.replace(served=served, h_time=time, h_phase=phase, h_got=got, h_fin=fin)

    # --- observations and state ------------------------------------------------------------
    def _core_obs(self, core: WarehouseCore) -> chex.Array:
        """§7: robots see their location, the human at it, their basket and (near the tool
        room) how many tools are staged; F sees the staged tools and who waits at a table."""
        n_h, n_t = self.n_humans, self.n_robots
        wp = core.rb_wp
        loc = jax.nn.one_hot(jnp.where(wp >= 0, wp, n_h + 2), n_h + 3)
        at_wa = (wp >= 0) & (wp < n_h)
        h = jnp.clip(wp, 0, n_h - 1)
        slot = 4 * h + core.h_phase[h]
        humans = jax.nn.one_hot(jnp.where(at_wa, slot, -1), V.N_PHASES * n_h)
        n_staged = jnp.sum(core.staging >= 0)
        ready = jnp.stack([n_staged == 1, n_staged == 2]).astype(jnp.float32)
        near_f = (wp < 0) | (wp >= n_h)
        robot_obs = jnp.concatenate(
            [loc, humans, core.basket.astype(jnp.float32), near_f[:, None] * ready[None, :]], axis=1
        )
        staged = self._staged_counts(core)
        if self.exact_motion:
            at_table = jnp.asarray(self.graph.at_table)[jnp.arange(n_t), core.rb_pt]
        else:
            at_table = jnp.all(core.rb_xy == jnp.asarray(self._tables), axis=1)
        fetch_obs = jnp.concatenate([staged, at_table.astype(jnp.float32)])
        fetch_obs = jnp.pad(fetch_obs, (0, self.spec.obs_dim - fetch_obs.shape[0]))
        robot_obs = jnp.pad(robot_obs, ((0, 0), (0, self.spec.obs_dim - robot_obs.shape[1])))
        return jnp.concatenate([robot_obs, fetch_obs[None]], axis=0)

    def _staged_counts(self, core: WarehouseCore) -> chex.Array:
        return jnp.sum(jax.nn.one_hot(core.staging, V.N_TOOLS), axis=0)  # -1 -> zero row

    def _core_global_state(self, core: WarehouseCore) -> chex.Array:
        """§8 (the reference's ``get_state`` for A/B/C, its generalisation for D/E)."""
        n_t = self.n_robots
        xy = jnp.concatenate([core.rb_xy, jnp.asarray([self.layout.fetch], jnp.float32)])
        pos = (xy / jnp.asarray([V.STATE_X_SCALE, V.STATE_Y_SCALE], jnp.float32)).ravel()
        passing = (core.f_act >= 1) & (core.f_act <= n_t) & (core.f_tau > 0)
        in_hand = jax.nn.one_hot(jnp.where(passing, core.staging[0], -1), V.N_TOOLS)
        dur = jnp.asarray(self._f_dur)[jnp.clip(core.f_act, 0, len(self._f_dur) - 1)]
        progress = jnp.where(core.f_act >= 0, core.f_tau / dur, 0.0)
        durations = jnp.take_along_axis(jnp.asarray(self._durations), core.h_phase[:, None], 1)[:, 0]
        h_progress = jnp.where(core.h_time >= 0, 1.0 - core.h_time / durations, -1.0)
        humans = jnp.concatenate([jax.nn.one_hot(core.h_phase, V.N_PHASES), h_progress[:, None]], axis=1)
        return jnp.concatenate(
            [
                pos,
                core.basket.astype(jnp.float32).ravel(),
                self._staged_counts(core),
                in_hand,
                progress[None].astype(jnp.float32),
                humans.ravel().astype(jnp.float32),
            ]
        ).astype(jnp.float32)

    def render(self, state) -> str:
        from envs_jax.warehouse.render import render_text

        return render_text(self, state)


class InjectedNoiseEnv(WarehouseEnv):
    """The same env whose ``step`` takes a :class:`Noise` where the key goes.

    ``env.step(noise, state, actions)`` replays a step with given draws (conformance
    harness, noise traces); everything else is inherited unchanged.
    """

    def _core_step(self, key, core, actions, free, mac) -> CoreStep:
        if not isinstance(key, Noise):
            raise TypeError(f"{self.spec.name}: InjectedNoiseEnv.step expects a Noise, got {type(key).__name__}")
        return self.transition(core, actions, free, key)
