"""Static description of the three Overcooked maps (SPEC §2, §8.1): grids, objects, macro lists.

Everything here is plain numpy / Python, built once per map at ``make`` time and closed over by
the jitted step. Cells are ``(x, y)`` = (row, column) on a 7×7 grid; a flat cell index is
``x * 7 + y``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

N = 7  # grid side
N_AGENTS = 3
N_OBJECTS = 11
N_ITEMS = 5  # movable items: tomato, lettuce, onion, plate 1, plate 2
N_FOODS = 3
RADIUS = 2  # default view radius (Chebyshev)

# Cell codes (SPEC §2.2).
FLOOR, COUNTER, AGENT, TOMATO, LETTUCE, PLATE, KNIFE, DELIVERY, ONION = range(9)

# Canonical object order (SPEC §2.1): index k -> name, cell code, initial cell (same on all maps).
OBJECT_NAMES = (
    "tomato", "lettuce", "onion", "plate1", "plate2", "knife1", "knife2", "delivery", "agent1", "agent2", "agent3",
)
OBJECT_CODES = np.array([TOMATO, LETTUCE, ONION, PLATE, PLATE, KNIFE, KNIFE, DELIVERY, AGENT, AGENT, AGENT], np.int32)
INIT_POS = np.array(
    [[0, 5], [1, 6], [2, 6], [5, 6], [6, 5], [1, 0], [2, 0], [3, 0], [1, 2], [1, 4], [5, 2]], np.int32
)
TOMATO_K, LETTUCE_K, ONION_K, PLATE1_K, PLATE2_K, KNIFE1_K, KNIFE2_K, DELIVERY_K = range(8)
AGENT0_K = 8
KNIFE_CELLS = INIT_POS[[KNIFE1_K, KNIFE2_K]]
DELIVERY_CELL = INIT_POS[DELIVERY_K]

# Primitive actions: index -> displacement (0 right, 1 down, 2 left, 3 up, 4 stay).
PRIM_NAMES = ("right", "down", "left", "up", "stay")
STAY = 4
DIRS = np.array([[0, 1], [1, 0], [0, -1], [-1, 0], [0, 0]], np.int32)

_ROWS = {
    "A": ("#####T#", "K.1.2.L", "K.....O", "D.....#", "#.....#", "#.3...P", "#####P#"),
    "B": ("#####T#", "K.1#2.L", "K..#..O", "D..#..#", "#..#..#", "#.3#..P", "#####P#"),
    "C": ("#####T#", "K.1#2.L", "K..#..O", "D..#..#", "#..#..#", "#.3...P", "#####P#"),
}
# Go-to-counter scan order of the middle-column rows (SPEC §8.2 rule 4); empty on map A.
_COUNTER_ROWS = {"A": (), "B": (3, 2, 4, 1, 5), "C": (3, 2, 4, 1)}
MAP_NAMES = tuple(_ROWS)

# Controller kinds of the macro-actions (SPEC §8.2).
K_STAY, K_GET, K_KNIFE, K_DELIVER, K_CHOP, K_COUNTER, K_DIR = range(7)


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """Static per-map data (numpy arrays; never traced).

    ``static_grid``   int32[7, 7]  codes of the fixed cells: counters 1, floor 0, knives 6, delivery 7
                                  (item spawn cells are counters).
    ``pm_background`` int32[7, 7]  background of the belief maps (SPEC §6): non-floor cells 1, floor 0.
    ``floor``         bool[7, 7]   walkable cells.
    ``counter_cells`` int32[C, 2]  go-to-counter candidates in scan order (C = 0 on map A).
    ``mac_kind``/``mac_obj``/``mac_dir`` int32[M]: per macro-action, controller kind, target object
                                  (−1 if none) and primitive direction (−1 if none).
    """

    name: str
    rows: tuple[str, ...]
    static_grid: np.ndarray
    pm_background: np.ndarray
    floor: np.ndarray
    counter_cells: np.ndarray
    action_names: tuple[str, ...]
    mac_kind: np.ndarray
    mac_obj: np.ndarray
    mac_dir: np.ndarray

    @property
    def num_actions(self) -> int:
        return len(self.action_names)


def build_layout(name: str) -> Layout:
    """Build the static data of map ``name`` ∈ {"A", "B", "C"}."""
    if name not in _ROWS:
        raise ValueError(f"unknown Overcooked map {name!r}; valid maps: {list(MAP_NAMES)}")
    rows = _ROWS[name]
    static = np.full((N, N), COUNTER, np.int32)
    for x, row in enumerate(rows):
        for y, ch in enumerate(row):
            static[x, y] = {".": FLOOR, "1": FLOOR, "2": FLOOR, "3": FLOOR, "K": KNIFE, "D": DELIVERY}.get(ch, COUNTER)
    floor = static == FLOOR
    # Consistency with the canonical object table: spawn cells are counters, agents start on floor.
    for k in range(N_OBJECTS):
        ch = rows[INIT_POS[k, 0]][INIT_POS[k, 1]]
        assert ch == "TLOPPKKD123"[k], (name, k, ch)
    pm_background = np.where(floor, FLOOR, COUNTER).astype(np.int32)
    counter_cells = np.array([[r, 3] for r in _COUNTER_ROWS[name]], np.int32).reshape(-1, 2)

    names = ["stay", "get tomato", "get lettuce", "get onion", "get plate 1", "get plate 2",
             "go to knife 1", "go to knife 2", "deliver", "chop"]
    kinds = [K_STAY, K_GET, K_GET, K_GET, K_GET, K_GET, K_KNIFE, K_KNIFE, K_DELIVER, K_CHOP]
    objs = [-1, TOMATO_K, LETTUCE_K, ONION_K, PLATE1_K, PLATE2_K, KNIFE1_K, KNIFE2_K, DELIVERY_K, -1]
    dirs = [-1] * 10
    if len(counter_cells):
        names.append("go to counter")
        kinds.append(K_COUNTER)
        objs.append(-1)
        dirs.append(-1)
    for d in range(4):
        names.append(PRIM_NAMES[d])
        kinds.append(K_DIR)
        objs.append(-1)
        dirs.append(d)
    return Layout(
        name=name,
        rows=rows,
        static_grid=static,
        pm_background=pm_background,
        floor=floor,
        counter_cells=counter_cells,
        action_names=tuple(names),
        mac_kind=np.array(kinds, np.int32),
        mac_obj=np.array(objs, np.int32),
        mac_dir=np.array(dirs, np.int32),
    )
