"""Macro-action Box Pushing (the original ``BP-MA-v0``) as a pure-functional JAX env.

Two agents on a ``g × g`` grid push two small boxes or, together, one big box to the top
row. Exactly per ``docs/envs/boxpushing.md``, quirks included (stale waypoint
memory Q1, no agent collisions Q2, the planner's SB0-row obstacle test and unclamped
positions Q3, sequential resolution Q18, non-absorbing terminal Q11, …).

Positions are integer cells ``(c, r)`` (the reference's float cell centres are
``c + 0.5``, ``r + 0.5``); headings 0..3 = N, E, S, W; north is +r; the goal row is
``g − 1``. Boxes only move north, so their columns are static.

Names: ``boxpushing-{g}x{g}`` for even ``g`` in 4..30 (experiments: 6, 8, 10, 12, 14).
"""

from __future__ import annotations

import dataclasses
import re

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax.core import CoreStep, EnvSpec, MacroEnv, RewardBounds
from envs_jax.registry import apply_overrides, register

# Macro-action ids.
GT_SB0, GT_SB1, GT_BB0, GT_BB1, PUSH, TURN_L, TURN_R, STAY = range(8)
ACTION_NAMES = ("GT_SB0", "GT_SB1", "GT_BB0", "GT_BB1", "Push", "Turn_L", "Turn_R", "Stay")
NORTH, EAST, SOUTH, WEST = range(4)
# (dc, dr) per heading N, E, S, W.
HEADING_DELTA = np.array([[0, 1], [1, 0], [0, -1], [-1, 0]], np.int32)
SB0, SB1, BB = range(3)
OBS_SIZE = 5
STATE_DIM = 18
GRID_SIZES = tuple(range(4, 31, 2))
_BIG_INT = 1 << 20  # "infinite" planner distance, still safe in int32 arithmetic


@dataclasses.dataclass(frozen=True)
class BoxPushingConfig:
    """Static configuration; defaults are the original experiments' settings."""

    grid: int = 6
    big_box_reward: float = 300.0
    small_box_reward: float = 20.0
    penalty: float = -10.0
    step_cost: float = -0.1
    horizon: int = 100
    discount: float = 0.98

    def __post_init__(self):
        if self.grid not in GRID_SIZES:
            raise ValueError(f"boxpushing: grid={self.grid!r} is invalid; valid grids are even sizes {GRID_SIZES}")
        if self.horizon < 1:
            raise ValueError(f"boxpushing: horizon={self.horizon!r} must be >= 1")
        if not 0.0 < self.discount <= 1.0:
            raise ValueError(f"boxpushing: discount={self.discount!r} must be in (0, 1]")


@dataclasses.dataclass(frozen=True)
class Layout:
    """Deterministic start configuration (SPEC §3), integer cells."""

    agent_pos: np.ndarray  # i32[2, 2] (c, r)
    agent_head: np.ndarray  # i32[2]
    box_col: np.ndarray  # i32[3]: SB0, SB1 columns and the big box's left column
    box_row: int  # start row of all boxes
    waypoints: np.ndarray  # i32[4, 2]: W0..W3, one row below the boxes


def layout(g: int) -> Layout:
    k = g // 2
    if g == 4:
        agents, sb_cols = [[0, 0], [3, 0]], (0, 3)
    elif g == 6:
        agents, sb_cols = [[0, 1], [5, 1]], (0, 5)
    else:
        agents, sb_cols = [[1, 1], [g - 2, 1]], (1, g - 2)
    box_col = np.array([sb_cols[0], sb_cols[1], k - 1], np.int32)
    wp_cols = [sb_cols[0], sb_cols[1], k - 1, k]
    return Layout(
        agent_pos=np.array(agents, np.int32),
        agent_head=np.array([EAST, WEST], np.int32),
        box_col=box_col,
        box_row=k,
        waypoints=np.array([[c, k - 1] for c in wp_cols], np.int32),
    )


@struct.dataclass
class BoxPushingCore:
    pos: chex.Array  # i32[2, 2] agent cells (c, r); unbounded (Q3)
    head: chex.Array  # i32[2] headings N/E/S/W
    wp: chex.Array  # i32[2] last waypoint whose GT completed, -1 none; never cleared (Q1)
    lock: chex.Array  # bool[2] locked into the cooperative big-box push; never cleared
    box_row: chex.Array  # i32[3] rows of SB0, SB1, BB


@struct.dataclass
class _Agent:
    """One agent's fields while its primitive step is resolved."""

    pos: chex.Array  # i32[2]
    head: chex.Array  # i32[]
    wp: chex.Array  # i32[]
    free: chex.Array  # bool[]
    rho: chex.Array  # f32[] the agent's own reward term (penalties)


class BoxPushing(MacroEnv[BoxPushingCore]):
    """Two-agent macro-action Box Pushing. See module docstring."""

    def __init__(self, config: BoxPushingConfig = BoxPushingConfig()):
        self.config = config
        self.layout = layout(config.grid)
        self.spec = EnvSpec(
            name=f"boxpushing-{config.grid}x{config.grid}",
            num_agents=2,
            num_actions=(8, 8),
            action_names=(ACTION_NAMES, ACTION_NAMES),
            obs_sizes=(OBS_SIZE, OBS_SIZE),
            state_dim=STATE_DIM,
            horizon=config.horizon,
            discount=config.discount,
            agent_names=("agent_0", "agent_1"),
        )

    def reward_bounds(self) -> RewardBounds:
        """A push costs each agent at most one wall and three box bumps (``_push``); the episode ends on the step
        the first box reaches the goal row, so each box pays at most once."""
        cfg = self.config
        penalties = 2 * 4  # two agents, a wall and three boxes each
        boxes = (cfg.small_box_reward, cfg.small_box_reward, cfg.big_box_reward)
        step_min = cfg.step_cost + penalties * min(0.0, cfg.penalty) + sum(min(0.0, r) for r in boxes)
        step_max = max(0.0, cfg.step_cost) + penalties * max(0.0, cfg.penalty)
        return RewardBounds(step_min, cfg.horizon * step_max + sum(max(0.0, r) for r in boxes))

    # --- geometry helpers ------------------------------------------------------------
    def _box_cells(self, box_row: chex.Array) -> chex.Array:
        """i32[4, 2]: cells of SB0, SB1, BB-left, BB-right."""
        col = self.layout.box_col
        cols = jnp.array([col[SB0], col[SB1], col[BB], col[BB] + 1], jnp.int32)
        rows = jnp.stack([box_row[SB0], box_row[SB1], box_row[BB], box_row[BB]])
        return jnp.stack([cols, rows], -1)

    def _at_edge(self, pos: chex.Array, head: chex.Array) -> chex.Array:
        g = self.config.grid
        c, r = pos[0], pos[1]
        edge = jnp.stack([r == g - 1, c == g - 1, r == 0, c == 0])
        return edge[head]

    # --- controllers (one primitive step of one agent, SPEC §6) ---------------------------
    def _goto(self, k: chex.Array, ag: _Agent, box_row: chex.Array) -> tuple[_Agent, chex.Array]:
        """GT_k for a (possibly traced) waypoint index ``k`` in 0..3."""
        w = jnp.asarray(self.layout.waypoints)[k]
        col = self.layout.box_col
        blocked_cols = jnp.array([col[SB0], col[SB1], col[BB], col[BB] + 1], jnp.int32)
        at_target = jnp.all(ag.pos == w)
        neigh = ag.pos[None, :] + jnp.asarray(HEADING_DELTA)  # [4, 2]
        dist = jnp.abs(neigh - w[None, :]).sum(-1)
        # Q3: only cells in SB0's *current* row at the four box columns count as obstacles.
        blocked = (neigh[:, 1] == box_row[SB0]) & jnp.any(neigh[:, 0:1] == blocked_cols[None, :], -1)
        dist = jnp.where(blocked, _BIG_INT, dist)
        d = jnp.arange(4)
        turn = jnp.where(d == ag.head, 0, jnp.where(d == (ag.head + 2) % 4, 2, 1))
        best = jnp.argmin(10 * dist + turn)  # first minimum = N, E, S, W tie order
        move = best == ag.head
        behind = best == (ag.head + 2) % 4
        pos = jnp.where(move, neigh[best], ag.pos)
        head = jnp.where(move, ag.head, jnp.where(behind, (ag.head + 1) % 4, best))  # Q6
        arrived = jnp.all(pos == w) & (head == NORTH)
        # At the waypoint already: re-orient north in one step, no move (Q5).
        pos = jnp.where(at_target, ag.pos, pos)
        head = jnp.where(at_target, NORTH, head)
        done = at_target | arrived
        out = ag.replace(
            pos=pos, head=head.astype(jnp.int32), wp=jnp.where(done, k, ag.wp).astype(jnp.int32), free=done
        )
        return out, box_row

    def _push(self, ag: _Agent, box_row: chex.Array) -> tuple[_Agent, chex.Array]:
        cfg = self.config
        delta = jnp.asarray(HEADING_DELTA)[ag.head]
        wall = self._at_edge(ag.pos, ag.head)
        pos = jnp.where(wall, ag.pos, ag.pos + delta)
        free = wall
        rho = jnp.where(wall, cfg.penalty, 0.0).astype(jnp.float32)
        pushed = jnp.zeros((), bool)
        col = self.layout.box_col
        for b in (SB0, SB1, BB):  # static 3-box resolution loop, in the reference's order
            cols = (col[b],) if b != BB else (col[b], col[b] + 1)
            hit = ~wall & (pos[1] == box_row[b]) & jnp.any(pos[0] == jnp.array(cols))
            push_ok = hit & (b != BB) & (ag.head == NORTH)
            bump = hit & ~push_ok
            box_row = box_row.at[b].add(push_ok.astype(jnp.int32))
            pushed = pushed | push_ok
            free = free | (push_ok & (box_row[b] == cfg.grid - 1)) | bump
            pos = jnp.where(bump, pos - delta, pos)
            rho = rho + jnp.where(bump, cfg.penalty, 0.0)
        free = free | (~wall & ~pushed & self._at_edge(pos, ag.head))  # walking into a wall: free (Q9)
        return ag.replace(pos=pos, free=free, rho=rho), box_row

    def _turn(self, delta: int):
        def turn(ag: _Agent, box_row):
            return ag.replace(head=(ag.head + delta) % 4, free=jnp.ones((), bool)), box_row

        return turn

    def _controller(self, action, ag: _Agent, box_row):
        # The four GT_k share one branch with a dynamic waypoint: under vmap every branch
        # is evaluated, so this keeps the step cheap.
        branches = [lambda a, b: self._goto(jnp.clip(action, 0, 3), a, b)]
        branches += [self._push, self._turn(-1), self._turn(1), self._turn(0)]
        return jax.lax.switch(jnp.maximum(action - 3, 0), branches, ag, box_row)

    # --- MacroEnv hooks ----------------------------------------------------------------
    def _core_reset(self, key: chex.PRNGKey) -> BoxPushingCore:
        del key  # the layout is deterministic (SPEC §10)
        lay = self.layout
        return BoxPushingCore(
            pos=jnp.asarray(lay.agent_pos),
            head=jnp.asarray(lay.agent_head),
            wp=jnp.full((2,), -1, jnp.int32),
            lock=jnp.zeros((2,), bool),
            box_row=jnp.full((3,), lay.box_row, jnp.int32),
        )

    def _core_reset_obs(self, core: BoxPushingCore) -> chex.Array:
        # Q12: the reference always returns "empty ahead" at reset.
        return jnp.tile(jnp.array([0, 0, 1, 0, 0], jnp.float32), (2, 1))

    def _core_step(self, key, core: BoxPushingCore, actions, free, mac) -> CoreStep:
        cfg = self.config
        # A. cooperative trigger, on the state before anything moves (Q1, Q19).
        wp_pair = jnp.sort(core.wp)
        trigger = (
            jnp.all(actions == PUSH) & jnp.all(free) & jnp.all(core.head == NORTH)
            & (wp_pair[0] == GT_BB0) & (wp_pair[1] == GT_BB1)
        )
        lock = core.lock | trigger

        # B. agents in index order; agent 1 sees the boxes agent 0 moved (Q18).
        def agent_step(box_row, i):
            ag = _Agent(core.pos[i], core.head[i], core.wp[i], jnp.zeros((), bool), jnp.zeros((), jnp.float32))
            moved, box_row_ctrl = self._controller(actions[i], ag, box_row)
            locked = ag.replace(pos=ag.pos + jnp.array([0, 1], jnp.int32))
            new = jax.tree_util.tree_map(lambda a, b: jnp.where(lock[i], a, b), locked, moved)
            box_row = jnp.where(lock[i], box_row, box_row_ctrl)
            mac_i = jnp.where(lock[i], PUSH, actions[i])
            return box_row, (new, mac_i)

        # Sequential by nature (Q18); unrolled so XLA fuses both agents' updates.
        box_row, (agents, mac_new) = jax.lax.scan(agent_step, core.box_row, jnp.arange(2), unroll=True)

        # C. the big box advances while anyone is locked; arrival frees the locked agents.
        any_lock = jnp.any(lock)
        box_row = box_row.at[BB].add(any_lock.astype(jnp.int32))
        bb_goal = any_lock & (box_row[BB] == cfg.grid - 1)
        mac_done = agents.free | (lock & bb_goal)

        # E. shared reward, summed in the reference's order.
        on_goal = box_row == cfg.grid - 1
        box_reward = jnp.array([cfg.small_box_reward, cfg.small_box_reward, cfg.big_box_reward], jnp.float32)
        reward = cfg.step_cost + agents.rho[0] + agents.rho[1] + jnp.sum(jnp.where(on_goal, box_reward, 0.0))
        new_core = BoxPushingCore(pos=agents.pos, head=agents.head, wp=agents.wp, lock=lock, box_row=box_row)
        return CoreStep(core=new_core, mac=mac_new, mac_done=mac_done, reward=reward, terminated=jnp.any(on_goal))

    def _core_obs(self, core: BoxPushingCore) -> chex.Array:
        g = self.config.grid
        front = core.pos + jnp.asarray(HEADING_DELTA)[core.head]  # [2, 2]
        cells = self._box_cells(core.box_row)
        same = jnp.all(front[:, None, :] == cells[None, :, :], -1)  # [2, 4]
        small = same[:, 0] | same[:, 1]
        big = same[:, 2] | same[:, 3]
        wall = (front[:, 0] < 0) | (front[:, 0] >= g) | (front[:, 1] < 0) | (front[:, 1] >= g)
        mate = jnp.all(front == core.pos[::-1], -1)
        empty = ~(small | big | wall | mate)
        return jnp.stack([small, big, empty, wall, mate], -1).astype(jnp.float32)

    def _core_global_state(self, core: BoxPushingCore) -> chex.Array:
        # Multiply by 1/g rather than divide: XLA rewrites divisions by constants inside jit,
        # which would make jitted and eager results differ in the last bit.
        inv_g = np.float32(1.0 / self.config.grid)
        agent_xy = (core.pos.astype(jnp.float32) + 0.5) * inv_g  # [2, 2]
        heading = jax.nn.one_hot(core.head, 4, dtype=jnp.float32)
        agents = jnp.concatenate([agent_xy, heading], -1).reshape(-1)  # [12]
        col = jnp.asarray(self.layout.box_col, jnp.float32)
        box_x = col + jnp.array([0.5, 0.5, 1.0], jnp.float32)  # BB: centre of its two cells
        box_y = core.box_row.astype(jnp.float32) + 0.5
        boxes = (jnp.stack([box_x, box_y], -1) * inv_g).reshape(-1)  # [6]
        return jnp.concatenate([agents, boxes])

    # --- rendering ---------------------------------------------------------------------
    # What ``render`` prints, symbol by symbol: (symbol, meaning) pairs (``jaxmac rollout`` prints them).
    render_legend = (
        (".", "empty cell (north is up; row 0 at the bottom)"),
        ("s", "small box (one agent can push it)"),
        ("B B", "the big box, two cells wide (both agents must push it together)"),
        ("0> 1<", "agent 0 / agent 1 and its heading: ^ north, > east, v south, < west"),
        ("s0^", "an agent in a box's cell: the box's symbol, then the agent's"),
        ("<- goal", "the goal row (top): the first box pushed into it ends the episode"),
        ("agent i: ...", "its macro-action, free (chooses next step) or busy, last waypoint, big-box lock"),
        ("off-grid", "an agent outside the grid (no walls stop it, Q3) is listed below the grid"),
    )

    def render(self, state) -> str:
        """Text grid, north at the top: ``s`` small box, ``B`` big box, ``^>v<`` agents 0/1
        (digits show which), ``.`` empty; off-grid agents are listed below."""
        core = jax.device_get(state.core)
        g = self.config.grid
        grid = [["." for _ in range(g)] for _ in range(g)]
        col = self.layout.box_col
        cells = [(col[SB0], core.box_row[SB0], "s"), (col[SB1], core.box_row[SB1], "s"),
                 (col[BB], core.box_row[BB], "B"), (col[BB] + 1, core.box_row[BB], "B")]
        for c, r, ch in cells:
            if 0 <= r < g:
                grid[r][c] = ch
        arrows = "^>v<"
        lines, off = [], []
        for i in range(2):
            c, r = (int(v) for v in core.pos[i])
            mark = f"{i}{arrows[int(core.head[i])]}"
            if 0 <= c < g and 0 <= r < g:
                grid[r][c] = mark if grid[r][c] == "." else grid[r][c] + mark
            else:
                off.append(f"agent {i} off-grid at (c={c}, r={r}) facing {'NESW'[int(core.head[i])]}")
        width = max(len(x) for row in grid for x in row)
        for r in range(g - 1, -1, -1):
            lines.append(" ".join(x.ljust(width) for x in grid[r]) + ("   <- goal" if r == g - 1 else ""))
        macs = jax.device_get(state.mac)
        free = jax.device_get(state.mac_done)
        for i in range(2):
            name = ACTION_NAMES[int(macs[i])] if macs[i] >= 0 else "-"
            lines.append(
                f"agent {i}: mac={name} {'free' if free[i] else 'busy'} wp={int(core.wp[i])} "
                f"locked={bool(core.lock[i])}"
            )
        lines.append(f"t={int(jax.device_get(state.t))}")
        return "\n".join(lines + off)


def _build(match: re.Match, overrides: dict) -> BoxPushing:
    g1, g2 = int(match.group(1)), int(match.group(2))
    name = match.group(0)
    if g1 != g2:
        raise ValueError(f"{name}: grids are square, got {g1}x{g2}; valid grids: {GRID_SIZES}")
    if "grid" in overrides:
        raise ValueError(f"{name}: the grid comes from the name; override 'grid' is not allowed")
    if g1 not in GRID_SIZES:
        raise ValueError(f"{name}: grid {g1} is invalid; valid grids are even sizes {GRID_SIZES}")
    return BoxPushing(apply_overrides(BoxPushingConfig(grid=g1), overrides, name))


register(
    "boxpushing",
    r"boxpushing-(\d+)x(\d+)",
    "boxpushing-{g}x{g} for even g in 4..30",
    _build,
)
