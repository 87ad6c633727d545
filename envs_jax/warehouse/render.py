"""Text rendering of a single (unbatched) Warehouse state."""

from __future__ import annotations

import numpy as np

from envs_jax.warehouse import variants as V

_CELL = 0.5  # metres per character

# What ``render_text`` prints, symbol by symbol: (symbol, meaning) pairs (``jaxmac rollout`` prints them).
RENDER_LEGEND = (
    (".", "0.5 m × 0.5 m of floor (x to the right, y up)"),
    ("A B C D", "the work areas of humans 0, 1, 2, 3"),
    ("T", "TRW, the robots' waiting spot by the tool room"),
    ("t", "a robot's spot at the table (TB_i) where F hands tools over"),
    ("F", "the fetch manipulator (the last agent; it never moves)"),
    ("0 1 2", "robots, drawn over whatever is at their position"),
    ("robotI ...", "position, last waypoint, macro-action (done), travel/wait timer, tools carried per type"),
    ("F ...", "F's macro-action, timer, doomed pass, staged tool types, successful searches per type"),
    ("humanH ...", "work phase (needs tool c in phase c < 3), phase timer, served = received tool 2"),
)


def render_text(env, state) -> str:
    """Map (robots as digits over work areas ``A``…, tool room ``T``, tables ``t``, F ``F``)
    followed by one line per robot, F and human."""
    lay, core = env.layout, state.core
    n_h, n_t = env.n_humans, env.n_robots
    width = 9.0 if max(x for x, _ in lay.work_areas) > 6 else 7.0
    cols, rows = int(width / _CELL) + 1, int(5.0 / _CELL) + 1
    grid = [["." for _ in range(cols)] for _ in range(rows)]

    def put(xy, ch):
        c = round(float(xy[0]) / _CELL)
        r = rows - 1 - round(float(xy[1]) / _CELL)
        if 0 <= r < rows and 0 <= c < cols:
            grid[r][c] = ch

    for h, wa in enumerate(lay.work_areas):
        put(wa, chr(ord("A") + h))
    put(lay.tool_room, "T")
    for tb in lay.tables:
        put(tb, "t")
    put(lay.fetch, "F")
    xy = np.asarray(core.rb_xy)
    for i in range(n_t):
        put(xy[i], str(i))

    names = env.spec.action_names
    mac, free = np.asarray(state.mac), np.asarray(state.mac_done)
    wp_names = [f"W{h}" for h in range(n_h)] + ["TR", "table"]
    header = (
        f"{env.spec.name} (paper {lay.paper_name})  t={int(state.t)}  "
        f"work areas A..{chr(ord('A') + n_h - 1)}, T tool room, t tables, F manipulator, digits robots"
    )
    lines = [header]
    lines += ["".join(row) for row in grid]
    for i in range(n_t):
        act = names[i][mac[i]] if mac[i] >= 0 else "-"
        wp = int(core.rb_wp[i])
        tau = int(core.rb_tau[i])
        status = f"travelling (d-0.8={tau / 100:.2f})" if tau > 0 else (f"waited {-tau // 100}" if tau < 0 else "")
        lines.append(
            f"robot{i} at ({xy[i, 0]:.2f},{xy[i, 1]:.2f}) last wp {wp_names[wp] if wp >= 0 else '-'}  "
            f"{act}{' (done)' if free[i] else ''} {status}  basket {np.asarray(core.basket[i]).tolist()}"
        )
    f_act = int(core.f_act)
    staging = [int(o) for o in np.asarray(core.staging) if o >= 0]
    lines.append(
        f"F {names[n_t][f_act] if f_act >= 0 else '-'}{' (done)' if free[n_t] else ''} timer {int(core.f_tau)}"
        f"{' doomed' if bool(core.f_failed) else ''}  staging {staging} (capacity {V.STAGING_CAPACITY})  "
        f"found {np.asarray(core.found).tolist()} of {env.config.n_each_obj} each"
    )
    for h in range(n_h):
        phase, time_left = int(core.h_phase[h]), int(core.h_time[h])
        if bool(core.h_fin[h]):
            what = "finished"
        elif phase < 3:
            what = f"needs tool {phase} ({'handed over' if bool(core.h_got[h]) else 'waiting' if time_left <= 0 else 'not yet'})"
        else:
            what = "last phase"
        lines.append(
            f"human{h} phase {phase}/3 timer {time_left}  {what}{'  served' if bool(core.served[h]) else ''}"
        )
    return "\n".join(lines)
