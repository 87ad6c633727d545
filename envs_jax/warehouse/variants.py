"""Warehouse Tool Delivery variants A–E: fixed layouts and the overridable configuration.

Numbers follow ``docs/envs/warehouse.md`` §1–§2 (the experiment configs of the
original MacroMARL scripts). A :class:`Layout` is the static geometry of a variant (never
overridden); a :class:`WarehouseConfig` holds the knobs ``envs_jax.make`` accepts as overrides.

Agents are ``[robot 0, …, robot nT-1, F]`` (F = the fixed manipulator). Robot i's waypoint
list ``W_i`` has ``nH + 2`` entries: ``W_i[h]`` = work area of human h, ``W_i[nH]`` = the
tool-room waiting spot TRW, ``W_i[nH + 1]`` = robot i's own table spot. Robot action k means
"go to ``W_i[k]``" (the last one, Get-Tool, also waits there to be handed a tool).
"""

from __future__ import annotations

import dataclasses

from envs_jax.validation import is_integer

N_TOOLS = 3  # tool types o ∈ {0, 1, 2}; human phase c < 3 requests tool c
N_PHASES = 4  # human work phases
STAGING_CAPACITY = 2  # tools F can hold ready for a pass
SPEED_CENTS = 80  # robot speed 0.8 m per step, in hundredths (all motion arithmetic is in 1/100 m)
WAIT_DURATION = 1  # F's macro-action durations in primitive steps
PASS_DURATION = 4
SEARCH_DURATION = 6
GET_TOOL_PATIENCE = PASS_DURATION + SEARCH_DURATION  # Get-Tool gives up after this many waiting steps
STEP_REWARD = -1.0
HANDOVER_REWARD = 100.0
STATE_X_SCALE = 7.0  # the reference normalises x by 7 even where x reaches 8 (SPEC §12.10)
STATE_Y_SCALE = 5.0


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static geometry of one variant (coordinates in metres)."""

    variant: str  # "A" … "E"
    paper_name: str
    work_areas: tuple[tuple[float, float], ...]  # WA_h, one per human
    tool_room: tuple[float, float]  # TRW, shared by the robots
    tables: tuple[tuple[float, float], ...]  # TB_i, one per robot
    starts: tuple[tuple[float, float], ...]  # robot start positions
    fetch: tuple[float, float]  # F never moves

    @property
    def n_humans(self) -> int:
        return len(self.work_areas)

    @property
    def n_robots(self) -> int:
        return len(self.tables)

    def waypoints(self, robot: int) -> tuple[tuple[float, float], ...]:
        """``W_i``: work areas, TRW, then robot ``robot``'s own table spot."""
        return (*self.work_areas, self.tool_room, self.tables[robot])


@dataclasses.dataclass(frozen=True)
class WarehouseConfig:
    """Overridable settings; defaults per variant come from :data:`DEFAULT_CONFIGS`.

    ``move_noise_std``/``fetch_duration_noise`` are the reference's optional noise (off in
    every experiment). ``done_at_horizon`` and ``arrival_exit_on_go_tr`` reproduce the
    variant-E quirks (SPEC §12.1, §12.9); setting them to False in E gives the corrected env.

    Episode end: ``terminated`` is the reference's own ``done`` — every human has received
    tool 2, or, with ``done_at_horizon`` (E), the step counter reaching ``horizon``: the E
    learners were trained with that time-out as a true terminal (no bootstrap), which is how
    WTD-Q was published. ``truncated`` (set by ``MacroEnv``) is the runner's cut at
    ``horizon`` when the env did not terminate (A–D, or E with ``done_at_horizon=False``).
    ``check_every_pass=True`` corrects a D/E quirk the SPEC does not list: the 3-robot code
    never dooms a pass to robot 2 at its start (SPEC §5.2's first check), so such a pass is
    only judged when it ends (a robot arriving during the pass still gets the tool).
    """

    horizon: int
    human_durations: tuple[tuple[int, ...], ...]  # [nH][4] steps per work phase
    n_each_obj: int  # searches that can succeed per tool type and episode
    drop_penalty: float = -10.0  # failed pass
    delay_penalty: float = -20.0  # added to the +100 of a handover to a waiting human
    move_noise_std: float = 0.0  # σ of the per-axis Gaussian motion noise (exact motion iff 0)
    fetch_duration_noise: bool = False  # F action durations get η ~ U{-1, 0, 1, 2}
    done_at_horizon: bool = False  # E: the env itself terminates at ``horizon`` (§12.9)
    arrival_exit_on_go_tr: bool = False  # E: arrival early exit hits Go-TR, not Get-Tool (§12.1)
    check_every_pass: bool = False  # the reference checks a pass at its start only for robots 0, 1
    discount: float = 1.0  # γ of the learners and of the reported returns (every original script: 1.0)

    def __post_init__(self):
        # Lists are accepted for convenience; the config must stay hashable (envs are static).
        durations = tuple(tuple(d) for d in self.human_durations) if _is_seq(self.human_durations) else None
        if durations is not None:
            object.__setattr__(self, "human_durations", durations)

    def validate(self, layout: Layout, name: str) -> None:
        """Raise ``ValueError`` naming the bad value and what is valid."""
        n_h = layout.n_humans
        if self.horizon < 1:
            raise ValueError(f"{name}: horizon={self.horizon} must be a positive int")
        if not 0.0 < self.discount <= 1.0:
            raise ValueError(f"{name}: discount={self.discount!r} must be in (0, 1]")
        d = self.human_durations
        ok = (
            isinstance(d, tuple)
            and len(d) == n_h
            and all(isinstance(row, tuple) and len(row) == N_PHASES for row in d)
            and all(is_integer(x) and x >= 1 for row in d for x in row)
        )
        if not ok:
            raise ValueError(
                f"{name}: human_durations={self.human_durations!r} must be {n_h} sequences "
                f"(one per human) of {N_PHASES} positive ints"
            )
        if self.n_each_obj < 1:
            raise ValueError(f"{name}: n_each_obj={self.n_each_obj} must be a positive int")
        if not self.move_noise_std >= 0.0:
            raise ValueError(f"{name}: move_noise_std={self.move_noise_std} must be >= 0")


def _is_seq(x) -> bool:
    return isinstance(x, (list, tuple)) and all(isinstance(r, (list, tuple)) for r in x)


_AB_WA = ((6.0, 3.0), (6.0, 2.0))
_CD_WA = ((6.0, 3.0), (8.0, 3.0), (8.0, 2.0))
_E_WA = ((6.0, 3.0), (8.0, 3.0), (6.0, 2.0), (8.0, 2.0))
_TRW = (3.0, 2.5)
_F = (0.9, 2.5)
_TB2 = ((1.2, 3.7), (1.2, 1.3))
_TB3 = ((0.8, 3.7), (1.2, 3.7), (1.2, 1.3))
_START2 = ((3.0, 3.5), (3.0, 1.5))
_START3 = ((3.0, 4.0), (3.0, 2.5), (3.0, 1.0))

LAYOUTS: dict[str, Layout] = {
    "A": Layout("A", "WTD-D", _AB_WA, _TRW, _TB2, _START2, _F),
    "B": Layout("B", "WTD-D1", _AB_WA, _TRW, _TB2, _START2, _F),
    "C": Layout("C", "WTD-T", _CD_WA, _TRW, _TB2, _START2, _F),
    "D": Layout("D", "WTD-T1", _CD_WA, _TRW, _TB3, _START3, _F),
    "E": Layout("E", "WTD-Q", _E_WA, _TRW, _TB3, _START3, _F),
}

DEFAULT_CONFIGS: dict[str, WarehouseConfig] = {
    "A": WarehouseConfig(200, ((27, 20, 20, 20), (27, 20, 20, 20)), 2),
    "B": WarehouseConfig(200, ((18, 15, 15, 15), (48, 18, 15, 15)), 2),
    "C": WarehouseConfig(250, ((40,) * 4,) * 3, 3),
    "D": WarehouseConfig(250, ((38,) * 4, (38,) * 4, (27,) * 4), 3),
    "E": WarehouseConfig(300, ((40,) * 4,) * 4, 4, done_at_horizon=True, arrival_exit_on_go_tr=True),
}


def action_names(layout: Layout) -> tuple[tuple[str, ...], ...]:
    """Per agent: robots ``Go-W0 … Go-TR, Get-Tool``; F ``Wait, Pass-R0 …, Search-T0 …``."""
    robot = (*(f"Go-W{h}" for h in range(layout.n_humans)), "Go-TR", "Get-Tool")
    fetch = ("Wait", *(f"Pass-R{j}" for j in range(layout.n_robots)), *(f"Search-T{o}" for o in range(N_TOOLS)))
    return (robot,) * layout.n_robots + (fetch,)


def robot_obs_size(n_humans: int) -> int:
    """Location one-hot (nH+3), human phases (4 nH), basket (3), F ready flags (2)."""
    return (n_humans + 3) + N_PHASES * n_humans + N_TOOLS + 2


def fetch_obs_size(n_robots: int) -> int:
    """Staged tools per type (3), robot-at-its-table flags (nT)."""
    return N_TOOLS + n_robots


def state_size(n_humans: int, n_robots: int) -> int:
    """SPEC §8: positions, baskets, staging, tool in hand, F progress, humans."""
    return 2 * (n_robots + 1) + N_TOOLS * n_robots + N_TOOLS + N_TOOLS + 1 + (N_PHASES + 1) * n_humans
