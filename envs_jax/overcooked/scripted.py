"""A jittable scripted policy that cooks and delivers the salad on maps A, B and C.

``scripted_actions(env, state) -> int32[3]`` reads the true state (and the agents' beliefs, so
that it never sends an agent after an item it does not know about) and returns a macro-action
for every agent; entries of busy agents are ignored by the env. It is reactive: decisions are
re-taken whenever an agent is free, and agents are decided one after the other (``lax.scan``
over agents) so that later ones see what earlier ones just claimed.

Protocol:
* map A (open room): an empty-handed agent fetches an unclaimed food when a knife is (or will
  be) free for it, puts it on an empty knife and chops it; an agent with nothing else to do
  fetches plate 1 and collects every chopped food (choppers leave or step aside), then
  delivers. Idle agents step aside when a teammate walks into them (the planner ignores agents
  and macro-actions never time out, so an idle agent on a path would block it for good), and
  agents walk towards items they cannot see yet;
* maps B and C (split by the counter column): agent 2 (the runner, on the food side) carries the
  tomato, the lettuce, plate 1 and the onion to the middle counters; agents 1 and 3 run the
  map-A protocol on what lies on the counters. On C nobody uses the opening.

Used as the learning ceiling in the report and checked by ``tests/test_overcooked.py``.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

from envs_jax.core import EnvState
from envs_jax.overcooked.layouts import AGENT0_K, DIRS, KNIFE_CELLS, N_AGENTS, N_FOODS, N_ITEMS, PLATE1_K
from envs_jax.overcooked.world import belief_maps

RUNNER = 1  # agent 2 carries things across the counter on maps B/C
RUNNER_ORDER = (0, 1, PLATE1_K, 2)  # tomato, lettuce, plate 1, onion


def scripted_actions(env, state: EnvState) -> chex.Array:
    """Macro-actions (int32[3]) for every agent; only free agents' entries matter."""
    core = state.core
    names = env.layout.action_names
    ids = {name: i for i, name in enumerate(names)}
    split = "go to counter" in ids
    get_item = jnp.array([ids["get tomato"], ids["get lettuce"], ids["get onion"], ids["get plate 1"], ids["get plate 2"]])
    go_knife = jnp.array([ids["go to knife 1"], ids["go to knife 2"]])
    right, left, up, down = ids["right"], ids["left"], ids["up"], ids["down"]
    stay, chop_m, deliver = ids["stay"], ids["chop"], ids["deliver"]

    me_all = core.pos[AGENT0_K:]
    dirs = jnp.asarray(DIRS)
    dir_macro = jnp.array([ids["right"], ids["down"], ids["left"], ids["up"]])
    pm = belief_maps(env.layout, core)
    items = jnp.arange(N_ITEMS)
    held_by = jnp.max(jnp.where(core.hold[None, :] == items[:, None], jnp.arange(N_AGENTS)[None, :], -1), axis=1)
    on_knife = jnp.max(jnp.where(core.knife_hold[None, :] == items[:, None], jnp.arange(2)[None, :], -1), axis=1)
    plated = jnp.concatenate([jnp.any(core.plate_has, axis=0), jnp.zeros((2,), bool)])
    chopped = jnp.concatenate([core.chop == 3, jnp.zeros((2,), bool)])
    delivered = core.deliv_hold >= 0
    loose = (held_by < 0) & (on_knife < 0) & ~plated  # lying on a counter
    knife_content = core.knife_hold
    knife_food = (knife_content >= 0) & (knife_content < N_FOODS)
    knife_unchopped = knife_food & (core.chop[jnp.clip(knife_content, 0, N_FOODS - 1)] < 3)
    knife_chopped = knife_food & ~knife_unchopped
    access = jnp.asarray(KNIFE_CELLS) + jnp.array([0, 1])  # the floor cell next to each knife
    at_access = jnp.all(me_all[:, None, :] == access[None], -1)  # [3 agents, 2 knives]
    plate_holder = jnp.any(core.hold >= PLATE1_K)
    # Busy agents' running macro-actions count as claims.
    busy = ~state.mac_done
    running = jnp.where(busy, state.mac, -1)
    claim_item = jnp.any(running[:, None] == get_item[None, :], axis=0) | (held_by >= 0)
    claim_knife = jnp.any(running[:, None] == go_knife[None, :], axis=0)

    def reachable(i, k):
        """Item k is for agent i: on B/C the runner serves the food side, the others the kitchen side."""
        if not split:
            return jnp.ones_like(k, bool)
        y = core.pos[k, 1]
        return jnp.where(i == RUNNER, y >= 4, y <= 3)

    def decide(carry, i):
        claim_item, claim_knife = carry
        me = me_all[i]
        h = core.hold[i]
        knows = jnp.all(core.belief[i, :N_ITEMS] == core.pos[:N_ITEMS], -1)  # [5]
        ok_item = loose & ~claim_item & knows & reachable(i, items)
        free_knife = (knife_content < 0) & ~claim_knife
        k_free = jnp.argmax(free_knife)
        any_free_knife = jnp.any(free_knife)
        my_access = at_access[i]
        in_corridor = jnp.any(my_access) | jnp.all(me == jnp.array([3, 1]))

        def look_at(k):
            """Direction macro towards item k, to bring it into view: a free neighbouring cell
            that gets closer (rows first)."""
            dx, dy = core.pos[k, 0] - me[0], core.pos[k, 1] - me[1]
            free = pm[i, (me[0] + dirs[:4, 0]) * 7 + me[1] + dirs[:4, 1]] == 0  # right, down, left, up
            options = jnp.array([dx < 0, dx > 0, dy < -1, dy > 1]) & free[jnp.array([3, 1, 2, 0])]
            return jnp.where(jnp.any(options), jnp.array([up, down, left, right])[jnp.argmax(options)], stay)

        # Holding something.
        h_food = (h >= 0) & (h < N_FOODS)
        h_chopped = h_food & chopped[jnp.clip(h, 0, N_ITEMS - 1)]
        plate = jnp.clip(h - PLATE1_K, 0, 1)
        plate_full = jnp.all(core.plate_has[plate])
        to_collect = chopped & ~plated & (held_by < 0) & knows
        f_collect = jnp.argmax(to_collect)
        loose_plate = loose & (items >= PLATE1_K) & knows & reachable(i, items)
        p_get = jnp.argmax(loose_plate)
        unseen_chopped = chopped & ~plated & (held_by < 0) & ~knows
        a_hold = jnp.select(
            [
                h_food & ~h_chopped & any_free_knife,
                h_chopped & jnp.any(loose_plate),
                (h >= PLATE1_K) & plate_full,
                (h >= PLATE1_K) & jnp.any(to_collect),
                (h >= PLATE1_K) & jnp.any(unseen_chopped),
                in_corridor,
            ],
            [go_knife[k_free], get_item[p_get], deliver, get_item[f_collect], look_at(jnp.argmax(unseen_chopped)), right],
            stay,
        )

        # Empty-handed.
        chop_here = jnp.any(my_access & knife_unchopped)
        take_here = my_access & knife_chopped
        unattended = knife_unchopped & ~jnp.any(at_access, axis=0) & ~claim_knife
        k_unatt = jnp.argmax(unattended)
        food_ok = ok_item & (items < N_FOODS) & ~chopped
        f_get = jnp.argmax(food_ok)
        # Fetch a food only for a knife that is (or will be, once its chopped food is collected)
        # free and not already promised to a food in someone's hands or on its way.
        slots = jnp.sum((knife_content < 0) | knife_chopped)
        demand = jnp.sum(claim_item[:N_FOODS] & ~chopped[:N_FOODS] & (on_knife[:N_FOODS] < 0))
        fetch = jnp.any(food_ok) & (slots > demand)
        want_plate = ~plate_holder & ~jnp.any(claim_item[PLATE1_K:]) & jnp.any(loose_plate)
        # A food or plate we cannot see yet (stale belief): walk towards its row.
        wanted = loose & ~claim_item & reachable(i, items) & ~knows & ((items < N_FOODS) & ~chopped | (items >= PLATE1_K))
        look = look_at(jnp.argmax(wanted))
        a_empty = jnp.select(
            [
                chop_here,
                fetch,
                jnp.any(take_here) & plate_holder,  # chopped food waits for the plate: make room
                jnp.any(take_here) & want_plate,
                jnp.any(take_here),
                jnp.any(unattended),
                want_plate,
                jnp.any(wanted) & ~delivered,
                in_corridor,
            ],
            [chop_m, get_item[f_get], right, get_item[p_get], stay, go_knife[k_unatt], get_item[p_get], look, right],
            stay,
        )
        a = jnp.where(h >= 0, a_hold, a_empty)
        # Make way: a teammate walked into us last step (the planner ignores agents and macro-actions
        # never time out, so an idle agent on someone's path would block it forever).
        pushed = jnp.any(jnp.all(me_all + dirs[core.prim] == me, -1) & (core.prim < 4))
        side = me + dirs[:4]
        side_free = pm[i, side[:, 0] * 7 + side[:, 1]] == 0
        a = jnp.where(pushed & jnp.any(side_free), dir_macro[jnp.argmax(side_free)], a)
        if split:
            # Runner: tomato, lettuce, plate 1, onion (the third food waits for a knife anyway).
            runner_food = loose & ~claim_item & reachable(i, items) & ((items < N_FOODS) | (items == PLATE1_K))
            first = jnp.argmax(runner_food[jnp.asarray(RUNNER_ORDER)])
            a_runner = jnp.where(
                h >= 0, ids["go to counter"], jnp.where(jnp.any(runner_food), get_item[jnp.asarray(RUNNER_ORDER)[first]], stay)
            )
            a = jnp.where(i == RUNNER, a_runner, a)
        a = jnp.where(state.mac_done[i], a, state.mac[i])
        # Claims for the agents decided after this one.
        claim_item = claim_item | (get_item == a)
        claim_knife = claim_knife | (go_knife == a)
        return (claim_item, claim_knife), a

    _, actions = jax.lax.scan(decide, (claim_item, claim_knife), jnp.arange(N_AGENTS))
    return actions.astype(jnp.int32)
