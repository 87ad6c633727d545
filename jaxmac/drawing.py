"""Pictures of env states: one state of Box Pushing, Overcooked or Warehouse drawn on a matplotlib ``Axes``.

    from matplotlib.figure import Figure
    fig = Figure(figsize=(4, 4)); ax = fig.subplots()
    draw_state(env, state, ax)                 # grid, walls/counters, agents (coloured, numbered), items, legend
    fig.savefig("state.png")

``state`` is one unbatched ``EnvState`` (device or numpy leaves). Every agent is a patch with gid ``"agent"``
(``agent_patches(ax)`` finds them). Helpers lay out several states as a grid of panels (``frames_figure``) or write
them as a GIF (``write_gif``, matplotlib's ``PillowWriter``).

Only ``matplotlib.figure.Figure`` objects are used: importing or calling this module never imports pyplot nor
switches matplotlib's global backend (a notebook's inline plots keep working). The env packages stay free of
matplotlib; the drawing of each family lives here, beside the others.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

# Agents: strong colours, numbered in white; items use other hues (food red/green/gold, boxes brown).
AGENT_COLOURS = ("#1f77b4", "#ff7f0e", "#7b3fb0", "#0f8f8f", "#c2185b", "#555555")
AGENT_GID = "agent"


def agent_colour(i: int) -> str:
    return AGENT_COLOURS[i % len(AGENT_COLOURS)]


def agent_patches(ax) -> list:
    """The agent markers drawn on ``ax`` (one per agent)."""
    return [p for p in ax.patches if p.get_gid() == AGENT_GID]


def agent_labels(env) -> tuple[str, ...]:
    """How the picture (and the env's text rendering) numbers the agents."""
    kind = _family(env)
    n = env.spec.num_agents
    if kind == "overcooked":
        return tuple(f"A{i + 1}" for i in range(n))
    if kind == "warehouse":
        return tuple(str(i) for i in range(n - 1)) + ("F",)
    return tuple(str(i) for i in range(n))


def draw_state(env, state, ax, legend: bool = True, fontsize: float = 7.0) -> list[tuple[Any, str]]:
    """Draw one state of ``env`` on ``ax`` (its contents are replaced) and return the legend entries
    ``[(handle, label)]``; with ``legend`` they are shown beside the axes."""
    import jax

    state = jax.device_get(state)
    ax.clear()
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)
    entries = _DRAWERS[_family(env)](env, state, ax, fontsize)
    if legend:
        ax.legend(*zip(*entries), loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=fontsize,
                  frameon=False, borderaxespad=0.0, handlelength=1.4)
    return entries


def state_figure(env, state, title: str | None = None, legend: bool = True):
    """A ``Figure`` with one drawn state (and its legend on the right)."""
    from matplotlib.figure import Figure  # its own Agg canvas: never touches pyplot's backend or figure list

    w, h = panel_inches(env)
    fig = Figure(figsize=(w + (2.6 if legend else 0.3), h + 0.6), dpi=100, layout="constrained")
    ax = fig.subplots()
    draw_state(env, state, ax, legend=legend)
    if title:
        ax.set_title(title, fontsize=8)
    return fig


def frames_figure(env, states: Sequence[Any], titles: Sequence[str], captions: Sequence[str] | None = None,
                  cols: int = 4, dpi: int = 100, title: str | None = None):
    """The states side by side in a grid of panels (``cols`` per row), each titled, with a caption under it, one
    legend for all of them at the bottom and ``title`` (lines) at the top."""
    from matplotlib.figure import Figure

    n = len(states)
    cols = max(1, min(cols, n))
    rows = -(-n // cols)
    w, h = panel_inches(env)
    top = 0.2 * (title.count("\n") + 1) if title else 0.0
    fig = Figure(figsize=(cols * (w + 0.25), rows * (h + 0.75) + 0.9 + top), dpi=dpi, layout="constrained")
    if title:
        fig.suptitle(title, fontsize=8)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    entries = []
    for k, ax in enumerate(axes):
        if k >= n:
            ax.axis("off")
            continue
        entries = draw_state(env, states[k], ax, legend=False)
        ax.set_title(titles[k], fontsize=8)
        if captions is not None:
            ax.set_xlabel(captions[k], fontsize=6)
    if entries:
        fig.legend(*zip(*entries), loc="outside lower center", ncol=min(len(entries), 5), fontsize=7,
                   frameon=False, handlelength=1.4)
    return fig


def write_gif(env, states: Sequence[Any], titles: Sequence[str], path: str, captions: Sequence[str] | None = None,
              fps: float = 2.0, dpi: int = 110, note: str | None = None) -> int:
    """One GIF frame per state (matplotlib's ``PillowWriter``), each titled (and captioned), ``note`` at the
    bottom; returns the number of frames written."""
    from matplotlib.animation import PillowWriter
    from matplotlib.figure import Figure

    w, h = panel_inches(env)
    width = w + 2.6
    lines = [part for line in (note or "").splitlines() for part in textwrap.wrap(line, int(width * 72 / 3.8))]
    below = 0.45 + 0.12 * len(lines)  # inches under the axes: caption, then the note
    height = h + 0.4 + below
    fig = Figure(figsize=(width, height), dpi=dpi)
    ax = fig.add_axes((0.3 / width, below / height, w / width, h / height))
    if lines:
        fig.text(0.5, 0.04 / height, "\n".join(lines), ha="center", va="bottom", fontsize=6.5, color="#444444")
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, path, dpi):
        for k, state in enumerate(states):
            draw_state(env, state, ax, legend=True)
            ax.set_title(titles[k], fontsize=9)
            if captions is not None:
                ax.set_xlabel(captions[k], fontsize=7)
            writer.grab_frame()
    return len(states)


def panel_inches(env) -> tuple[float, float]:
    """Width and height of one drawn state, in inches (the grid's aspect ratio)."""
    if _family(env) == "warehouse":
        width, height = _warehouse_extent(env)
        return 1.9 * width / height, 1.9
    return 2.4, 2.4


# --- the three families ------------------------------------------------------------------------------------------


def _family(env) -> str:
    from envs_jax.boxpushing import BoxPushing
    from envs_jax.overcooked.env import Overcooked
    from envs_jax.warehouse.env import WarehouseEnv

    for cls, name in ((BoxPushing, "boxpushing"), (Overcooked, "overcooked"), (WarehouseEnv, "warehouse")):
        if isinstance(env, cls):
            return name
    raise ValueError(f"no picture for {type(env).__name__} ({env.spec.name}); drawn families: Box Pushing, "
                     "Overcooked, Warehouse")


def _agent(ax, xy, i: int, label: str, radius: float, fontsize: float, shape: int = 0) -> None:
    """Agent ``i``: a circle (or a ``shape``-gon) in its colour with its number."""
    from matplotlib.patches import Circle, RegularPolygon

    style = {"fc": agent_colour(i), "ec": "black", "lw": 0.8, "zorder": 5, "gid": AGENT_GID}
    patch = RegularPolygon(xy, shape, radius=radius, **style) if shape else Circle(xy, radius, **style)
    ax.add_patch(patch)
    ax.text(xy[0], xy[1], label, ha="center", va="center", color="white", fontsize=fontsize, fontweight="bold",
            zorder=6)


def _marker(marker: str, colour: str, label: str, size: float = 7, edge: str = "black"):
    from matplotlib.lines import Line2D

    return Line2D([], [], ls="none", marker=marker, ms=size, mfc=colour, mec=edge, mew=0.7), label


def _patch(colour: str, label: str, edge: str = "black", hatch: str | None = None):
    from matplotlib.patches import Patch

    return Patch(fc=colour, ec=edge, lw=0.7, hatch=hatch), label


def _agent_entries(env, shape_of: Callable[[int], str] = lambda i: "o") -> list:
    names = agent_labels(env)
    return [_marker(shape_of(i), agent_colour(i), f"agent {names[i]}", size=8) for i in range(env.spec.num_agents)]


# Box Pushing ------------------------------------------------------------------------------------------------------

_SMALL_BOX, _BIG_BOX, _GOAL, _WALL = "#d8b07a", "#8b5a2b", "#cdeccd", "#333333"


def _draw_boxpushing(env, state, ax, fs: float) -> list:
    from matplotlib.patches import Rectangle, RegularPolygon

    from envs_jax.boxpushing import BB, HEADING_DELTA, SB0, SB1

    g, core = env.config.grid, state.core
    ax.add_patch(Rectangle((-0.5, -0.5), g, g, fc="white", ec="none", zorder=0))
    ax.add_patch(Rectangle((-0.5, g - 1.5), g, 1, fc=_GOAL, ec="none", zorder=0.5))
    for k in range(g + 1):
        ax.plot([k - 0.5, k - 0.5], [-0.5, g - 0.5], color="#d0d0d0", lw=0.5, zorder=1)
        ax.plot([-0.5, g - 0.5], [k - 0.5, k - 0.5], color="#d0d0d0", lw=0.5, zorder=1)
    ax.add_patch(Rectangle((-0.5, -0.5), g, g, fill=False, ec=_WALL, lw=2.5, zorder=4))  # the walls
    col, rows = env.layout.box_col, np.asarray(core.box_row)
    for b in (SB0, SB1):
        if 0 <= rows[b] < g:
            ax.add_patch(Rectangle((col[b] - 0.36, rows[b] - 0.36), 0.72, 0.72, fc=_SMALL_BOX, ec="#6b4423",
                                   lw=1, zorder=2, gid="box"))
    if 0 <= rows[BB] < g:
        ax.add_patch(Rectangle((col[BB] - 0.42, rows[BB] - 0.42), 1.84, 0.84, fc=_BIG_BOX, ec="#3e2512", lw=1.2,
                               zorder=2, gid="box"))
    pos, head = np.asarray(core.pos), np.asarray(core.head)
    shared = bool((pos[0] == pos[1]).all())
    for i in range(len(pos)):
        xy = pos[i].astype(float) + ((0.2 * (2 * i - 1), 0.0) if shared else (0.0, 0.0))
        radius = 0.2 if shared else 0.27
        _agent(ax, xy, i, str(i), radius, fs)
        d = HEADING_DELTA[int(head[i]) % 4]
        tip = xy + (radius + 0.09) * d
        ax.add_patch(RegularPolygon(tip, 3, radius=0.11, orientation=-math.pi / 2 * int(head[i]),
                                    fc=agent_colour(i), ec="black", lw=0.6, zorder=5))
    lo = min(-0.5, float(pos.min()) - 0.5)
    hi = max(g - 0.5, float(pos.max()) + 0.5)
    ax.set_xlim(lo - 0.05, hi + 0.05)
    ax.set_ylim(lo - 0.05, hi + 0.05)
    return _agent_entries(env) + [
        _marker("^", "white", "heading"),
        _patch(_SMALL_BOX, "small box", "#6b4423"),
        _patch(_BIG_BOX, "big box (2 agents)", "#3e2512"),
        _patch(_GOAL, "goal row", "none"),
        _patch("white", "walls", _WALL),
    ]


# Overcooked -------------------------------------------------------------------------------------------------------

_FOODS = (("tomato", "#e53935"), ("lettuce", "#43a047"), ("onion", "#f2b705"))
_COUNTER, _FLOOR, _DELIVERY, _PLATE = "#c9b99b", "white", "#8fd18f", "#f4f4f4"


def _star(centre, radius: float, points: int = 5) -> np.ndarray:
    angles = math.pi / 2 + np.arange(2 * points) * math.pi / points
    radii = np.where(np.arange(2 * points) % 2 == 0, radius, 0.45 * radius)
    return np.stack([centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)], -1)


def _food(ax, centre, f: int, chop: int, radius: float, z: float, fs: float) -> None:
    """A food: a disc while raw (chop count 1–2 written on it), a star once chopped (3 chops)."""
    from matplotlib.patches import Circle, Polygon

    colour = _FOODS[f][1]
    if chop >= 3:
        ax.add_patch(Polygon(_star(centre, 1.25 * radius), closed=True, fc=colour, ec="black", lw=0.6, zorder=z,
                             gid="food"))
    else:
        ax.add_patch(Circle(centre, radius, fc=colour, ec="black", lw=0.6, zorder=z, gid="food"))
        if chop > 0:
            ax.text(centre[0], centre[1], str(chop), ha="center", va="center", fontsize=0.8 * fs, zorder=z + 0.1)


def _oc_item(ax, core, k: int, centre, scale: float, z: float, fs: float) -> None:
    """Item ``k`` (0–2 foods, 3–4 plates with the foods on them) at ``centre``."""
    from matplotlib.patches import Circle

    from envs_jax.overcooked.layouts import PLATE1_K

    if k < PLATE1_K:
        _food(ax, centre, k, int(core.chop[k]), 0.2 * scale, z, fs)
        return
    ax.add_patch(Circle(centre, 0.33 * scale, fc=_PLATE, ec="#555555", lw=1.0, zorder=z, gid="plate"))
    ax.add_patch(Circle(centre, 0.22 * scale, fill=False, ec="#aaaaaa", lw=0.5, zorder=z))
    foods = [f for f in range(3) if core.plate_has[k - PLATE1_K, f]]
    for j, f in enumerate(foods):
        a = math.pi / 2 + 2 * math.pi * j / max(len(foods), 1)
        off = 0.0 if len(foods) == 1 else 0.14 * scale
        _food(ax, (centre[0] + off * math.cos(a), centre[1] + off * math.sin(a)), f, int(core.chop[f]),
              0.1 * scale, z + 0.2, fs * 0.8)
    ax.text(centre[0] + 0.3 * scale, centre[1] - 0.32 * scale, str(k - PLATE1_K + 1), fontsize=0.75 * fs,
            ha="center", va="center", zorder=z + 0.3, color="#333333")


def _draw_overcooked(env, state, ax, fs: float) -> list:
    from matplotlib.patches import Polygon, Rectangle

    from envs_jax.overcooked.layouts import AGENT0_K, COUNTER, DELIVERY, KNIFE, N_AGENTS, N_ITEMS, N

    core = state.core
    static = env.layout.static_grid

    def at(x, y):  # cell (row x, column y) -> plot coordinates, row 0 at the top
        return float(y), float(N - 1 - x)

    knife = 0
    for x in range(N):
        for y in range(N):
            cx, cy = at(x, y)
            code = static[x, y]
            colour = {COUNTER: _COUNTER, KNIFE: _COUNTER, DELIVERY: _DELIVERY}.get(code, _FLOOR)
            ax.add_patch(Rectangle((cx - 0.5, cy - 0.5), 1, 1, fc=colour, ec="#bbbbbb", lw=0.4, zorder=0))
            if code == KNIFE:  # a blade and a handle
                knife += 1
                ax.add_patch(Polygon([(cx - 0.35, cy + 0.05), (cx + 0.15, cy + 0.05), (cx + 0.15, cy - 0.12),
                                      (cx - 0.28, cy - 0.08)], fc="#dcdcdc", ec="#555555", lw=0.6, zorder=1))
                ax.add_patch(Rectangle((cx + 0.15, cy - 0.09), 0.22, 0.12, fc="#4e342e", ec="none", zorder=1))
                ax.text(cx - 0.3, cy + 0.3, f"K{knife}", fontsize=0.75 * fs, ha="center", va="center", zorder=1)
            elif code == DELIVERY:
                ax.text(cx - 0.3, cy + 0.3, "D", fontsize=0.75 * fs, ha="center", va="center", zorder=1,
                        fontweight="bold")
    ax.add_patch(Rectangle((-0.5, -0.5), N, N, fill=False, ec="#333333", lw=1.5, zorder=4))
    hold = np.asarray(core.hold)
    held = {int(h) for h in hold if h >= 0}
    plated = {f for f in range(3) if np.asarray(core.plate_has)[:, f].any()}
    pos = np.asarray(core.pos)
    for k in range(N_ITEMS):
        if k not in held and k not in plated:
            _oc_item(ax, core, k, at(*pos[k]), 1.0, 2.0, fs)
    for i in range(N_AGENTS):
        cx, cy = at(*pos[AGENT0_K + i])
        _agent(ax, (cx, cy), i, str(i + 1), 0.3, fs)
        if hold[i] >= 0:
            _oc_item(ax, core, int(hold[i]), (cx + 0.27, cy + 0.27), 0.6, 7.0, fs)
    ax.set_xlim(-0.55, N - 0.45)
    ax.set_ylim(-0.55, N - 0.45)
    return _agent_entries(env) + [
        *(_marker("o", colour, name) for name, colour in _FOODS),
        _marker("*", "white", "chopped food", size=9),
        _marker("o", _PLATE, "plate", size=9, edge="#555555"),
        _patch(_COUNTER, "counter"),
        _patch(_DELIVERY, "delivery (D)"),
        _marker(r"$\dagger$", "#555555", "knife (K1, K2)", size=9, edge="#555555"),
    ]


# Warehouse --------------------------------------------------------------------------------------------------------

_TOOLS = (("^", "#d62728"), ("s", "#2ca02c"), ("D", "#e6ab02"))  # tool types 0, 1, 2
_TABLE, _WA, _WAITING, _DONE = "#a0522d", "#eeeeee", "#f4a6a6", "#b8e0b8"


def _warehouse_extent(env) -> tuple[float, float]:
    width = 9.0 if max(x for x, _ in env.layout.work_areas) > 6 else 7.0  # as the text rendering's canvas
    return width, 5.0


def _tool(ax, centre, o: int, size: float, z: float = 6.0) -> None:
    from matplotlib.patches import Rectangle, RegularPolygon

    marker, colour = _TOOLS[o]
    style = {"fc": colour, "ec": "black", "lw": 0.5, "zorder": z, "gid": "tool"}
    if marker == "s":
        ax.add_patch(Rectangle((centre[0] - size, centre[1] - size), 2 * size, 2 * size, **style))
    else:
        ax.add_patch(RegularPolygon(centre, 3 if marker == "^" else 4, radius=1.3 * size, **style))


def _draw_warehouse(env, state, ax, fs: float) -> list:
    from matplotlib.patches import Rectangle, RegularPolygon

    lay, core = env.layout, state.core
    n_t = env.n_robots
    width, height = _warehouse_extent(env)
    ax.add_patch(Rectangle((0, 0), width, height, fc="#fafafa", ec="#333333", lw=2.0, zorder=0))
    for x in range(1, int(width)):
        ax.plot([x, x], [0, height], color="#e4e4e4", lw=0.5, zorder=0.5)
    for y in range(1, int(height)):
        ax.plot([0, width], [y, y], color="#e4e4e4", lw=0.5, zorder=0.5)
    # humans at their work areas: grey while working, red while waiting for a tool, green once finished
    phase, timer = np.asarray(core.h_phase), np.asarray(core.h_time)
    got, fin = np.asarray(core.h_got), np.asarray(core.h_fin)
    for h, (x, y) in enumerate(lay.work_areas):
        waiting = phase[h] < 3 and timer[h] <= 0 and not got[h] and not fin[h]
        colour = _DONE if fin[h] else _WAITING if waiting else _WA
        ax.add_patch(Rectangle((x - 0.38, y - 0.38), 0.76, 0.76, fc=colour, ec="#444444", lw=0.8, zorder=1,
                               gid="work_area"))
        ax.text(x, y + 0.18, f"H{h}", fontsize=0.85 * fs, ha="center", va="center", zorder=2)
        what = "done" if fin[h] else f"ph {int(phase[h])}"
        ax.text(x, y - 0.05, what, fontsize=0.7 * fs, ha="center", va="center", zorder=2)
        if not fin[h] and phase[h] < 3:  # the tool this phase needs
            _tool(ax, (x, y - 0.25), int(phase[h]), 0.07, 2.0)
    tx, ty = lay.tool_room
    ax.add_patch(RegularPolygon((tx, ty), 4, radius=0.2, fc="#bdbdbd", ec="#444444", lw=0.8, zorder=1))
    ax.text(tx, ty - 0.35, "TR", fontsize=0.75 * fs, ha="center", va="center", zorder=2)
    for x, y in lay.tables:  # a robot's spot at the table (it hides the middle when there)
        ax.add_patch(Rectangle((x - 0.32, y - 0.17), 0.64, 0.34, fc=_TABLE, ec="#3e2512", lw=0.8, zorder=1))
    # F with the tools it has staged
    fx, fy = lay.fetch
    _agent(ax, (fx, fy), n_t, "F", 0.3, fs, shape=6)
    for j, o in enumerate(int(o) for o in np.asarray(core.staging) if o >= 0):
        _tool(ax, (fx - 0.12 + 0.24 * j, fy - 0.45), o, 0.08)
    # robots with the tools in their baskets (robots at the same spot are spread out)
    xy, basket = np.asarray(core.rb_xy, float), np.asarray(core.basket)
    seen: dict[tuple[float, float], int] = {}
    for i in range(n_t):
        spot = (round(xy[i, 0], 1), round(xy[i, 1], 1))
        k = seen[spot] = seen.get(spot, -1) + 1
        centre = (xy[i, 0] + 0.28 * k, xy[i, 1] - 0.12 * k)
        _agent(ax, centre, i, str(i), 0.22, fs)
        tools = [o for o in range(3) for _ in range(int(basket[i, o]))]
        for j, o in enumerate(tools):
            _tool(ax, (centre[0] - 0.15 + 0.15 * j, centre[1] + 0.33), o, 0.065)
    ax.set_xlim(-0.1, width + 0.1)
    ax.set_ylim(-0.1, height + 0.1)
    return [_marker("o", agent_colour(i), f"robot {i}", size=8) for i in range(n_t)] + [
        _marker("h", agent_colour(n_t), "F (fetch arm)", size=9),
        *(_marker(m, c, f"tool {o}", size=6) for o, (m, c) in enumerate(_TOOLS)),
        _patch(_WA, "human at work area"),
        _patch(_WAITING, "human waiting for a tool"),
        _patch(_DONE, "human finished"),
        _marker("D", "#bdbdbd", "TR (tool-room wait spot)"),
        _patch(_TABLE, "table spot", "#3e2512"),
    ]


_DRAWERS = {"boxpushing": _draw_boxpushing, "overcooked": _draw_overcooked, "warehouse": _draw_warehouse}
