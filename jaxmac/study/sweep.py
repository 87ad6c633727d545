"""The paper's experiments as sweeps: named sets of (method, scenario) cells × seeds, run into one folder.

    jaxmac sweep EXPERIMENT [--protocol cpu|full|paper|smoke] [--out DIR] [--seeds N|A:B] [--devices N] [--dry-run]

A *cell* is one ordinary run folder (``jaxmac train``'s): a method (a learner with its settings) on a scenario for a
range of seeds. The sweep plans every cell of the experiment and protocol, skips cells already finished (their
``summary.json`` exists), resumes cells that were interrupted (``config.json`` without a summary: resume is exact) and
starts the others, one after another in this process, each with its seeds vmapped and sharded over ``devices``
(``jax.sharding``: the same command uses several GPUs or hosts). Seeds are a range, so a later
``--seeds 4:8`` adds four seeds to a sweep run with ``--seeds 4``: their cells are new folders
(``…/seeds4-8``) that the statistics merge with the first ones.

Several sweep processes may work through one folder at once (e.g. one per core: ``taskset -c 0 jaxmac sweep bp &
taskset -c 1 jaxmac sweep bp``): each takes a cell by locking its run folder (``jaxmac.runs.lock_run_folder``: an OS
lock, released when its process ends, however it ends), and leaves cells another live process holds. On a cluster,
``--cluster ray`` runs every cell as a Ray task instead (``jaxmac.study.cluster``), through the same ``run_cell``.
Every attempt at a cell appends where and how it ran to the cell's ``attempts.jsonl`` (``record_attempt``).

Folder layout: ``OUT/<scenario>/<method>/seeds<A>-<B>/`` (a run folder).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

from jaxmac.config import WATCH_SETTINGS, TrainConfig
from jaxmac.presets import scenario_config
from jaxmac.runs.divergence import diverged_record
from jaxmac.runs.early_end import SettledRule
from jaxmac.scenarios import BOXPUSHING, FAMILIES, OVERCOOKED, WAREHOUSE, family
from jaxmac.study.stats import return_column


@dataclasses.dataclass(frozen=True)
class Method:
    """A learner with its settings, as a curve of the paper's figures is labelled."""

    name: str  # folder and legend key, e.g. "tomacvf-wo-atpg"
    algorithm: str
    overrides: tuple[tuple[str, Any], ...] = ()
    label: str = ""  # legend text (the paper's name)
    # (scenario or scenario family, overrides) applied on top of ``overrides`` where the key matches
    scenario_overrides: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()
    paper: bool = False  # start from the publication's settings instead of jaxmac's defaults (``--paper``)

    def overrides_for(self, scenario: str) -> dict[str, Any]:
        """The settings this method changes on ``scenario``'s own."""
        values = dict(self.overrides)
        for key, extra in self.scenario_overrides:
            if key in (scenario, family(scenario)):
                values.update(extra)
        return values

    def config(self, scenario: str, tiny: bool = False) -> TrainConfig:
        return scenario_config(scenario, self.algorithm, tiny=tiny, paper=self.paper,
                               overrides=self.overrides_for(scenario))


@dataclasses.dataclass(frozen=True)
class Cell:
    """One run folder of a sweep."""

    experiment: str
    method: Method
    scenario: str
    first_seed: int
    seeds: int
    episodes: int
    tiny: bool = False
    scale_schedules: bool = False  # a budget cut shortens the warm-up and ε schedule in proportion
    end_early: SettledRule | None = None  # the protocol's rule for ending before the budget

    @property
    def path(self) -> str:
        return os.path.join(self.scenario, self.method.name, f"seeds{self.first_seed}-{self.first_seed + self.seeds}")

    def config(self) -> TrainConfig:
        config = self.method.config(self.scenario, self.tiny)
        changes: dict[str, Any] = {"episodes": self.episodes}
        if self.scale_schedules and self.episodes < config.episodes:
            fraction = self.episodes / config.episodes
            for name in SCHEDULE_SETTINGS:
                if getattr(config, name) > 0:
                    changes[name] = max(1, round(getattr(config, name) * fraction))
        return config.override(**changes)


# Settings counted in episodes that place a phase of the run (the replay warm-up before training, ε's start and
# length): a shortened budget keeps each phase at the same fraction of the run.
SCHEDULE_SETTINGS = ("start_train_episodes", "eps_decay_start", "eps_decay_episodes")


TOMACVF = Method("tomacvf", "tomacvf", label="ToMacVF")
# The paper's own table where jaxmac's defaults differ (Overcooked, Warehouse; docs/tomacvf-settings.md). Its
# Overcooked target period copies after every gradient step, which a configuration must ask for as period 0.
TOMACVF_PAPER = Method("tomacvf-paper", "tomacvf", label="ToMacVF (paper's settings)", paper=True,
                       scenario_overrides=(("overcooked", (("target_update_episodes", 0),)),))
# ToMacVF on Box Pushing with the settings jaxmac found to solve it where the defaults (the paper's) are slow
# (README, "Results"): one gradient step per 4 collected episodes (D13's default: one per 16 on 6x6) and the
# optimistic TD weighting 0.3. The defaults stay the ``tomacvf`` cells.
TOMACVF_TUNED = Method("tomacvf-tuned", "tomacvf", label="ToMacVF (tuned)", scenario_overrides=(
    ("boxpushing", (("overestimate_weight", 0.3),)),
    ("boxpushing-6x6", (("updates_per_round", 4),)),  # 16 episodes per round
    ("boxpushing-8x8", (("updates_per_round", 4),)),  # 16
    ("boxpushing-10x10", (("updates_per_round", 8),)),  # 32
    ("boxpushing-12x12", (("updates_per_round", 12),)),  # 48
    ("boxpushing-14x14", (("updates_per_round", 12),)),  # 48
))
BASELINES = (
    Method("mac_cac", "mac_cac", label="Mac-CAC"),
    Method("mac_iaicc", "mac_iaicc", label="Mac-IAICC"),
    Method("mac_niacc", "mac_niacc", label="Mac-NIACC"),
    Method("macdec_ddrqn", "macdec_ddrqn", label="Mac-Dec-MADDRQN"),
    Method("maccen_ddrqn", "maccen_ddrqn", label="Mac-Cen-DDRQN"),
    Method("avf", "avf", label="AVF"),
)
WO_ATPG = Method("tomacvf-wo-atpg", "tomacvf", (("mixer_params", "state"),), "ToMacVF w/o ATPG")
# Mac-JERT (the squeezed sequence) stores macro-observations only and is not packed
_MAC_JERT = (("buffer", "mac_jert"), ("obs_mode", "macro"), ("packing", False))
WO_SJERT = Method("tomacvf-wo-sjert", "tomacvf", _MAC_JERT, "ToMacVF w/o Mac-SJERT")
WO_BOTH = Method("tomacvf-wo-both", "tomacvf", (("mixer_params", "state"),) + _MAC_JERT,
                 "ToMacVF w/o ATPG and Mac-SJERT")
# ToMacVF's own mixer is QMIX: its cells are the other experiments' ToMacVF cells
MIXERS = (dataclasses.replace(TOMACVF, label="ToMacVF_QMIX"),) + tuple(
    Method(f"tomacvf-{m}", "tomacvf", (("mixer", m),), f"ToMacVF_{label}")
    for m, label in (("vdn", "VDN"), ("qplex", "QPLEX"), ("qtran", "Qtran")))


# experiment -> (methods, scenarios), as the paper's figures group them
EXPERIMENTS: dict[str, tuple[tuple[Method, ...], tuple[str, ...]]] = {
    "bp": ((TOMACVF, TOMACVF_TUNED) + BASELINES, BOXPUSHING),
    # the paper leaves the two DDRQNs out of Warehouse
    "warehouse": ((TOMACVF, TOMACVF_PAPER) + tuple(m for m in BASELINES if not m.name.endswith("ddrqn")), WAREHOUSE),
    "overcooked": ((TOMACVF, TOMACVF_PAPER) + BASELINES, OVERCOOKED),
    "ablation": ((TOMACVF, WO_ATPG, WO_SJERT, WO_BOTH), ("overcooked-B", "warehouse-E")),
    "mixers": (MIXERS, OVERCOOKED),
}


def method_by_name(name: str) -> Method:
    """The sweep method called ``name`` (its folder name)."""
    methods = {m.name: m for ms, _ in EXPERIMENTS.values() for m in ms}
    if name not in methods:
        raise ValueError(f"unknown method {name!r}; valid methods: {sorted(methods)}")
    return methods[name]


@dataclasses.dataclass(frozen=True)
class Protocol:
    """How many seeds and episodes every cell gets, and which cells it leaves out (with the reason)."""

    name: str
    seeds: int
    budgets: tuple[tuple[str, int], ...]  # (scenario family, at most this many episodes per seed); () = the paper's
    about: str
    tiny: bool = False  # tiny networks and budgets (a smoke run of the sweep's plumbing)
    scale_schedules: bool = False  # see Cell.scale_schedules
    # (method name, scenario or scenario family, why the cell is not run)
    not_run: tuple[tuple[str, str, str], ...] = ()
    end_early: SettledRule | None = None  # a cell may end before its budget once its curves have settled

    def budget(self, scenario: str, paper_budget: int) -> int:
        return min(paper_budget, dict(self.budgets).get(family(scenario), paper_budget))

    def not_run_reason(self, method: str, scenario: str) -> str | None:
        for name, where, why in self.not_run:
            if name == method and where in (scenario, family(scenario)):
                return why
        return None


_SLOW_WHY = ("{what}: {rate} training episodes per second of 4 seeds on one core here (whole {steps}-step episodes, "
             "a gradient step per 64 env steps, as the original scripts): 4 seeds x {episodes} episodes would take "
             "{hours} per cell")
_NOT_RUN_CPU = (
    ("maccen_ddrqn", "overcooked", _SLOW_WHY.format(what="a step over 64 episodes x 201 entries x 2,744 joint actions",
                                                    rate="about 0.6", steps=200, episodes="2K", hours="~4 h")),
    ("macdec_ddrqn", "overcooked", _SLOW_WHY.format(what="Mac-Cen-DDRQN's joint net plus per-agent nets",
                                                    rate="under 0.6", steps=200, episodes="2K", hours="over 4 h")),
    ("avf", "overcooked", _SLOW_WHY.format(what="recurrent per-agent Q over whole episodes", rate="0.56", steps=200,
                                           episodes="2K", hours="~4 h")),
    ("avf", "warehouse", _SLOW_WHY.format(what="recurrent per-agent Q over whole episodes", rate="0.24 (Warehouse-E)",
                                          steps=300, episodes="3K", hours="~14 h")),
)
_HOURS_WHY = "{rate} training episodes per second of one seed on one core here (jaxmac calibrate): {hours} per cell"
_NOT_RUN_FULL = (
    ("tomacvf-paper", "overcooked", "the publication's table diverges on Overcooked (its target is copied after every "
                                    "gradient step; docs/tomacvf-settings.md): the tomacvf cells run jaxmac's settings"),
    ("tomacvf-paper", "warehouse", "the publication's γ = 1 diverges on Warehouse (Q_tot past the ceiling by 12K "
                                   "episodes; docs/tomacvf-settings.md): the tomacvf cells run jaxmac's settings"),
    ("maccen_ddrqn", "overcooked", _HOURS_WHY.format(rate="about 0.6", hours="4 seeds x 100K episodes ~ 185 h")),
    ("macdec_ddrqn", "overcooked", _HOURS_WHY.format(rate="under 0.6", hours="over 185 h")),
    ("avf", "overcooked", _HOURS_WHY.format(rate="0.56", hours="4 seeds x 100K episodes ~ 200 h")),
    ("avf", "warehouse", _HOURS_WHY.format(rate="0.24 (Warehouse-E)", hours="4 seeds x 100K episodes ~ 460 h")),
) + tuple(
    (m, "warehouse-E", "ablation on Overcooked-B only in this protocol: " + _HOURS_WHY.format(
        rate=rate, hours=hours)) for m, rate, hours in (
        ("tomacvf-wo-atpg", "about 3 (as ToMacVF)", "~38 h"), ("tomacvf-wo-sjert", "3.1", "~36 h"),
        ("tomacvf-wo-both", "about 3", "~36 h"))
) + tuple(
    (m, scenario, "the mixers on Overcooked-A only in this protocol: " + _HOURS_WHY.format(rate=rate, hours=hours))
    for m, rate, hours in (("tomacvf-vdn", "about 7 (as ToMacVF, Overcooked-B)", "~19 h at 120K"),
                           ("tomacvf-qplex", "4.9 (Overcooked-B)", "~27 h at 120K"),
                           ("tomacvf-qtran", "7.5 (Overcooked-B)", "~18 h at 120K"))
    for scenario in ("overcooked-B", "overcooked-C")
)
PROTOCOLS = {
    "paper": Protocol("paper", 20, (), "20 seeds, the paper's budget per scenario (a GPU or a long campaign)"),
    "cpu": Protocol(
        "cpu", 4, (("boxpushing", 4_000), ("warehouse", 3_000), ("overcooked", 2_000)),
        "4 seeds; at most 4K episodes per seed on Box Pushing, 3K on Warehouse, 2K on Overcooked (the paper's "
        "40K-120K), the warm-up and exploration schedules shortened in proportion; the value baselines not run where "
        "their update makes a cell cost hours: about 12 hours of a 2-core CPU", scale_schedules=True,
        not_run=_NOT_RUN_CPU),
    "full": Protocol(
        "full", 4, (),
        "4 seeds at the paper's budget per scenario (Overcooked 100K/120K/100K, Warehouse 40K/40K/80K/80K/100K "
        "episodes) with the paper's schedules; a cell ends early once every seed's evaluations of the last 20K "
        "episodes stay within 2 % of their mean, after at least 40K; the cells that would cost far beyond ~12 "
        "core-hours here are not run (the reason and the measured cost are listed)",
        not_run=_NOT_RUN_FULL, end_early=SettledRule(40_000, 20_000, 0.02)),
    "smoke": Protocol("smoke", 1, (("boxpushing", 32), ("warehouse", 32), ("overcooked", 32)),
                      "1 seed, 32 episodes, tiny networks: checks a sweep's plumbing and decides nothing; ~25 s a "
                      "cell on a 2-core CPU, nearly all of it compiling the cell's own program (bp's 40 cells took "
                      "17 min; 109 cells in all five experiments, not timed); --only TEXT runs fewer", tiny=True),
}


def not_run_cells(experiment: str, protocol: str) -> list[tuple[str, str, str]]:
    """(scenario, method name, reason) of each cell of ``experiment`` that ``protocol`` leaves out."""
    proto = PROTOCOLS[protocol]
    methods, scenarios = EXPERIMENTS[experiment]
    return [(s, m.name, why) for s in scenarios for m in methods
            if (why := proto.not_run_reason(m.name, s)) is not None]


def protocol_cell(experiment: str, protocol: str, method: Method, scenario: str, first_seed: int,
                  seeds: int) -> Cell:
    """``method`` on ``scenario`` as ``protocol`` runs it: its budget, its schedules and its rule for ending early."""
    proto = PROTOCOLS[protocol]
    budget = proto.budget(scenario, method.config(scenario, proto.tiny).episodes)
    end_early = None if proto.end_early is None else dataclasses.replace(proto.end_early,
                                                                          column=return_column(scenario))
    return Cell(experiment, method, scenario, first_seed, seeds, budget, proto.tiny, proto.scale_schedules, end_early)


def plan(experiment: str, protocol: str = "cpu", seeds: tuple[int, int] | None = None,
         only: str | None = None, methods: tuple[Method, ...] | None = None) -> list[Cell]:
    """Every cell of ``experiment`` under ``protocol``; ``seeds`` = (first seed, count) replaces the protocol's
    count (e.g. (4, 4) adds seeds 4-7); ``only`` keeps the cells whose path contains that text; ``methods``
    replaces the experiment's methods (``jaxmac sweep --config``: ``jaxmac.config_files.sweep_methods``)."""
    if experiment not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {experiment!r}; valid experiments: {list(EXPERIMENTS)}")
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; valid protocols: {list(PROTOCOLS)}")
    proto = PROTOCOLS[protocol]
    first, count = seeds if seeds is not None else (0, proto.seeds)
    own, scenarios = EXPERIMENTS[experiment]
    methods = own if methods is None else methods
    cells = [protocol_cell(experiment, protocol, method, scenario, first, count)
             for scenario in scenarios for method in methods if proto.not_run_reason(method.name, scenario) is None]
    if only is not None:
        cells = [c for c in cells if only in c.path]
        if not cells:
            raise ValueError(f"--only {only!r} matches no cell of {experiment!r}")
    return cells


def fit_to_existing(cells: list[Cell], out_dir: str) -> list[Cell]:
    """``cells`` with each one whose seeds other seed-range folders of its method already hold split along them:
    asked for seeds 0-3 where ``seeds0-2/`` exists, the sweep takes ``seeds0-2`` as it stands (done, resumed or
    extended like any cell) and plans ``seeds2-4`` for the rest, instead of training seeds 0-1 a second time in
    ``seeds0-4/`` (the results merge a cell's ranges and refuse a seed held twice). A cell's own folder, when it
    exists, is kept as is; a range that holds some of the cell's seeds and some outside it is an error naming it."""
    from jaxmac.study.stats import seed_range, seed_range_folders

    fitted = []
    for cell in cells:
        method_dir = os.path.join(out_dir, cell.scenario, cell.method.name)
        first, end = cell.first_seed, cell.first_seed + cell.seeds
        if os.path.exists(os.path.join(out_dir, cell.path)):
            fitted.append(cell)
            continue
        ranges = [seed_range(name) for name in seed_range_folders(method_dir)]
        inside = sorted((a, b) for a, b in ranges if first <= a and b <= end)
        straddling = [f"seeds{a}-{b}" for a, b in ranges if a < end and first < b and (a, b) not in inside]
        straddling += [f"seeds{a}-{b}" for (_, end_before), (a, b) in zip(inside, inside[1:]) if a < end_before]
        if straddling:
            raise ValueError(f"{method_dir}: {', '.join(straddling)} holds seeds that another range or the asked seeds "
                             f"{first}..{end - 1} only partly hold; ask for seeds that the existing ranges "
                             f"{sorted(ranges)} tile without overlap (--seeds A:B)")
        if not inside:
            fitted.append(cell)
            continue
        cuts = sorted({first, end} | {v for r in inside for v in r})
        fitted += [dataclasses.replace(cell, first_seed=a, seeds=b - a) for a, b in zip(cuts, cuts[1:])]
    return fitted


def cell_status(out_dir: str, cell: Cell) -> str:
    """'done' (a summary), 'diverged' (the divergence guard stopped its run: ``diverged.json``; an exact resume would
    diverge again, so the sweep does not rerun it), 'interrupted' (a run folder without either), 'shorter' (the cell's
    run trained to a smaller budget, finished or not: the sweep extends it, as ``jaxmac train --resume RUN --episodes
    N`` would) or 'new'. A folder that holds a run of another configuration (other settings, a larger budget or other
    seeds) is refused, naming what differs: cells are shared between experiments by path, so a path must always mean
    the same run. The divergence guard's settings (``WATCH_SETTINGS``) are not compared: they never change what a run
    computes, so a run started under another guard is the cell's (``watch_differences`` names the difference)."""
    from jaxmac.runs import read_meta

    path = os.path.join(out_dir, cell.path)
    config_path = os.path.join(path, "config.json")
    if not os.path.exists(config_path):
        return "new"
    meta = read_meta(path)
    held = TrainConfig.from_dict(meta["config"]).run_settings()
    wanted = cell.config().run_settings()
    differ = [f"{k}: {held.get(k)!r} there, {v!r} here" for k, v in wanted.items() if held.get(k) != v]
    if (meta["seeds"], meta["seed_offset"]) != (cell.seeds, cell.first_seed):
        differ.append(f"seeds: {meta['seed_offset']}..{meta['seed_offset'] + meta['seeds'] - 1} there, "
                      f"{cell.first_seed}..{cell.first_seed + cell.seeds - 1} here")
    if differ == [f"episodes: {held.get('episodes')!r} there, {wanted['episodes']!r} here"] and \
            held["episodes"] < wanted["episodes"]:
        return "shorter"
    if differ:
        raise ValueError(f"{path} holds another run than the sweep's cell ({'; '.join(differ)}); move it away or use "
                         "another --out")
    if os.path.exists(os.path.join(path, "summary.json")):
        return "done"
    return "diverged" if diverged_record(path) is not None else "interrupted"


def watch_differences(path: str, cell: Cell) -> str:
    """The settings that only watch a run (``WATCH_SETTINGS``) in which the run folder ``path`` differs from the
    cell, as "name=there there, here here" items ('' if none): such a folder holds the cell's run all the same."""
    from jaxmac.runs import read_meta

    held = TrainConfig.from_dict(read_meta(path)["config"]).flat_dict()
    wanted = cell.config().flat_dict()
    return "; ".join(f"{k}={held[k]!r} there, {wanted[k]!r} here" for k in WATCH_SETTINGS if held[k] != wanted[k])


def diverged_text(path: str) -> str:
    """What the divergence guard stopped in the cell folder ``path`` and after which chunk, in a line."""
    record = diverged_record(path)
    return f"stopped by the divergence guard after chunk {record['chunk']}: {record['problem']}"


def load_rates(path: str) -> dict[str, dict]:
    """Measured training rates per ``"method@scenario"`` (``jaxmac calibrate``'s file); {} if none."""
    import json

    if not os.path.exists(path):
        return {}
    with open(path) as f:
        return json.load(f)


def estimate_seconds(cell: Cell, rates: dict[str, dict], episodes: int | None = None) -> tuple[float, str] | None:
    """Seconds of one core that ``cell`` needs (for ``episodes`` per seed; default its budget) at a measured rate
    (seed-episodes per second), and the pair measured: the same method on the cell's scenario, else on the nearest
    measured scenario of its family (Box Pushing grids by size, Overcooked and Warehouse maps by letter); None when
    the method was not measured there. A whole run's rate (``jaxmac calibrate --from-sweep``/``--from-run``: an entry
    with a ``source``) is preferred to a rate of a run's first chunks (``jaxmac calibrate``: an entry with
    ``chunks``), wherever in the family it was measured: first chunks run at ε ≈ 1, whose episodes last to the time
    limit, and overstate a whole run's cost several times where trained policies finish early (Warehouse's
    actor-critics: ~6×)."""
    fam = family(cell.scenario)
    order = FAMILIES[fam]
    here = order.index(cell.scenario) if cell.scenario in order else 0
    measured = [s for s in order if f"{cell.method.name}@{s}" in rates]
    if not measured:
        return None
    whole_runs = [s for s in measured if "source" in rates[f"{cell.method.name}@{s}"]]
    nearest = min(whole_runs or measured, key=lambda s: abs(order.index(s) - here))
    key = f"{cell.method.name}@{nearest}"
    episodes = cell.episodes if episodes is None else episodes
    return cell.seeds * episodes / rates[key]["episodes_per_s"], key


def run_sweep(cells: list[Cell], out_dir: str, devices: int = 1, progress: bool = True, log=print,
              checkpoint_seconds: float = 120.0) -> dict[str, str]:
    """Run every cell not done yet (resume the interrupted ones); returns {cell path: what was done}."""
    import jax

    done = {}
    for k, cell in enumerate(cells):
        done[cell.path] = run_cell(cell, out_dir, devices, progress, log, checkpoint_seconds,
                                   prefix=f"[{k + 1}/{len(cells)}] ")
        if done[cell.path] in ("trained", "resumed", "extended"):
            jax.clear_caches()  # the next cell compiles its own program
    return done


def run_cell(cell: Cell, out_dir: str, devices: int = 1, progress: bool = True, log=print,
             checkpoint_seconds: float = 120.0, prefix: str = "", where: dict | None = None) -> str:
    """Train ``cell`` into ``out_dir`` (resume it if interrupted, extend it to the cell's budget if it ran a smaller
    one): 'trained', 'resumed', 'extended', 'skipped' (done already), 'diverged' (the divergence guard stopped it,
    now or before: the cell's result, kept as it is and not rerun) or 'busy' (another live process holds it). Each
    attempt is recorded in the cell's ``attempts.jsonl`` (``where``: the executor's own fields, e.g. a Ray node id;
    default: this process, ``executor: embedded``). The one code path of a cell, in a sweep process (``run_sweep``)
    or a Ray task (``jaxmac.study.cluster``)."""
    from jaxmac.runs import RunDiverged, resume_run, train_run

    path = os.path.join(out_dir, cell.path)

    def settled(status: str) -> str | None:
        """The result of a cell with nothing to run, logged ('skipped' when done, 'diverged'); None otherwise."""
        if status == "done":
            log(f"{prefix}{cell.path}: done")
            return "skipped"
        if status == "diverged":
            log(f"{prefix}{cell.path}: diverged, not rerun ({diverged_text(path)})")
            return "diverged"
        return None

    result = settled(cell_status(out_dir, cell))
    if result:
        return result
    lock = claim_cell(path)
    if not lock:
        log(f"{prefix}{cell.path}: being trained by another sweep process")
        return "busy"
    try:
        status = cell_status(out_dir, cell)  # again, ours now: another process may have finished it meanwhile
        result = settled(status)
        if result:
            return result
        log(f"{prefix}{cell.path}: {status}")
        action = {"interrupted": "resume", "shorter": "extend"}.get(status, "train")
        record_attempt(path, action, devices, where)
        end_early = None if cell.end_early is None else cell.end_early.reason
        try:
            if status in ("interrupted", "shorter"):
                watched = watch_differences(path, cell)
                if watched:  # the same run (WATCH_SETTINGS), resumed exactly: under the guard it started with
                    log(f"{prefix}{cell.path}: goes on under the divergence guard its run started with ({watched})")
                resume_run(path, progress=progress, devices=devices, checkpoint_seconds=checkpoint_seconds,
                           end_early=end_early, episodes=cell.episodes if status == "shorter" else None)
                return "resumed" if status == "interrupted" else "extended"
            train_run(cell.config(), cell.seeds, path, seed_offset=cell.first_seed, progress=progress,
                      devices=devices, checkpoint_seconds=checkpoint_seconds, end_early=end_early)
            return "trained"
        except RunDiverged:  # a result of the cell's method and settings, not a failure of the sweep: go on
            log(f"{prefix}{cell.path}: diverged ({diverged_text(path)})")
            return "diverged"
    finally:
        lock.release()


ATTEMPTS_FILE = "attempts.jsonl"


def record_attempt(path: str, action: str, devices: int = 1, where: dict | None = None) -> dict:
    """Append to the cell folder ``path``'s ``attempts.jsonl`` one line on where and how this attempt at the cell runs:
    the executor (``embedded``: a sweep process; ``ray``: a Ray task, with its node and task ids), host, process,
    the devices its seeds run on, JAX's version, and for a resume the chunks its newest checkpoint covers. A cell run
    in several attempts (killed, resumed elsewhere) has a line per attempt. Returns the line's record."""
    import json
    import socket
    import time

    import jax

    from jaxmac.runs.folders import append_text

    used = jax.devices()[:devices]
    record = {"executor": "embedded", **(where or {}), "action": action,
              "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "host": socket.gethostname(), "pid": os.getpid(),
              "devices": [str(d) for d in used], "platform": used[0].platform,
              "device_kind": used[0].device_kind, "jax": jax.__version__}
    if action == "resume":
        from jaxmac.runs.folders import read_progress

        record["from_chunk"] = (read_progress(path) or {}).get("chunks_done", 0)
    try:  # a record for people: a full disk must not stop the cell (its run folder says so itself)
        append_text(os.path.join(path, ATTEMPTS_FILE), json.dumps(record) + "\n")
    except OSError:
        pass
    return record


def claim_cell(path: str):
    """Take the cell folder ``path`` for this process, so that several sweep processes — one per core, or per host on
    a shared disk that supports ``flock`` — can work through one sweep folder without training a cell twice: the
    run folder's own lock (``jaxmac.runs.try_lock_run_folder``), which the train or resume of the cell takes again.
    Returns the lock (release it when the cell is done), or None if another live process holds the cell. The OS
    releases the lock of a process that ends, however it ends, so a killed process's cell is taken over; a lock
    file alone (a dead process's, one naming a reused PID, an empty one left by a full disk) never blocks."""
    from jaxmac.runs import try_lock_run_folder

    return try_lock_run_folder(path, "sweep")
