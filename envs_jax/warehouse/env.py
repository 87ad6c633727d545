"""Warehouse Tool Delivery (MacroMARL "OSD") as a pure-JAX :class:`MacroEnv`.

Behaviour is ``docs/envs/warehouse.md``; section numbers below refer to it.
One primitive step (§5) is factored into

    noise = env.sample_noise(key, core)                 # all randomness of the step
    out   = env.transition(core, actions, free, noise)  # deterministic

so a conformance harness can replay recorded draws (:class:`InjectedNoiseEnv`).

Sizes: nT robots, nH humans, n = nT + 1 agents (F last), nW = nH + 2 robot waypoints /
robot actions, nF = 1 + nT + 3 F actions. The dynamics are integer arithmetic: robot timers
are kept in hundredths of a step (the reference's ``d - 0.8``) and, without motion noise,
positions as motion-graph points (``motion.py``); the ratios of the state vector come from
tables rounded once from float64. Everything thus matches the float64 reference exactly
(the state vector is its float32 rounding), under ``jit``, ``vmap`` or op by op.

Performance note: per-agent arrays are tiny ([nT] <= 3), so under ``vmap`` they become
[batch, nT] arrays whose minor dimension is too short to vectorise on CPU. The robots are
therefore updated by an unrolled ``lax.scan`` over robots working on scalars (the
reference's sequential order anyway), and small-axis indexing uses select chains.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax.core import CoreStep, EnvSpec, MacroEnv, RewardBounds
from envs_jax.warehouse import variants as V
from envs_jax.warehouse.motion import build_motion_graph, continuous_move


# Indexing a small axis by a traced index is written as a chain of selects: under vmap,
# XLA turns x[i] into a gather (or a one-hot product into a reduction), which on CPU cost
# several times more than selects that fuse with their neighbours.
def _onehot(i: chex.Array, n: int) -> chex.Array:
    """bool[..., n]: ``i[..., None] == arange(n)`` (all False for out-of-range i)."""
    return i[..., None] == jnp.arange(n)


def _pick(x: chex.Array, i: chex.Array) -> chex.Array:
    """``x[..., i]`` for a small static last axis (``x[..., 0]`` where i is out of range)."""
    n = x.shape[-1]
    return jnp.select([i == j for j in range(1, n)], [x[..., j] for j in range(1, n)], x[..., 0])


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
            discount=config.discount,
            agent_names=tuple(f"robot{i}" for i in range(n_t)) + ("fetch",),
        )
        self.graph = g = build_motion_graph(layout)
        # One row per (robot, point, target): next point, its x and y (float32 bits) and the
        # distance in 1/100, so that exact motion is a single gather per robot and step.
        next_xy = g.xy[np.arange(n_t)[:, None, None], g.next].view(np.int32)  # [nT, P, nW, 2]
        self._motion_rows = np.concatenate(
            [g.next[..., None], next_xy, g.dist_cents[..., None]], axis=-1
        ).reshape(-1, 4)
        # Constant tables (numpy: closed over as constants by jit).
        self._waypoints = np.array([layout.waypoints(i) for i in range(n_t)], np.float32)  # [nT, nW, 2]
        self._tables = np.array(layout.tables, np.float32)  # [nT, 2]
        self._durations = np.array(config.human_durations, np.int32)  # [nH, 4]
        # State-vector entries that are ratios, tabulated from float64 and rounded once, so the
        # float32 state is exactly the rounded reference value (and identical under jit, vmap
        # or op-by-op execution, where XLA may otherwise rewrite a division).
        scale = np.array([V.STATE_X_SCALE, V.STATE_Y_SCALE])
        self._state_xy = (g.xy64 / scale).astype(np.float32)  # [nT, P, 2]
        self._fetch_state_xy = (np.array(layout.fetch) / scale).astype(np.float32)
        t = np.arange(self._durations.max() + 1)
        self._h_progress = (1.0 - t / self._durations[..., None]).astype(np.float32)  # [nH, 4, T]: T_h = t
        self._f_tau_min = -1  # F's timer after a step lies in [-1, longest duration + 1]
        tau = np.arange(self._f_tau_min, V.SEARCH_DURATION + 2)
        durs = np.array([V.WAIT_DURATION, V.PASS_DURATION, V.SEARCH_DURATION])
        self._f_progress = (tau / durs[:, None]).astype(np.float32)  # [Wait/Pass/Search, tau]
        self.go_tr, self.get_tool = n_h, n_h + 1  # robot action ids
        # The action whose arrival step ends the robot's update early (§5.1, §12.1).
        self._exit_action = self.go_tr if config.arrival_exit_on_go_tr else self.get_tool
        # Passes (F actions 1..this) that are checked when they start (see WarehouseConfig).
        self._checked_passes = n_t if config.check_every_pass else min(n_t, 2)
        # One persistent scan body (no closure): JAX caches its trace by identity, so that eager,
        # op-by-op stepping does not recompile the robot scan on every step.
        self._robot_update_fn = self._robot_update

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

    def reward_bounds(self) -> RewardBounds:
        """Every handed-over tool was found by a search first (at most ``n_each_obj`` per tool type) and each human
        takes at most one per work phase; per step, each robot hands over at most once and F fails at most one
        pass."""
        cfg = self.config
        handover = V.HANDOVER_REWARD + np.array([0.0, cfg.delay_penalty])  # on time, late
        handovers = min(self.n_humans * V.N_PHASES, V.N_TOOLS * cfg.n_each_obj)
        step_min = V.STEP_REWARD + min(0.0, cfg.drop_penalty) + self.n_robots * min(0.0, float(handover.min()))
        step_max = max(0.0, V.STEP_REWARD) + max(0.0, cfg.drop_penalty)
        return RewardBounds(step_min, cfg.horizon * step_max + handovers * max(0.0, float(handover.max())))

    def _robots_step(self, core: WarehouseCore, k: chex.Array, eps: chex.Array):
        """§5.1 for the robots in index order (a later robot sees the tool an earlier one
        handed over). Returns (core, done bool[nT], reward f32[]).

        The scan is unrolled and its body works on one robot's scalars, so that under
        ``vmap`` every operand is a [batch] vector (fast on CPU) rather than [batch, nT]."""
        rows = (jnp.arange(self.n_robots), k, core.rb_xy, core.rb_pt, core.rb_wp, core.rb_tau, core.basket, eps)
        carry = (core.h_phase, core.h_time, core.h_got, jnp.zeros((), jnp.float32))
        (_, _, h_got, reward), (xy, pt, wp, tau, basket, done) = jax.lax.scan(
            self._robot_update_fn, carry, rows, unroll=True
        )
        core = core.replace(rb_xy=xy, rb_pt=pt, rb_wp=wp, rb_tau=tau, basket=basket, h_got=h_got)
        return core, done, reward

    def _robot_update(self, carry, robot):
        """One robot's move (§2.1), timer/termination (§5.1) and handover check."""
        h_phase, h_time, h_got, reward = carry  # humans do not change before §5.3
        i, k, xy, pt, wp, tau, basket, eps = robot
        n_h = self.n_humans
        target_xy = jnp.asarray(self._waypoints)[i, k]
        if self.exact_motion:
            n_p = self.graph.xy.shape[1]
            row = jnp.asarray(self._motion_rows)[(i * n_p + pt) * (n_h + 2) + k]  # [4]
            moved_pt, d_cents = row[0], row[3]
            moved_xy = jax.lax.bitcast_convert_type(row[1:3], jnp.float32)
        else:
            d_cents, moved_xy = continuous_move(xy, target_xy, eps)
            moved_pt = pt
        arrive = d_cents <= V.SPEED_CENTS
        travelling = tau > 0
        # Arrival step of the "exit" action: stop there, not done, no handover check (§12.1).
        stop = arrive & travelling & (k == self._exit_action)
        tau_arr = jnp.where(travelling, 0, tau)
        waiting = tau_arr - 100  # Get-Tool counts one more waiting step
        timeout = waiting <= -100 * V.GET_TOOL_PATIENCE
        is_get_tool = k == self.get_tool
        tau_arr = jnp.where(is_get_tool & ~stop, jnp.where(timeout, -100, waiting), tau_arr)
        done = arrive & ~stop & (~is_get_tool | timeout)
        tau = jnp.where(arrive, tau_arr, d_cents - V.SPEED_CENTS)
        wp = jnp.where(arrive, k, wp)
        xy = jnp.where(arrive, target_xy, moved_xy)
        pt = jnp.where(arrive, k, moved_pt)

        # Handover to the human at the robot's own work area, if it wants a tool we carry.
        req = _pick(jnp.minimum(h_phase, 2), k)  # the tool that human wants
        give = ~stop & (k < n_h) & (wp == k) & ~_pick(h_got, k) & (_pick(basket, req) > 0)
        late = _pick(h_time, k) <= 0
        reward += jnp.where(give, V.HANDOVER_REWARD + jnp.where(late, self.config.delay_penalty, 0.0), 0.0)
        basket = basket - (give & _onehot(req, V.N_TOOLS))
        h_got = h_got | (give & _onehot(k, n_h))
        return (h_phase, h_time, h_got, reward), (xy, pt, wp, tau, basket, done)

    def _fetch_step(self, core, k_rb, rb_done, k, free, eta):
        """§5.2: F acts after the robots and may release one of them. Returns
        (core, robot done bool[nT], F done bool[], reward f32[])."""
        n_t = self.n_robots
        tau = core.f_tau - 1
        busy = tau > 0
        start = ~busy & free
        finish = ~busy & ~free

        # Start k: a pass is doomed at once if its robot is not already waiting at its table.
        # The reference only checks passes to robots 0 and 1 at their start (see WarehouseConfig).
        starts_pass = start & (k >= 1) & (k <= self._checked_passes)
        not_ready = (_pick(core.rb_wp, k - 1) != self.get_tool) | (_pick(core.rb_tau, k - 1) > -100)
        failed = core.f_failed | (starts_pass & not_ready)

        # Finish the running action.
        act = core.f_act
        is_pass = finish & (act >= 1) & (act <= n_t)
        robot_j = _onehot(act - 1, n_t)  # the pass's robot (all False if not a pass)
        success = is_pass & ~failed & (_pick(core.rb_tau, act - 1) < 0) & (_pick(k_rb, act - 1) == self.get_tool)
        n_staged = jnp.sum(core.staging >= 0)
        give = success & (n_staged > 0)
        basket = core.basket + ((give & robot_j)[:, None] & _onehot(core.staging[0], V.N_TOOLS))
        popped = jnp.concatenate([core.staging[1:], jnp.full((1,), -1, jnp.int32)])
        staging = jnp.where(give, popped, core.staging)
        rb_done = rb_done | (success & robot_j)
        rb_tau = jnp.where(success & robot_j, 0, core.rb_tau)
        reward = jnp.where(is_pass & ~success, self.config.drop_penalty, 0.0)
        failed = jnp.where(is_pass, False, failed)

        o = act - 1 - n_t  # searched tool type
        is_search = finish & (act >= 1 + n_t)
        found_ok = is_search & (n_staged < V.STAGING_CAPACITY) & (_pick(core.found, o) < self.config.n_each_obj)
        found = core.found + (found_ok & _onehot(o, V.N_TOOLS))
        staging = jnp.where(found_ok & (jnp.arange(V.STAGING_CAPACITY) == n_staged), o, staging)

        tau = jnp.where(start, self._duration(k) - 1 + eta, tau)
        f_act = jnp.where(start, k, act)
        f_done = jnp.where(start, k == 0, free | finish)
        core = core.replace(
            f_act=f_act, f_tau=tau, f_failed=failed, staging=staging, found=found, basket=basket,
            rb_tau=rb_tau,
        )
        return core, rb_done, f_done, reward

    def _duration(self, f_action: chex.Array) -> chex.Array:
        """Nominal duration of an F action (Wait, Pass, Search)."""
        return jnp.where(
            f_action == 0, V.WAIT_DURATION, jnp.where(f_action <= self.n_robots, V.PASS_DURATION, V.SEARCH_DURATION)
        )

    def _humans_step(self, core: WarehouseCore) -> WarehouseCore:
        """§5 items 4–5: served check, then phase timers of the unfinished humans."""
        served = core.served | ((core.h_phase == 2) & core.h_got)
        active = ~core.h_fin
        time = jnp.where(active, core.h_time - 1, core.h_time)
        advance = active & (time <= 0) & core.h_got
        fin = core.h_fin | (advance & (core.h_phase == 3))
        step_up = advance & (core.h_phase < 3)
        phase = core.h_phase + step_up
        next_dur = _pick(jnp.asarray(self._durations), phase)
        time = jnp.where(step_up, next_dur, time)
        got = jnp.where(step_up & (phase <= 2), False, core.h_got)
        return core.replace(served=served, h_time=time, h_phase=phase, h_got=got, h_fin=fin)

    # --- observations and state ------------------------------------------------------------
    def _core_obs(self, core: WarehouseCore) -> chex.Array:
        """§7: robots see their location, the human at it, their basket and (near the tool
        room) how many tools are staged; F sees the staged tools and who waits at a table.

        Built column-wise (each entry compares its column index with the agent's values) so
        that the whole [n, O] matrix is one elementwise computation."""
        n_h, n_t = self.n_humans, self.n_robots
        col = jnp.arange(self.spec.obs_dim)
        c = col[None, :]  # [1, O]
        wp = core.rb_wp[:, None]  # [nT, 1]
        at_wa = (wp >= 0) & (wp < n_h)
        loc = jnp.where(wp >= 0, wp, n_h + 2)  # one-hot location, "none" last
        human = jnp.where(at_wa, n_h + 3 + 4 * wp + _pick(core.h_phase, wp), -1)  # slot 4h + c_h
        b0 = n_h + 3 + V.N_PHASES * n_h  # basket columns b0..b0+2, then the two ready flags
        basket = jnp.where((c >= b0) & (c < b0 + V.N_TOOLS), _pick(core.basket[:, None, :], c - b0), 0)
        n_staged = jnp.sum(core.staging >= 0)
        near_f = (wp < 0) | (wp >= n_h)
        ready = near_f & (((c == b0 + 3) & (n_staged == 1)) | ((c == b0 + 4) & (n_staged == 2)))
        robots = ((c == loc) | (c == human) | ready).astype(jnp.float32) + basket.astype(jnp.float32)
        if self.exact_motion:  # only the table node has the table's exact coordinates
            at_table = core.rb_pt == self.get_tool
        else:
            at_table = jnp.all(core.rb_xy == jnp.asarray(self._tables), axis=1)
        staged = jnp.sum(core.staging[:, None] == jnp.where(col < V.N_TOOLS, col, -2), axis=0)
        waiting = (col >= V.N_TOOLS) & (col < V.N_TOOLS + n_t) & _pick(at_table, col - V.N_TOOLS)
        fetch = staged.astype(jnp.float32) + waiting.astype(jnp.float32)
        return jnp.concatenate([robots, fetch[None]], axis=0)

    def _staged_counts(self, core: WarehouseCore) -> chex.Array:
        """f32[3]: staged tools per type."""
        return jnp.sum(core.staging[:, None] == jnp.arange(V.N_TOOLS), axis=0).astype(jnp.float32)

    def _core_global_state(self, core: WarehouseCore) -> chex.Array:
        """§8 (the reference's ``get_state`` for A/B/C, its generalisation for D/E)."""
        n_t, n_h = self.n_robots, self.n_humans
        if self.exact_motion:
            robots_xy = jnp.asarray(self._state_xy)[jnp.arange(n_t), core.rb_pt]
        else:
            robots_xy = core.rb_xy / jnp.asarray([V.STATE_X_SCALE, V.STATE_Y_SCALE], jnp.float32)
        pos = jnp.concatenate([robots_xy, jnp.asarray(self._fetch_state_xy)[None]]).ravel()
        passing = (core.f_act >= 1) & (core.f_act <= n_t) & (core.f_tau > 0)
        in_hand = jax.nn.one_hot(jnp.where(passing, core.staging[0], -1), V.N_TOOLS)
        kind = jnp.where(core.f_act <= 0, 0, jnp.where(core.f_act <= n_t, 1, 2))  # Wait, Pass, Search
        tau_ix = jnp.clip(core.f_tau - self._f_tau_min, 0, self._f_progress.shape[1] - 1)
        progress = jnp.where(core.f_act >= 0, jnp.asarray(self._f_progress)[kind, tau_ix], 0.0)
        t_ix = jnp.clip(core.h_time, 0, self._h_progress.shape[2] - 1)
        h_progress = jnp.asarray(self._h_progress)[jnp.arange(n_h), core.h_phase, t_ix]
        h_progress = jnp.where(core.h_time >= 0, h_progress, -1.0)
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

    @property
    def render_legend(self) -> tuple[tuple[str, str], ...]:
        """What ``render`` prints, symbol by symbol: (symbol, meaning) pairs."""
        from envs_jax.warehouse.render import RENDER_LEGEND

        return RENDER_LEGEND

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
