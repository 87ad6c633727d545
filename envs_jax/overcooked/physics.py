"""Physics of one primitive step (SPEC §5): sequential agents with deferral and swaps.

Agents are processed in index order in passes; an agent walking into a teammate that has not
moved yet retries in the next pass (or swaps with it when they walk into each other). Three
passes always suffice (SPEC §5 "Bound on passes"), so the loop is a fixed ``fori_loop`` of nine
(pass, agent) iterations that skip resolved agents. Interactions (pick up, put down, chop, plate,
deliver) happen in the same sequence, so a lower-index agent wins a contested item.

Rewards are returned as event counts (chops completed, wrong deliveries, correct delivery) so the
physics stays integer; the env weighs them with the configured rewards.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.overcooked.layouts import (
    AGENT,
    AGENT0_K,
    COUNTER,
    DELIVERY,
    DIRS,
    FLOOR,
    INIT_POS,
    KNIFE,
    KNIFE_CELLS,
    LETTUCE,
    N_AGENTS,
    N_FOODS,
    N_ITEMS,
    ONION,
    PLATE,
    PLATE1_K,
    STAY,
    TOMATO,
    Layout,
)
from envs_jax.overcooked.world import OvercookedState, grid_code, same


@struct.dataclass
class Events:
    """Reward events of one step (int32 counts)."""

    chops: chex.Array  # foods that reached 3 chops
    wrong: chex.Array  # wrong deliveries
    correct: chex.Array  # correct dish delivered (0/1): the episode terminates


def _bundle(s: OvercookedState, obj: chex.Array) -> chex.Array:
    """bool[5]: item ``obj`` (−1 for none) and, if it is a plate, the foods on it."""
    k = jnp.arange(N_ITEMS)
    plate = jnp.clip(obj - PLATE1_K, 0, 1)
    foods = jnp.where(obj >= PLATE1_K, s.plate_has[plate], False)
    return (k == obj) | jnp.concatenate([foods, jnp.zeros((2,), bool)])


def _move(pos: chex.Array, mask: chex.Array, cell: chex.Array) -> chex.Array:
    """Items in ``mask`` (bool[5]) go to ``cell``."""
    return pos.at[:N_ITEMS].set(jnp.where(mask[:, None], cell, pos[:N_ITEMS]))


def _agent_turn(layout: Layout, s: OvercookedState, ev: Events, resolved, prim, i):
    """Process unresolved agent ``i`` with primitive action ``prim[i]`` (SPEC §5 (a)–(d))."""
    a = prim[i]
    me = s.pos[AGENT0_K + i]
    c = me + jnp.asarray(DIRS)[a]
    code = grid_code(layout, s, c)
    h = s.hold[i]
    holding = h >= 0
    is_plate_h = h >= PLATE1_K
    chopped = s.chop == 3  # bool[3]
    chopped_h = (h >= 0) & (h < N_FOODS) & chopped[jnp.clip(h, 0, N_FOODS - 1)]
    act = a != STAY

    # (a) a teammate stands on c.
    at_c = same(s.pos[AGENT0_K:], c)
    j = jnp.argmax(at_c)
    bump_agent = act & (code == AGENT)
    j_free = ~resolved[j]
    j_target = s.pos[AGENT0_K + j] + jnp.asarray(DIRS)[prim[j]]
    swap = bump_agent & j_free & (prim[j] != STAY) & same(j_target, me)
    defer = bump_agent & j_free & ~swap
    # (b) free floor.
    walk = act & (code == FLOOR)

    # Which food / plate / knife sits at c (valid only under the matching code).
    food_at = jnp.select([code == TOMATO, code == LETTUCE, code == ONION], [0, 1, 2], -1)
    plate_at = jnp.where(same(s.pos[PLATE1_K], c), PLATE1_K, PLATE1_K + 1)
    kn = jnp.where(same(jnp.asarray(KNIFE_CELLS[0]), c), 0, 1)
    e = s.knife_hold[kn]
    e_food = (e >= 0) & (e < N_FOODS)
    e_chopped = e_food & chopped[jnp.clip(e, 0, N_FOODS - 1)]
    e_plate = e >= PLATE1_K
    on_knife = act & (code == KNIFE)

    # (c) empty-handed bumps.
    empty = act & ~holding
    pick_food = empty & (food_at >= 0)
    pick_plate = empty & (code == PLATE)
    knife_take = empty & on_knife & (e_plate | e_chopped)
    knife_chop = empty & on_knife & e_food & ~e_chopped
    # (d) bumps while holding h.
    full = act & holding
    put_counter = full & (code == COUNTER)
    food_to_plate = full & (code == PLATE) & chopped_h
    knife_put = full & on_knife & (e < 0)
    knife_merge_to_held = full & on_knife & e_chopped & is_plate_h  # chopped food joins the held plate
    knife_merge_to_plate = full & on_knife & e_plate & chopped_h  # held food joins the plate; take it
    at_delivery = full & (code == DELIVERY)
    plate_row = s.plate_has[jnp.clip(h - PLATE1_K, 0, 1)]
    deliver_ok = at_delivery & is_plate_h & jnp.all(plate_row)
    deliver_bad = at_delivery & ~deliver_ok
    counter_food_to_plate = full & (food_at >= 0) & is_plate_h & chopped[jnp.clip(food_at, 0, N_FOODS - 1)]

    pos, hold, plate_has = s.pos, s.hold, s.plate_has
    knife_hold, chop, deliv_hold = s.knife_hold, s.chop, s.deliv_hold
    mine = _bundle(s, h)

    # Movement: walk (with the held bundle) or swap with agent j.
    theirs = _bundle(s, s.hold[j])
    new_me = jnp.where(walk, c, jnp.where(swap, s.pos[AGENT0_K + j], me))
    pos = _move(pos, mine & (walk | swap), new_me)
    pos = _move(pos, theirs & swap, me)
    pos = pos.at[AGENT0_K + j].set(jnp.where(swap, me, pos[AGENT0_K + j]))
    pos = pos.at[AGENT0_K + i].set(new_me)

    # Pick-ups from counters and knives: the item (with a plate's foods) comes to the agent.
    picked = jnp.select([pick_food, pick_plate, knife_take], [food_at, plate_at, e], -1)
    pos = _move(pos, _bundle(s, picked), me)
    knife_hold = knife_hold.at[kn].set(jnp.where(knife_take | knife_merge_to_held | knife_merge_to_plate, -1, e))
    # Chopping.
    chop_inc = jnp.where(knife_chop, jnp.arange(N_FOODS) == e, False)
    chop = chop + chop_inc.astype(jnp.int32)
    n_chops = jnp.sum(chop_inc & (chop == 3)).astype(jnp.int32)

    # Put-downs: on a counter, onto a plate on a counter, onto an empty knife.
    pos = _move(pos, mine & (put_counter | knife_put), c)
    pos = _move(pos, mine & food_to_plate, c)
    knife_hold = knife_hold.at[kn].set(jnp.where(knife_put, h, knife_hold[kn]))
    plate_of_c = plate_at - PLATE1_K
    plate_has = plate_has.at[plate_of_c].set(
        plate_has[plate_of_c] | (food_to_plate & (jnp.arange(N_FOODS) == h))
    )
    # Merges into the held plate (chopped food from a knife or a counter).
    merged = jnp.select([knife_merge_to_held, counter_food_to_plate], [e, food_at], -1)
    pos = _move(pos, _bundle(s, merged), me)
    held_plate = jnp.clip(h - PLATE1_K, 0, 1)
    plate_has = plate_has.at[held_plate].set(
        plate_has[held_plate] | ((knife_merge_to_held | counter_food_to_plate) & (jnp.arange(N_FOODS) == merged))
    )
    # Held chopped food onto the plate lying on the knife; the agent takes that plate.
    knife_plate = jnp.clip(e - PLATE1_K, 0, 1)
    pos = _move(pos, _bundle(s, e) & knife_merge_to_plate, me)
    plate_has = plate_has.at[knife_plate].set(
        plate_has[knife_plate] | (knife_merge_to_plate & (jnp.arange(N_FOODS) == h))
    )

    # Deliveries: the correct dish stays on the delivery cell; anything else is sent back to
    # its initial cell(s), foods un-chopped.
    pos = _move(pos, mine & deliver_ok, c)
    deliv_hold = jnp.where(deliver_ok, h, deliv_hold)
    sent_back = mine & deliver_bad
    pos = pos.at[:N_ITEMS].set(jnp.where(sent_back[:, None], jnp.asarray(INIT_POS[:N_ITEMS]), pos[:N_ITEMS]))
    chop = jnp.where(sent_back[:N_FOODS], 0, chop)
    plate_has = plate_has.at[held_plate].set(jnp.where(deliver_bad & is_plate_h, False, plate_has[held_plate]))

    # What the agent holds afterwards.
    drops = put_counter | food_to_plate | knife_put | deliver_ok | deliver_bad
    hold = hold.at[i].set(
        jnp.select([picked >= 0, knife_merge_to_plate, drops], [picked, e, -1], h)
    )
    new_s = s.replace(pos=pos, hold=hold, plate_has=plate_has, knife_hold=knife_hold, chop=chop, deliv_hold=deliv_hold)
    ev = Events(
        chops=ev.chops + n_chops,
        wrong=ev.wrong + deliver_bad.astype(jnp.int32),
        correct=ev.correct + deliver_ok.astype(jnp.int32),
    )
    resolved = resolved.at[i].set(~defer)
    resolved = resolved.at[j].set(resolved[j] | swap)
    return new_s, ev, resolved


def physics(layout: Layout, s: OvercookedState, prim: chex.Array) -> tuple[OvercookedState, Events]:
    """Apply the joint primitive action ``prim`` (int32[3]) to the world (SPEC §5)."""
    zero = jnp.zeros((), jnp.int32)

    def body(it, carry):
        s, ev, resolved = carry
        i = it % N_AGENTS
        new = _agent_turn(layout, s, ev, resolved.at[i].set(True), prim, i)
        return jax.tree_util.tree_map(lambda x, y: jnp.where(resolved[i], x, y), (s, ev, resolved), new)

    init = (s, Events(zero, zero, zero), jnp.zeros((N_AGENTS,), bool))
    s, ev, _ = jax.lax.fori_loop(0, 3 * N_AGENTS, body, init)
    return s.replace(prim=prim), ev
