"""Text rendering of one (unbatched) Overcooked state.

Legend: ``#`` counter, ``.`` floor, ``K1``/``K2`` knives, ``D`` delivery; foods ``t``/``l``/``o`` followed by
their chop count (``t3`` = chopped tomato); plates ``P1``/``P2`` followed by their foods in braces;
agents ``A1``..``A3`` followed by what they hold in brackets. Below the grid, one line per agent
with its macro-action and status.
"""

from __future__ import annotations

import numpy as np

from envs_jax.core import EnvState
from envs_jax.overcooked.layouts import AGENT0_K, DELIVERY, KNIFE, N_AGENTS, N_ITEMS, PLATE1_K, N

_FOOD = "tlo"

# What ``render`` prints, symbol by symbol: (symbol, meaning) pairs (``jaxmac rollout`` prints them).
RENDER_LEGEND = (
    ("#", "counter (items can be put on it)"),
    (".", "floor"),
    ("0..6", "row numbers x (left) and column numbers y (top): a cell is (x, y)"),
    ("K1 K2", "knife 1 / knife 2; an item lying on a knife follows it (K1t2)"),
    ("D", "delivery counter; an item on it follows it (DP1{lot})"),
    ("t l o", "tomato, lettuce, onion, followed by their chop count (t3 = chopped tomato)"),
    ("P1 P2", "plate 1 / plate 2"),
    ("P1{lt}", "a plate and, in braces, the foods on it (letters only)"),
    ("A1 A2 A3", "the agents"),
    ("A2[t3]", "an agent and, in brackets, what it holds (A2[P1{o}]: plate 1 with the onion on it)"),
    ("A1: ...", "an agent's macro-action, done or running, and its chop counter"),
)


def _item(core, k: int) -> str:
    if k < 3:
        return f"{_FOOD[k]}{int(core.chop[k])}"
    foods = "".join(_FOOD[f] for f in range(3) if core.plate_has[k - PLATE1_K, f])
    return f"P{k - 2}" + (f"{{{foods}}}" if foods else "")


def render(env, state: EnvState) -> str:
    core = state.core if hasattr(state, "core") else state
    core = type(core)(**{f: np.asarray(getattr(core, f)) for f in core.__dataclass_fields__})
    static = env.layout.static_grid
    cells = [["." if static[x, y] == 0 else "#" for y in range(N)] for x in range(N)]
    cells[1][0], cells[2][0] = "K1", "K2"
    for x in range(N):
        for y in range(N):
            if static[x, y] == DELIVERY:
                cells[x][y] = "D"
    held = {int(h) for h in core.hold if h >= 0}
    plated = {f for f in range(3) if core.plate_has[:, f].any()}
    for k in range(N_ITEMS):
        if k in held or k in plated:
            continue
        x, y = (int(v) for v in core.pos[k])
        base = cells[x][y]
        cells[x][y] = (base if static[x, y] in (KNIFE, DELIVERY) else "") + _item(core, k)
    for i in range(N_AGENTS):
        x, y = (int(v) for v in core.pos[AGENT0_K + i])
        h = int(core.hold[i])
        cells[x][y] = f"A{i + 1}" + (f"[{_item(core, h)}]" if h >= 0 else "")
    width = max(len(c) for row in cells for c in row) + 1
    lines = [("   " + "".join(str(y).ljust(width) for y in range(N))).rstrip()]
    lines += [f"{x}  " + "".join(c.ljust(width) for c in row).rstrip() for x, row in enumerate(cells)]
    if hasattr(state, "mac"):
        names = env.spec.action_names[0]
        mac, done = np.asarray(state.mac), np.asarray(state.mac_done)
        for i in range(N_AGENTS):
            m = names[int(mac[i])] if mac[i] >= 0 else "-"
            lines.append(f"A{i + 1}: {m} ({'done' if done[i] else 'running'}), chop counter {int(core.chop_ctr[i])}")
        lines.append(f"t = {int(state.t)}")
    return "\n".join(lines)
