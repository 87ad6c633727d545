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
    OBJECT_CODES,
    ONION,
    PLATE,
    PLATE1_K,
    STAY,
    TOMATO,
    Layout,
    N,
)
from envs_jax.overcooked.world import OvercookedState, loose_items


@struct.dataclass
class Events:
    """Reward events of one step (int32 counts)."""

    chops: chex.Array  # foods that reached 3 chops
    wrong: chex.Array  # wrong deliveries
    correct: chex.Array  # correct dish delivered (0/1): the episode terminates


@struct.dataclass
class _World:
    """What the physics reads and changes; cells as flat indices (no reductions over (x, y)
    pairs, which keeps XLA's fused loops few and wide)."""

    cell: chex.Array  # i32[11] flat cell of every object
    hold: chex.Array
    plate_has: chex.Array
    knife_hold: chex.Array
    chop: chex.Array
    deliv_hold: chex.Array


_DIR_FLAT = DIRS[:, 0] * N + DIRS[:, 1]  # primitive action -> flat displacement
_INIT_FLAT = INIT_POS[:, 0] * N + INIT_POS[:, 1]
_KNIFE1_FLAT = int(KNIFE_CELLS[0, 0] * N + KNIFE_CELLS[0, 1])


def _code_at(layout: Layout, w: _World, c: chex.Array) -> chex.Array:
    """True grid code at flat cell ``c`` (SPEC §3.1; as ``world.grid_code``)."""
    static = jnp.asarray(layout.static_grid.reshape(-1))[c]
    item_here = loose_items(w) & (w.cell[:N_ITEMS] == c)
    item_code = jnp.sum(jnp.where(item_here, jnp.asarray(OBJECT_CODES[:N_ITEMS]), 0))
    code = jnp.where((static == COUNTER) & jnp.any(item_here), item_code, static)
    return jnp.where(jnp.any(w.cell[AGENT0_K:] == c), AGENT, code)


def _bundle(s: _World, obj: chex.Array) -> chex.Array:
    """bool[5]: item ``obj`` (−1 for none) and, if it is a plate, the foods on it."""
    k = jnp.arange(N_ITEMS)
    plate = jnp.clip(obj - PLATE1_K, 0, 1)
    foods = jnp.where(obj >= PLATE1_K, s.plate_has[plate], False)
    return (k == obj) | jnp.concatenate([foods, jnp.zeros((2,), bool)])


def _agent_turn(layout: Layout, s: _World, ev: Events, resolved, prim, i):
    """Process unresolved agent ``i`` with primitive action ``prim[i]`` (SPEC §5 (a)–(d))."""
    a = prim[i]
    me = s.cell[AGENT0_K + i]
    c = me + jnp.asarray(_DIR_FLAT)[a]
    code = _code_at(layout, s, c)
    h = s.hold[i]
    holding = h >= 0
    is_plate_h = h >= PLATE1_K
    chopped = s.chop == 3  # bool[3]
    chopped_h = (h >= 0) & (h < N_FOODS) & chopped[jnp.clip(h, 0, N_FOODS - 1)]
    act = a != STAY

    # (a) a teammate stands on c.
    j = jnp.argmax(s.cell[AGENT0_K:] == c)
    bump_agent = act & (code == AGENT)
    j_free = ~resolved[j]
    j_target = s.cell[AGENT0_K + j] + jnp.asarray(_DIR_FLAT)[prim[j]]
    swap = bump_agent & j_free & (prim[j] != STAY) & (j_target == me)
    defer = bump_agent & j_free & ~swap
    # (b) free floor.
    walk = act & (code == FLOOR)

    # Which food / plate / knife sits at c (valid only under the matching code).
    food_at = jnp.select([code == TOMATO, code == LETTUCE, code == ONION], [0, 1, 2], -1)
    plate_at = jnp.where(s.cell[PLATE1_K] == c, PLATE1_K, PLATE1_K + 1)
    kn = jnp.where(c == _KNIFE1_FLAT, 0, 1)
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

    mine = _bundle(s, h)
    theirs = _bundle(s, s.hold[j]) & swap
    # Another item (with a plate's foods) that comes to the agent's cell: picked up from a counter
    # or knife, merged into the held plate, or the plate lying on the knife that the agent takes.
    fetched = jnp.select(
        [pick_food, pick_plate, knife_take | knife_merge_to_held | knife_merge_to_plate, counter_food_to_plate],
        [food_at, plate_at, e, food_at],
        -1,
    )
    new_me = jnp.where(walk, c, jnp.where(swap, s.cell[AGENT0_K + j], me))
    mine_dest = jnp.where(walk | swap, new_me, c)
    mine_moves = walk | swap | put_counter | knife_put | food_to_plate | deliver_ok
    dest = jnp.where(mine & mine_moves, mine_dest, s.cell[:N_ITEMS])
    dest = jnp.where(_bundle(s, fetched) | theirs, me, dest)
    sent_back = mine & deliver_bad  # a wrong delivery returns everything to its initial cell
    dest = jnp.where(sent_back, jnp.asarray(_INIT_FLAT[:N_ITEMS]), dest)
    objects = jnp.arange(s.cell.shape[0])
    cell = jnp.concatenate([dest, s.cell[N_ITEMS:]])
    cell = jnp.where(swap & (objects == AGENT0_K + j), me, cell)
    cell = jnp.where(objects == AGENT0_K + i, new_me, cell)

    # Chopping.
    chop_inc = knife_chop & (jnp.arange(N_FOODS) == e)
    chop = s.chop + chop_inc.astype(jnp.int32)
    n_chops = jnp.sum(chop_inc & (chop == 3)).astype(jnp.int32)
    chop = jnp.where(sent_back[:N_FOODS], 0, chop)

    # Plates: one food joins one plate (the cases are exclusive), or the held plate is emptied.
    held_plate = jnp.clip(h - PLATE1_K, 0, 1)
    joins = food_to_plate | knife_merge_to_held | counter_food_to_plate | knife_merge_to_plate
    plate_idx = jnp.select([food_to_plate, knife_merge_to_plate], [plate_at - PLATE1_K, jnp.clip(e - PLATE1_K, 0, 1)], held_plate)
    food_idx = jnp.select([knife_merge_to_held, counter_food_to_plate], [e, food_at], h)
    plate_rows = jnp.arange(2)[:, None]
    plate_has = s.plate_has | (joins & (plate_rows == plate_idx) & (jnp.arange(N_FOODS) == food_idx))
    plate_has = plate_has & ~(deliver_bad & is_plate_h & (plate_rows == held_plate))

    knife_hold = jnp.where(
        jnp.arange(2) == kn, jnp.select([knife_take | knife_merge_to_held | knife_merge_to_plate, knife_put], [-1, h], e), s.knife_hold
    )
    deliv_hold = jnp.where(deliver_ok, h, s.deliv_hold)
    picked = jnp.select([pick_food, pick_plate, knife_take, knife_merge_to_plate], [food_at, plate_at, e, e], -1)
    drops = put_counter | food_to_plate | knife_put | deliver_ok | deliver_bad
    agents = jnp.arange(N_AGENTS)
    hold = jnp.where(agents == i, jnp.select([picked >= 0, drops], [picked, -1], h), s.hold)
    new_s = _World(cell=cell, hold=hold, plate_has=plate_has, knife_hold=knife_hold, chop=chop, deliv_hold=deliv_hold)
    ev = Events(
        chops=ev.chops + n_chops,
        wrong=ev.wrong + deliver_bad.astype(jnp.int32),
        correct=ev.correct + deliver_ok.astype(jnp.int32),
    )
    resolved = jnp.where(agents == i, ~defer, resolved | (swap & (agents == j)))
    return new_s, ev, resolved


def _retry_turn(s: _World, resolved, prim, i: int):
    """Agent ``i`` retries a move deferred in an earlier pass. Its target cell held a teammate, so
    it is floor: the agent walks in if it is free now, waits again if the teammate there has not
    moved yet, and gives up if it has (a swap would have happened in the first pass)."""
    me = s.cell[AGENT0_K + i]
    c = me + jnp.asarray(_DIR_FLAT)[prim[i]]
    at_c = s.cell[AGENT0_K:] == c
    waiting = jnp.any(at_c & ~resolved)
    walk = ~resolved[i] & ~jnp.any(at_c)
    moves = jnp.concatenate([_bundle(s, s.hold[i]), jnp.arange(N_ITEMS, s.cell.shape[0]) == AGENT0_K + i])
    return s.replace(cell=jnp.where(walk & moves, c, s.cell)), resolved | (~waiting & (jnp.arange(N_AGENTS) == i))


def physics(layout: Layout, s: OvercookedState, prim: chex.Array) -> tuple[OvercookedState, Events]:
    """Apply the joint primitive action ``prim`` (int32[3]) to the world (SPEC §5).

    Pass 1 gives every agent its full turn. Later passes only retry deferred moves, whose target
    cell is floor (it held an agent), so they are plain walks (``_retry_turn``). Three passes are
    what the original's loop amounts to (SPEC §5 bound); each pass is a loop over agents (a
    large unrolled body compiles slowly)."""
    zero = jnp.zeros((), jnp.int32)
    ev = Events(zero, zero, zero)
    resolved = jnp.zeros((N_AGENTS,), bool)
    full = s
    s = _World(s.pos[:, 0] * N + s.pos[:, 1], s.hold, s.plate_has, s.knife_hold, s.chop, s.deliv_hold)

    def first_pass(i, carry):
        s, ev, resolved = carry
        # An agent already resolved by a lower-index agent's swap has no turn of its own.
        new = _agent_turn(layout, s, ev, resolved | (jnp.arange(N_AGENTS) == i), prim, i)
        return jax.tree_util.tree_map(lambda old, x: jnp.where(resolved[i], old, x), carry, new)

    # A loop rather than three unrolled turns: the turn is large and compiling it once is 3× faster.
    s, ev, resolved = jax.lax.fori_loop(0, N_AGENTS, first_pass, (s, ev, resolved))
    s, resolved = jax.lax.fori_loop(
        0, 2 * N_AGENTS, lambda it, carry: _retry_turn(*carry, prim, it % N_AGENTS), (s, resolved)
    )
    return full.replace(
        pos=jnp.stack([s.cell // N, s.cell % N], axis=-1), hold=s.hold, plate_has=s.plate_has,
        knife_hold=s.knife_hold, chop=s.chop, deliv_hold=s.deliv_hold, prim=prim,
    ), ev
