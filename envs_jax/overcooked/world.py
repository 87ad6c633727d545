"""Overcooked world state and the quantities derived from it (SPEC §3, §6, §9).

The state holds only what cannot be derived: object cells, chop counts, who holds what, plate
contents, knife/delivery contents, the agents' beliefs and the ``chop`` controllers' counters. The
true cell-code grid, the belief maps and the observations are pure functions of it.
"""

from __future__ import annotations

import chex
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax.overcooked.layouts import (
    AGENT,
    AGENT0_K,
    COUNTER,
    INIT_POS,
    N_AGENTS,
    N_FOODS,
    N_ITEMS,
    N_OBJECTS,
    OBJECT_CODES,
    STAY,
    Layout,
    N,
)

N_TASKS = 7  # length of the task one-hot (task 6 = lettuce-onion-tomato salad)
TASK_ID = 6
OBS_DIM = 3 * N_FOODS + 2 * (N_OBJECTS - N_FOODS) + N_TASKS  # 32
_SEVENTHS = (np.arange(N) / N).astype(np.float32)  # cell coordinate k -> k/7 (as the original's float64, rounded)
_THIRDS = (np.arange(4) / 3).astype(np.float32)  # chop count -> chop/3


@struct.dataclass
class OvercookedState:
    """Domain state of one environment (the ``core`` of ``EnvState``). All int32 unless noted.

    pos         [11, 2]  cell of every object (canonical order, SPEC §2.1); held items are at the
                         holder's cell, plated foods at the plate's cell
    chop        [3]      chop count of tomato, lettuce, onion (chopped ⇔ 3)
    hold        [3]      item held by each agent, −1 or 0..4
    plate_has   bool[2, 3]  foods on plate 1 / plate 2
    knife_hold  [2]      item lying on knife 1 / 2, −1 or 0..4
    deliv_hold  []       plate on the delivery cell (set only by the correct delivery), −1 or 3..4
    belief      [3, 11, 2]  each agent's believed cell of every object (SPEC §6)
    chop_ctr    [3]      per-agent counter of the ``chop`` controller
    prim        [3]      primitive actions of the last step (4 = stay after reset)
    """

    pos: chex.Array
    chop: chex.Array
    hold: chex.Array
    plate_has: chex.Array
    knife_hold: chex.Array
    deliv_hold: chex.Array
    belief: chex.Array
    chop_ctr: chex.Array
    prim: chex.Array


def initial_state() -> OvercookedState:
    """The (unique, deterministic) state after reset: everything at its spawn cell, beliefs exact.

    The reset's belief update (SPEC §3.2) leaves exact beliefs unchanged, so it is skipped."""
    pos = jnp.asarray(INIT_POS)
    return OvercookedState(
        pos=pos,
        chop=jnp.zeros((N_FOODS,), jnp.int32),
        hold=jnp.full((N_AGENTS,), -1, jnp.int32),
        plate_has=jnp.zeros((2, N_FOODS), bool),
        knife_hold=jnp.full((2,), -1, jnp.int32),
        deliv_hold=jnp.full((), -1, jnp.int32),
        belief=jnp.broadcast_to(pos, (N_AGENTS, N_OBJECTS, 2)),
        chop_ctr=jnp.zeros((N_AGENTS,), jnp.int32),
        prim=jnp.full((N_AGENTS,), STAY, jnp.int32),
    )


def flat(cell: chex.Array) -> chex.Array:
    """(..., 2) cells -> (...) flat indices x * 7 + y."""
    return cell[..., 0] * N + cell[..., 1]


# Cell helpers on (..., 2) arrays. They combine the two coordinates elementwise rather than by
# reductions over the last axis, which XLA fuses into far fewer loops under ``vmap``.
def same(a: chex.Array, b: chex.Array) -> chex.Array:
    """Cell equality."""
    return (a[..., 0] == b[..., 0]) & (a[..., 1] == b[..., 1])


def manhattan(a: chex.Array, b: chex.Array) -> chex.Array:
    return jnp.abs(a[..., 0] - b[..., 0]) + jnp.abs(a[..., 1] - b[..., 1])


def in_view(agent_cell: chex.Array, cell: chex.Array, radius: int) -> chex.Array:
    """Chebyshev distance ≤ radius (the agent's 5×5 view for radius 2)."""
    return jnp.maximum(jnp.abs(cell[..., 0] - agent_cell[..., 0]), jnp.abs(cell[..., 1] - agent_cell[..., 1])) <= radius


def loose_items(s: OvercookedState) -> chex.Array:
    """bool[5]: items lying by themselves (not held, not on a plate): they show on the grid."""
    k = jnp.arange(N_ITEMS)
    held = jnp.any(s.hold[None, :] == k[:, None], axis=1)
    plated = jnp.concatenate([jnp.any(s.plate_has, axis=0), jnp.zeros((2,), bool)])
    return ~held & ~plated


def grid_code(layout: Layout, s: OvercookedState, cell: chex.Array) -> chex.Array:
    """Code of the true grid at ``cell`` (SPEC §3.1): agents, then loose items on plain counters,
    then the static layout."""
    static = jnp.asarray(layout.static_grid)[cell[0], cell[1]]
    item_here = loose_items(s) & same(s.pos[:N_ITEMS], cell)
    item_code = jnp.sum(jnp.where(item_here, jnp.asarray(OBJECT_CODES[:N_ITEMS]), 0))
    agent_here = jnp.any(same(s.pos[AGENT0_K:], cell))
    code = jnp.where((static == COUNTER) & jnp.any(item_here), item_code, static)
    return jnp.where(agent_here, AGENT, code)


def true_grid(layout: Layout, s: OvercookedState) -> chex.Array:
    """int32[7, 7]: the original's cell-code grid, derived from the objects (SPEC §3.1)."""
    cells = jnp.stack(jnp.meshgrid(jnp.arange(N), jnp.arange(N), indexing="ij"), -1).reshape(-1, 2)
    loose = loose_items(s)
    at = same(s.pos[None, :, :], cells[:, None, :])  # [49, 11]
    item_code = jnp.sum(jnp.where(at[:, :N_ITEMS] & loose, jnp.asarray(OBJECT_CODES[:N_ITEMS]), 0), axis=1)
    static = jnp.asarray(layout.static_grid).reshape(-1)
    code = jnp.where((static == COUNTER) & jnp.any(at[:, :N_ITEMS] & loose, axis=1), item_code, static)
    return jnp.where(jnp.any(at[:, AGENT0_K:], axis=1), AGENT, code).reshape(N, N)


def update_beliefs(s: OvercookedState, radius: int) -> chex.Array:
    """SPEC §6: seen objects are believed where they are; a believed cell seen empty of the object
    resets the belief to the object's *initial* cell (no second check). Returns int32[3, 11, 2]."""
    me = s.pos[AGENT0_K:][:, None, :]  # [3, 1, 2]
    see_true = in_view(me, s.pos[None], radius)  # [3, 11]
    see_belief = in_view(me, s.belief, radius)
    init = jnp.asarray(INIT_POS)[None]
    return jnp.where(see_true[..., None], s.pos[None], jnp.where(see_belief[..., None], init, s.belief))


def belief_maps(layout: Layout, s: OvercookedState) -> chex.Array:
    """int32[3, 49]: each agent's belief map PM_i, flattened (SPEC §6).

    Background, then the code of every object at its believed cell with later objects winning,
    then 2 at the agent's own true cell."""
    cells = jnp.arange(N * N)
    at = flat(s.belief)[:, :, None] == cells  # [3, 11, 49]
    last = jnp.max(jnp.where(at, jnp.arange(N_OBJECTS)[None, :, None], -1), axis=1)  # [3, 49]
    pm = jnp.where(last >= 0, jnp.asarray(OBJECT_CODES)[jnp.maximum(last, 0)], layout.pm_background.reshape(-1))
    own = flat(s.pos[AGENT0_K:])[:, None] == cells
    return jnp.where(own, AGENT, pm)


def belief_codes_at(layout: Layout, s: OvercookedState, cells: chex.Array) -> chex.Array:
    """int32[3, K]: ``belief_maps`` read only at flat ``cells`` int32[3, K] (agent i's own cells).

    Much cheaper than building the maps when a controller needs a few cells."""
    at = flat(s.belief)[:, None, :] == cells[:, :, None]  # [3, K, 11]
    last = jnp.max(jnp.where(at, jnp.arange(N_OBJECTS), -1), axis=-1)
    code = jnp.where(last >= 0, jnp.asarray(OBJECT_CODES)[jnp.maximum(last, 0)], jnp.asarray(layout.pm_background.reshape(-1))[cells])
    return jnp.where(cells == flat(s.pos[AGENT0_K:])[:, None], AGENT, code)


def _features(s: OvercookedState, visible: chex.Array) -> chex.Array:
    """The 32-value layout of SPEC §9 for objects marked ``visible`` (bool[..., 11])."""
    # Table lookups rather than divisions, so that every compiled program yields the same floats
    # (XLA may turn x / 7 into x * (1/7), which differs in the last bit).
    xy = jnp.asarray(_SEVENTHS)[s.pos]  # [11, 2]
    chop = jnp.asarray(_THIRDS)[s.chop]
    food = jnp.concatenate([xy[:N_FOODS], chop[:, None]], axis=1)  # [3, 3]
    vis = visible[..., :, None]
    foods = jnp.where(vis[..., :N_FOODS, :], food, 0.0).reshape(*visible.shape[:-1], -1)
    others = jnp.where(vis[..., N_FOODS:, :], xy[N_FOODS:], 0.0).reshape(*visible.shape[:-1], -1)
    task = jnp.broadcast_to(jnp.asarray(np.eye(N_TASKS, dtype=np.float32)[TASK_ID]), (*visible.shape[:-1], N_TASKS))
    return jnp.concatenate([foods, others, task], axis=-1)


def observations(s: OvercookedState, radius: int) -> chex.Array:
    """f32[3, 32]: fresh observation of every agent from the true state (SPEC §9)."""
    visible = in_view(s.pos[AGENT0_K:][:, None, :], s.pos[None], radius)
    return _features(s, visible)


def global_state(s: OvercookedState) -> chex.Array:
    """f32[32]: the observation layout with every object visible (the traces' ``gstate``)."""
    return _features(s, jnp.ones((N_OBJECTS,), bool))
