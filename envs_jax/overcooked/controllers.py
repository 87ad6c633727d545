"""Macro-action controllers (SPEC §8.2) and the post-step termination checks (SPEC §8.4).

A controller turns agent i's running macro-action into one primitive action, reading the world as
it is *before* this step's physics and agent i's belief map from the end of the previous step.
All agents are handled at once (arrays over the 3 agents); the planner runs once per agent.
"""

from __future__ import annotations

from collections.abc import Callable

import chex
import jax.numpy as jnp
import numpy as np

from envs_jax.overcooked import world
from envs_jax.overcooked.layouts import (
    AGENT,
    AGENT0_K,
    COUNTER,
    DIRS,
    FLOOR,
    K_CHOP,
    K_COUNTER,
    K_DELIVER,
    K_DIR,
    K_GET,
    K_KNIFE,
    K_STAY,
    KNIFE_CELLS,
    N_AGENTS,
    N_FOODS,
    N_ITEMS,
    PLATE1_K,
    STAY,
    Layout,
    N,
)
from envs_jax.overcooked.world import OvercookedState, flat, in_view, manhattan, same

# Cells of the two hard-coded "step right" rules (SPEC §8.2 rules 3 and 6.2).
_CELL_1_1 = np.array([1, 1], np.int32)
_CELL_3_1 = np.array([3, 1], np.int32)
_CELL_1_0 = np.array([1, 0], np.int32)
_FLAT_2_1 = 2 * N + 1
_TEAMMATES = np.array([[j for j in range(N_AGENTS) if j != i] for i in range(N_AGENTS)], np.int32)

# planner(s i32[3], t i32[3], mates i32[3, 2], items i32[3, 5], enabled bool[3]) -> i32[3] (plan_table)
Planner = Callable[..., chex.Array]


def _knife_content(s: OvercookedState, cell: chex.Array):
    """(is a knife cell, item on it or −1) for cells [..., 2]."""
    k1 = same(cell, jnp.asarray(KNIFE_CELLS[0]))
    k2 = same(cell, jnp.asarray(KNIFE_CELLS[1]))
    return k1 | k2, jnp.where(k1, s.knife_hold[0], jnp.where(k2, s.knife_hold[1], -1))


def _unchopped_food(s: OvercookedState, item: chex.Array) -> chex.Array:
    return (item >= 0) & (item < N_FOODS) & (s.chop[jnp.clip(item, 0, N_FOODS - 1)] < 3)


def controllers(
    layout: Layout, s: OvercookedState, mac: chex.Array, planner: Planner, radius: int
) -> tuple[chex.Array, chex.Array, chex.Array]:
    """Primitive actions of all agents (SPEC §8.2).

    Args: ``mac`` int32[3] macro-actions being executed, ``planner`` answers for the 3 agents at
    once (``plan_table.make_planner``). Belief maps are read only where a rule looks.
    Returns (prim int32[3], done bool[3], chop_ctr int32[3]).
    """
    mac = jnp.clip(mac, 0, layout.num_actions - 1)
    kind = jnp.asarray(layout.mac_kind)[mac]
    obj = jnp.asarray(layout.mac_obj)[mac]
    direction = jnp.asarray(layout.mac_dir)[mac]
    me = s.pos[AGENT0_K:]  # [3, 2]
    hold = s.hold
    rows = jnp.arange(N_AGENTS)
    dirs = jnp.asarray(DIRS)

    # chop: first neighbour (right, down, left, up) that is a knife with an unchopped food.
    nbrs = me[:, None, :] + dirs[None, :4]  # [3, 4, 2]
    is_knife, content = _knife_content(s, nbrs)
    can_chop = is_knife & _unchopped_food(s, content)
    chop_dir = jnp.argmax(can_chop, axis=1)
    chop_any = jnp.any(can_chop, axis=1)
    ctr = jnp.where(chop_any, s.chop_ctr + 1, s.chop_ctr)
    chop_done = ~chop_any | (ctr >= 3)
    chop_ctr = jnp.where((kind == K_CHOP) & chop_any & (ctr >= 3), 0, jnp.where(kind == K_CHOP, ctr, s.chop_ctr))
    chop_a = jnp.where(chop_any, chop_dir, STAY)

    # The belief-map cells the rules read: the direction macro's next cell, (2,1), the believed
    # target cell and the middle counters.
    step_cell = flat(me + dirs[jnp.clip(direction, 0, 3)])
    belief_target = s.belief[rows, jnp.clip(obj, 0)]  # [3, 2]
    cc = jnp.asarray(layout.counter_cells).reshape(-1, 2)
    n_cc = cc.shape[0]
    queries = jnp.concatenate(
        [step_cell[:, None], jnp.full((N_AGENTS, 1), _FLAT_2_1), flat(belief_target)[:, None],
         jnp.broadcast_to(flat(cc), (N_AGENTS, n_cc))], axis=1,
    )
    codes = world.belief_codes_at(layout, s, queries)  # [3, 3 + C]

    # direction macros: step only onto believed-free floor.
    dir_a = jnp.where(codes[:, 0] == FLOOR, direction, STAY)

    # deliver's hard-coded rule: at (1,1) with an agent believed at (2,1), step right.
    agent_below_1_1 = codes[:, 1] == AGENT
    deliver_rule = (kind == K_DELIVER) & same(me, _CELL_1_1) & agent_below_1_1

    # Target cell: the believed cell of the target object, or the first believed-free middle counter.
    target, pm_t = belief_target, codes[:, 2]
    if n_cc:
        free = codes[:, 3:] == COUNTER  # [3, C]
        counter_found = jnp.any(free, axis=1)
        first_free = jnp.argmax(free, axis=1)
        is_counter = kind == K_COUNTER
        target = jnp.where(is_counter[:, None], cc[first_free], target)
        pm_t = jnp.where(is_counter, COUNTER, pm_t)
    else:
        counter_found = jnp.zeros((N_AGENTS,), bool)
    t_flat = flat(target)
    inview = in_view(me, target, radius)
    adjacent = manhattan(me, target) == 1
    is_get_food = (kind == K_GET) & (obj < N_FOODS)
    plate_at_t = same(s.pos[PLATE1_K], target) | same(s.pos[PLATE1_K + 1], target)
    food_in_plate = is_get_food & inview & plate_at_t  # rule 6.1
    knife_rule = same(target, _CELL_1_0) & same(me, _CELL_3_1) & agent_below_1_1  # rule 6.2
    under_agent = (pm_t == AGENT) & inview  # rule 6.3
    seeks = (kind == K_GET) | (kind == K_KNIFE) | (kind == K_DELIVER)
    needs_plan = (seeks & ~deliver_rule & ~food_in_plate & ~knife_rule & ~under_agent) | (
        (kind == K_COUNTER) & counter_found
    )

    mates = flat(s.belief[rows[:, None], AGENT0_K + jnp.asarray(_TEAMMATES)])  # [3, 2]
    plan = planner(flat(me), t_flat, mates, flat(s.belief[:, :N_ITEMS]), needs_plan)

    # Rule 6.4 on arrival (adjacent before moving): the bump is the interaction, with exceptions.
    chopped_in_hand = (hold >= 0) & (hold < N_FOODS) & (s.chop[jnp.clip(hold, 0, N_FOODS - 1)] == 3)
    is_get_plate = (kind == K_GET) & (obj >= PLATE1_K)
    t_is_knife, t_content = _knife_content(s, target)
    item_moved = ~same(s.pos[jnp.clip(obj, 0)], target)
    seek_a = plan
    seek_done = (plan == STAY) | adjacent
    seek_done = jnp.where(adjacent & is_get_plate & chopped_in_hand, False, seek_done)
    stop = (is_get_plate & (hold >= 0) & ~chopped_in_hand & (hold < N_FOODS)) | ((kind == K_KNIFE) & (hold < 0))
    stop |= is_get_food & t_is_knife & _unchopped_food(s, t_content)
    stop |= (kind == K_GET) & item_moved
    seek_a = jnp.where(adjacent & stop, STAY, seek_a)
    # Earlier rules override later ones: 6.3, then 6.2, 6.1 and deliver's rule 3 on top.
    for rule, a, d in ((under_agent, STAY, True), (knife_rule, 0, False), (food_in_plate, STAY, True),
                       (deliver_rule, 0, False)):
        seek_a = jnp.where(rule, a, seek_a)
        seek_done = jnp.where(rule, d, seek_done)

    counter_a = jnp.where(counter_found, plan, STAY)
    counter_done = ~counter_found | adjacent

    prim = jnp.select(
        [kind == K_STAY, kind == K_CHOP, kind == K_COUNTER, kind == K_DIR], [STAY, chop_a, counter_a, dir_a], seek_a
    )
    done = jnp.select(
        [kind == K_STAY, kind == K_CHOP, kind == K_COUNTER, kind == K_DIR], [True, chop_done, counter_done, True], seek_done
    )
    return prim.astype(jnp.int32), done, chop_ctr.astype(jnp.int32)


def post_step_done(layout: Layout, s: OvercookedState, mac: chex.Array) -> chex.Array:
    """SPEC §8.4: terminations decided after the physics and the belief update (bool[3]).

    ``s`` is the post-step state (positions, holdings, new beliefs)."""
    mac = jnp.clip(mac, 0, layout.num_actions - 1)
    kind = jnp.asarray(layout.mac_kind)[mac]
    obj = jnp.asarray(layout.mac_obj)[mac]
    me = s.pos[AGENT0_K:]
    target = s.belief[jnp.arange(N_AGENTS), jnp.clip(obj, 0)]
    adjacent = manhattan(me, target) == 1
    item = jnp.clip(obj, 0)
    arrived_empty = ((kind == K_KNIFE) | (kind == K_DELIVER)) & (s.hold < 0) & adjacent
    t_is_knife, _ = _knife_content(s, target)
    food_here_unchopped = same(s.pos[item], target) & (s.chop[jnp.clip(obj, 0, N_FOODS - 1)] < 3)
    food_on_knife = (kind == K_GET) & (obj < N_FOODS) & adjacent & t_is_knife & food_here_unchopped
    stale = (kind == K_GET) & ~same(s.pos[item], target)
    return arrived_empty | food_on_knife | stale
