"""The controllers' path planner (SPEC §7): first move of an A*-style search, bit-exact.

The original runs a best-first search with a binary heap (Python ``heapq``) whose comparison is
*non-strict* on ``(f, p)``; ties between equally short paths are decided by the heap's internal
layout, so we emulate that heap exactly in a fixed 32-slot array (``plan_exact``). A search pushes
each passable cell at most once (≤ 25 interior cells), so the heap never exceeds 25 entries and
every sift loop needs at most 4 moves.

``plan_exact`` works on one agent's belief map; it is the specification. ``PlanTable`` (built at
``make`` time) precomputes its answer for every belief map without phantom items on the floor, and
``plan`` uses the table when that answer provably equals the search (see ``PlanTable``), falling
back to ``plan_exact`` otherwise.

Cells are flat indices ``x * 7 + y``. Inputs of the planner:
    passable bool[49]  belief-map code is floor (0) or agent (2)
    agent    bool[49]  belief-map code is agent (2): such entries carry ``p = 1``
    s, t     int32[]   start (the agent's cell) and target cells
Output: int32[] primitive action 0..3, or 4 (stay) when the search exhausts.
"""

from __future__ import annotations

import heapq

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.overcooked.layouts import N

N_CELLS = N * N
HEAP_SLOTS = 32
SIFT_STEPS = 4  # depth of a 25-entry binary heap
NO_FIRST = 7  # "first move not defined yet" (the start entry)
# Expansion order right, left, down, up (SPEC §7): flat offsets and their primitive indices.
EXPAND_OFFSETS = (1, -1, N, -N)
EXPAND_PRIMS = (0, 2, 1, 3)

_CX = np.arange(N_CELLS) // N
_CY = np.arange(N_CELLS) % N
_CELLS = np.arange(N_CELLS)
_SLOTS = np.arange(HEAP_SLOTS)


# A heap entry is one int32: key << 9 | cell << 3 | first, with key = 2 f + p (f = g + h ≤ 64).
# Only the key takes part in comparisons; g is recovered as f - h(cell).
def _pack(key, cell, first):
    return (key << 9) | (cell << 3) | first


def _key(entry):
    return entry >> 9


def _cell(entry):
    return (entry >> 3) & 63


def _first(entry):
    return entry & 7


def _precedes(a, b):
    """heapq's ``a < b`` for the original's entries: (f, p) compared non-strictly."""
    return _key(a) <= _key(b)


def _sift_up(heap, pos, item, enable):
    """heapq ``_siftdown``: move ``item`` from slot ``pos`` towards the root past every parent it
    precedes, then store it (all only if ``enable``). Re-testing an unmoved slot gives the same
    answer, so a fixed number of masked steps reproduces the loop with its ``break``."""

    def step(_, carry):
        heap, pos = carry
        parent = jnp.maximum(pos - 1, 0) >> 1
        parent_item = heap[parent]
        move = enable & (pos > 0) & _precedes(item, parent_item)
        heap = jnp.where(move & (_SLOTS == pos), parent_item, heap)
        return heap, jnp.where(move, parent, pos)

    heap, pos = jax.lax.fori_loop(0, SIFT_STEPS, step, (heap, pos))
    return jnp.where(enable & (_SLOTS == pos), item, heap)


def _pop(heap, size):
    """heapq ``heappop``: returns (entry, heap, size). Requires size ≥ 1."""
    size = size - 1
    last = heap[size]
    root = heap[0]

    # Move the hole at the root down to a leaf, always promoting the child that precedes
    # (the left one unless the right one exists and the left does not precede it).
    def step(_, carry):
        heap, pos = carry
        left = 2 * pos + 1
        right = left + 1
        left_item = heap[jnp.minimum(left, HEAP_SLOTS - 1)]
        right_item = heap[jnp.minimum(right, HEAP_SLOTS - 1)]
        use_right = (right < size) & ~_precedes(left_item, right_item)
        move = left < size
        heap = jnp.where(move & (_SLOTS == pos), jnp.where(use_right, right_item, left_item), heap)
        return heap, jnp.where(move, jnp.where(use_right, right, left), pos)

    heap, pos = jax.lax.fori_loop(0, SIFT_STEPS, step, (heap, jnp.zeros_like(size)))
    # Put the former last entry into the hole and sift it back up.
    heap = _sift_up(heap, pos, last, True)
    return jnp.where(size == 0, last, root), heap, size


def search(
    passable: jax.Array, agent: jax.Array, s: jax.Array, t: jax.Array, enabled: jax.Array | bool = True
) -> tuple[jax.Array, jax.Array]:
    """The original planner's search (SPEC §7) from ``s`` towards ``t``.

    Returns (first primitive move, bool[49] cells pushed on the heap). ``enabled=False`` skips the
    search (returns 4 without iterating), for callers that plan for several agents but need only
    some answers."""
    s = jnp.asarray(s, jnp.int32)
    t = jnp.asarray(t, jnp.int32)
    cx, cy = jnp.asarray(_CX, jnp.int32), jnp.asarray(_CY, jnp.int32)
    h = jnp.abs(cx - t // N) + jnp.abs(cy - t % N)  # i32[49] Manhattan heuristic
    # Each expansion can only generate the target or cells inside the grid (the start is a floor
    # cell and border cells are never passable), so no bounds checks are needed.
    heap = jnp.where(_SLOTS == 0, _pack(2 * h[s], s, NO_FIRST), 0)
    seen = _CELLS == s
    skip = ~jnp.asarray(enabled, bool)
    init = (heap, jnp.ones((), jnp.int32), seen, skip, jnp.full((), 4, jnp.int32))

    def cond(carry):
        _, size, _, found, _ = carry
        return ~found & (size > 0)

    offsets, prims = jnp.asarray(EXPAND_OFFSETS), jnp.asarray(EXPAND_PRIMS)

    def body(carry):
        heap, size, seen, found, result = carry
        entry, heap, size = _pop(heap, size)
        cell, first = _cell(entry), _first(entry)
        g = (_key(entry) >> 1) - h[cell]

        def expand(d, carry):  # neighbour d in the order right, left, down, up
            heap, size, seen, found, result = carry
            n = cell + offsets[d]
            fresh = ~found & ~seen[n]
            first_n = jnp.where(first == NO_FIRST, prims[d], first)
            push = fresh & passable[n]
            key = 2 * (g + 1 + h[n]) + agent[n].astype(jnp.int32)
            heap = _sift_up(heap, size, _pack(key, n, first_n), push)
            seen = seen | (push & (_CELLS == n))
            hit = fresh & (n == t)
            return heap, size + push.astype(jnp.int32), seen, found | hit, jnp.where(hit, first_n, result)

        return jax.lax.fori_loop(0, len(EXPAND_OFFSETS), expand, (heap, size, seen, found, result))

    _, _, seen, _, result = jax.lax.while_loop(cond, body, init)
    return result, seen & (_CELLS != s)


def plan_exact(
    passable: jax.Array, agent: jax.Array, s: jax.Array, t: jax.Array, enabled: jax.Array | bool = True
) -> jax.Array:
    """First primitive move from ``s`` towards ``t`` exactly as the original planner (SPEC §7)."""
    return search(passable, agent, s, t, enabled)[0]


# ------------------------------------------------------------------------------------------
# Reference implementation in plain Python (tests only): the same search with ``heapq``.


class _Entry:
    __slots__ = ("cell", "f", "first", "g", "p")

    def __init__(self, f, p, cell, first, g):
        self.f, self.p, self.cell, self.first, self.g = f, p, cell, first, g

    def __lt__(self, other):  # non-strict on purpose (SPEC §7)
        return self.f < other.f or (self.f == other.f and self.p <= other.p)


def plan_reference(pm: np.ndarray, s: tuple[int, int], t: tuple[int, int]) -> int:
    """Plain-Python planner on a 7×7 belief map (codes); used to test ``plan_exact``."""
    pm = np.asarray(pm)

    def h(c):
        return abs(c[0] - t[0]) + abs(c[1] - t[1])

    seen = np.zeros(pm.shape, bool)
    seen[s] = True
    heap = [_Entry(h(s), 0, tuple(s), None, 0)]
    while heap:
        e = heapq.heappop(heap)
        for (dx, dy), prim in zip(((0, 1), (0, -1), (1, 0), (-1, 0)), EXPAND_PRIMS):
            n = (e.cell[0] + dx, e.cell[1] + dy)
            if not (0 <= n[0] < pm.shape[0] and 0 <= n[1] < pm.shape[1]) or seen[n]:
                continue
            first = e.first if e.first is not None else prim
            if pm[n] in (0, 2):
                heapq.heappush(heap, _Entry(e.g + 1 + h(n), int(pm[n] == 2), n, first, e.g + 1))
                seen[n] = True
            if n == tuple(t):
                return first
    return 4
