"""Fast, exact planner: a per-map table of search answers plus the search as a fallback.

The planner's input is a belief map, but on these maps a belief map can only differ from the
static layout in two ways (SPEC §6): cells holding an agent (the own cell ``s`` and the believed
cells ``a``, ``b`` of the two teammates; passable, ``p = 1``) and floor cells holding a *phantom*
item (an item believed to lie on the floor; impassable). So the search is a function of
``(s, t, {a, b}, blocked)``.

``build_table`` runs the exact search (``planner.search``) once per ``(s, t, {a, b})`` with no
blocked cell and stores its first move together with the set of cells it pushed. With blocked
cells, the search takes exactly the same course as long as it never pushes a blocked cell, so a
table answer is valid iff ``pushed ∩ blocked = ∅``; otherwise (rare: a phantom item on the
search's frontier) we run the search itself. Under ``vmap`` the fallback searches are gathered into
small chunks (``jax.custom_batching.custom_vmap``), so their cost does not scale with the batch.

Building uses the fact that a teammate cell only matters if the search pushes it: answers without
teammates, then with one, then the pairs that still need their own search (~110k searches on
map A; a few seconds per map, once per process; the table is 0.8–1.6 MB).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.overcooked import planner
from envs_jax.overcooked.layouts import N, build_layout

N_CELLS = N * N
_BUILD_CHUNK = 8192


@dataclasses.dataclass(frozen=True, eq=False)
class PlanTable:
    """Planner answers for belief maps without phantom items (numpy, static).

    ``floor_cells``  int32[F]      flat indices of the floor cells (F ≤ 25)
    ``floor_index``  int32[49]     flat cell -> index into ``floor_cells`` or −1
    ``entries``      int32[F*49*P] entry of (s, t, pair{a, b}): ``pushed_bits << 3 | first_move``,
                                   pushed bits over floor indices, P = F (F + 1) / 2 unordered pairs
    """

    floor_cells: np.ndarray
    floor_index: np.ndarray
    entries: np.ndarray

    @property
    def n_floor(self) -> int:
        return len(self.floor_cells)


def pair_index(lo, hi, n_floor: int):
    """Index of the unordered pair {lo, hi} (lo ≤ hi) among the F (F + 1) / 2 pairs."""
    return lo * n_floor - lo * (lo - 1) // 2 + (hi - lo)


@jax.jit
def _search_chunk(passable, agent, s, t):
    return jax.vmap(planner.search, in_axes=(None, 0, 0, 0))(passable, agent, s, t)


def _run(floor49: np.ndarray, s: np.ndarray, t: np.ndarray, agents: np.ndarray):
    """Exact searches for lanes (s, t, agent cells[..., k]); returns (first, pushed bool[49])."""
    n = len(s)
    firsts, pushed = [], []
    for lo in range(0, n, _BUILD_CHUNK):
        sl = slice(lo, min(n, lo + _BUILD_CHUNK))
        m = sl.stop - sl.start
        agent = np.zeros((_BUILD_CHUNK, N_CELLS), bool)
        rows = np.arange(m)[:, None]
        agent[rows, np.concatenate([s[sl, None], agents[sl]], axis=1)] = True
        pad = (0, _BUILD_CHUNK - m)
        f, p = _search_chunk(floor49, agent, np.pad(s[sl], pad), np.pad(t[sl], pad))
        firsts.append(np.asarray(f)[:m])
        pushed.append(np.asarray(p)[:m])
    return np.concatenate(firsts), np.concatenate(pushed)


@functools.cache
def build_table(map_name: str) -> PlanTable:
    """Table of map ``map_name`` (cached per process)."""
    layout = build_layout(map_name)
    floor49 = layout.floor.reshape(-1)
    cells = np.flatnonzero(floor49).astype(np.int32)
    F = len(cells)
    index = np.full(N_CELLS, -1, np.int32)
    index[cells] = np.arange(F)
    to_bits = lambda pushed: (pushed[..., cells].astype(np.int64) << np.arange(F)).sum(-1)

    # No teammate on the search's way: (s, t).
    si, t = (g.reshape(-1) for g in np.meshgrid(np.arange(F), np.arange(N_CELLS), indexing="ij"))
    r0, p0 = _run(floor49, cells[si], t, np.zeros((len(si), 0), np.int32))
    r0, p0 = r0.reshape(F, N_CELLS), p0[:, cells].reshape(F, N_CELLS, F)
    # One teammate: (s, t, a).
    si, t, ai = (g.reshape(-1) for g in np.meshgrid(np.arange(F), np.arange(N_CELLS), np.arange(F), indexing="ij"))
    r1, p1 = _run(floor49, cells[si], t, cells[ai][:, None])
    r1, p1 = r1.reshape(F, N_CELLS, F), p1[:, cells].reshape(F, N_CELLS, F, F)

    # Every (s, t, {a, b}), a ≤ b: reuse the 0/1-teammate search when the other teammate is
    # never pushed by it.
    lo, hi = np.triu_indices(F)
    si, t, pi = (g.reshape(-1) for g in np.meshgrid(np.arange(F), np.arange(N_CELLS), np.arange(len(lo)), indexing="ij"))
    a, b = lo[pi], hi[pi]
    in_a, in_b = p0[si, t, a], p0[si, t, b]
    use0 = ~in_a & ~in_b
    use_a = ~use0 & in_a & ((a == b) | ~p1[si, t, a, b])
    use_b = ~use0 & ~use_a & in_b & ~p1[si, t, b, a]
    first = np.where(use0, r0[si, t], np.where(use_a, r1[si, t, a], r1[si, t, b]))
    bits0 = (p0.astype(np.int64) << np.arange(F)).sum(-1)  # [F, 49]
    bits1 = (p1.astype(np.int64) << np.arange(F)).sum(-1)  # [F, 49, F]
    bits = np.where(use0, bits0[si, t], np.where(use_a, bits1[si, t, a], bits1[si, t, b]))
    # Pairs whose searches push both teammates: search them.
    need = ~(use0 | use_a | use_b)
    r2, p2 = _run(floor49, cells[si[need]], t[need], np.stack([cells[a[need]], cells[b[need]]], 1))
    first[need] = r2
    bits[need] = to_bits(p2)
    entries = ((bits << 3) | first).astype(np.int32)
    return PlanTable(floor_cells=cells, floor_index=index, entries=entries)


def _chunk(lanes: int) -> int:
    """Lanes searched together by the fallback: ~0.5% of the lanes, 4..64. In random play a search
    must run for ~0.4% (map A) to ~0.8% (map C) of the planning agents (a phantom item on the
    search's frontier); more lanes than a chunk just take another round."""
    return int(min(64, max(4, lanes // 192)))


def planner_masks(floor: np.ndarray, s, mates, items):
    """(passable, agent) bool[49] of one agent's belief map, from its compact description: own
    cell ``s``, teammates' believed cells ``mates`` [2], items' believed cells ``items`` [5] (all
    flat). Items make floor cells impassable unless an agent is believed there too (SPEC §6)."""
    cells = jnp.arange(N_CELLS)
    agent = (cells == s) | jnp.any(cells[:, None] == mates[None, :], axis=1)
    item = jnp.any(cells[:, None] == items[None, :], axis=1)
    return jnp.asarray(floor.reshape(-1)) & (~item | agent), agent


def make_exact_planner(floor: np.ndarray):
    """``plan(s, t, mates, items, enabled)`` for the 3 agents by the search alone (reference)."""

    def one(s, t, mates, items, enabled):
        return planner.plan_exact(*planner_masks(floor, s, mates, items), s, t, enabled)

    return jax.vmap(one)


def make_planner(table: PlanTable, floor: np.ndarray):
    """The controllers' planner: ``plan(s, t, mates, items, enabled)`` for the 3 agents.

    Args (leading axis = agents, flat cells): ``s``/``t`` int32[3] own and target cells,
    ``mates`` int32[3, 2] the teammates' believed cells, ``items`` int32[3, 5] the believed cells
    of the five movable items, ``enabled`` bool[3] (who needs an answer). Returns int32[3] first
    moves, identical to ``planner.plan_exact`` on the agents' belief maps wherever ``enabled``.
    """
    entries = jnp.asarray(table.entries)
    findex = jnp.asarray(table.floor_index)
    n_floor = table.n_floor
    n_pairs = n_floor * (n_floor + 1) // 2

    def exact(s, t, mates, items, enabled):  # one lane
        return planner.plan_exact(*planner_masks(floor, s, mates, items), s, t, enabled)

    def lookup(s, t, mates, items):
        """Table answer and whether it is valid, for lanes [L]."""
        si, a, b = findex[s], findex[mates[:, 0]], findex[mates[:, 1]]
        lo, hi = jnp.minimum(a, b), jnp.maximum(a, b)
        idx = (jnp.maximum(si, 0) * N_CELLS + t) * n_pairs + pair_index(jnp.maximum(lo, 0), jnp.maximum(hi, 0), n_floor)
        entry = entries[idx]
        # Phantom items: believed on a floor cell where no agent is believed.
        fi = findex[items]  # [L, 5]
        under_agent = (items == s[:, None]) | (items == mates[:, :1]) | (items == mates[:, 1:])
        bit = jnp.where((fi >= 0) & ~under_agent, jnp.left_shift(1, jnp.maximum(fi, 0)), 0)
        blocked = jax.lax.reduce(bit, np.int32(0), jax.lax.bitwise_or, (1,))
        ok = (si >= 0) & (lo >= 0) & ((entry >> 3) & blocked == 0)
        return entry & 7, ok

    def plan_lanes(s, t, mates, items, enabled):
        first, ok = lookup(s, t, mates, items)
        need = enabled & ~ok
        slow = jax.vmap(exact)(s, t, mates, items, need)
        return jnp.where(need, slow, first)

    def plan_compact(s, t, mates, items, enabled):
        """Like ``plan_lanes`` for many lanes, searching only the lanes that need it, in chunks."""
        first, ok = lookup(s, t, mates, items)
        need = enabled & ~ok
        lanes = s.shape[0]
        chunk = _chunk(lanes)
        n_need = jnp.sum(need)
        order = jnp.nonzero(need, size=lanes + chunk, fill_value=lanes)[0]  # lanes needing a search first

        def body(carry):
            c, out = carry
            sel = jax.lax.dynamic_slice(order, (c * chunk,), (chunk,))
            take = lambda x: x.at[sel].get(mode="fill", fill_value=0)
            res = jax.vmap(exact)(take(s), take(t), take(mates), take(items), sel < lanes)
            return c + 1, out.at[sel].set(res, mode="drop")

        _, out = jax.lax.while_loop(lambda carry: carry[0] * chunk < n_need, body, (jnp.zeros((), jnp.int32), first))
        return out

    @jax.custom_batching.custom_vmap
    def plan(s, t, mates, items, enabled):
        return plan_lanes(s, t, mates, items, enabled)

    @plan.def_vmap
    def _plan_batched(axis_size, in_batched, s, t, mates, items, enabled):
        args = [
            x if batched else jnp.broadcast_to(x, (axis_size, *x.shape))
            for x, batched in zip((s, t, mates, items, enabled), in_batched)
        ]
        lanes = [x.reshape(-1, *x.shape[2:]) for x in args]
        return plan_compact(*lanes).reshape(axis_size, -1), True

    return plan
