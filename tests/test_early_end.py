"""The ``full`` protocol's early end: a run whose curves have settled ends before its budget, saying why."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from jaxmac.presets import scenario_config
from jaxmac.runs import train_run
from jaxmac.runs.early_end import SettledRule


def write_metrics(path, curves: dict[int, list[tuple[int, float]]]) -> str:
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["seed", "episodes", "eval_disc_return", "eval_return"])
        for seed, points in curves.items():
            for episodes, value in points:
                out.writerow([seed, episodes, value, value + 60.0])
    return str(path)


def flat(level, until=60_000, every=1_000, wobble=0.01, seed=0):
    rng = np.random.default_rng(seed)
    return [(e, level * (1 + rng.uniform(-wobble, wobble))) for e in range(every, until + 1, every)]


RULE = SettledRule(40_000, 20_000, 0.02)


def test_settled_curves_end_and_the_reason_names_the_episodes(tmp_path):
    path = write_metrics(tmp_path / "m.csv", {0: flat(160.0), 1: flat(150.0, seed=1)})
    reason = RULE.reason(path)
    assert reason is not None and "settled at 60000 episodes" in reason and "2%" in reason


def test_one_seed_moving_in_the_window_keeps_the_run_going(tmp_path):
    moving = flat(150.0, seed=1)
    moving[-5] = (moving[-5][0], 140.0)  # 6 % off, inside the last 20K episodes
    assert RULE.reason(write_metrics(tmp_path / "m.csv", {0: flat(160.0), 1: moving})) is None
    # the same dip before the window does not count
    early = flat(150.0, seed=1)
    early[30] = (early[30][0], 100.0)  # at 31K episodes, the window is 40K-60K
    assert RULE.reason(write_metrics(tmp_path / "e.csv", {0: flat(160.0), 1: early})) is not None


def test_too_few_episodes_or_a_short_record_never_end(tmp_path):
    assert RULE.reason(write_metrics(tmp_path / "a.csv", {0: flat(160.0, until=39_000)})) is None
    # 40K episodes trained but evaluations only since 30K: the window is not covered
    late = [(e, v) for e, v in flat(160.0, until=40_000) if e > 30_000]
    assert RULE.reason(write_metrics(tmp_path / "b.csv", {0: late})) is None
    # Warehouse reads the undiscounted column
    assert SettledRule(40_000, 20_000, 0.02, "eval_return").reason(
        write_metrics(tmp_path / "c.csv", {0: flat(160.0)})) is not None


@pytest.mark.parametrize("kwargs,match", [(dict(window=0), "window"), (dict(window=50_000), "window"),
                                          (dict(tolerance=0.0), "tolerance"), (dict(tolerance=2.0), "tolerance")])
def test_bad_rules_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SettledRule(**{"min_episodes": 40_000, "window": 20_000, "tolerance": 0.02} | kwargs)


def test_a_run_ends_where_the_rule_says_with_its_summary(tmp_path):
    config = scenario_config("boxpushing-6x6", tiny=True).override(
        horizon=20, episodes=64, num_envs=8, batch_size=8, buffer_episodes=16, eval_every_episodes=8,
        eval_episodes=2, target_update_episodes=16, eps_decay_episodes=16)
    asked = []

    def after_24_episodes(metrics_csv):
        with open(metrics_csv) as f:
            episodes = max(int(row["episodes"]) for row in csv.DictReader(f))
        asked.append(episodes)
        return "enough" if episodes >= 24 else None

    out = tmp_path / "run"
    summary = train_run(config, 2, str(out), rounds_per_chunk=1, checkpoint_seconds=0.0, progress=False,
                        end_early=after_24_episodes)
    assert asked == [8, 16, 24] and summary["episodes"] == 24 and summary["ended_early"] == "enough"
    assert json.loads((out / "summary.json").read_text())["ended_early"] == "enough"
    assert (out / "curve.png").exists()
    # a run that goes to its budget has no such field, and the rule is not asked after the last chunk
    asked.clear()
    full = train_run(config.override(episodes=16), 1, str(tmp_path / "full"), rounds_per_chunk=1,
                     checkpoint_seconds=0.0, progress=False, end_early=after_24_episodes)
    assert "ended_early" not in full and asked == [8]


def test_the_full_protocol_runs_the_issues_cells_and_ends_cells_by_the_rule():
    from jaxmac.study.sweep import not_run_cells, plan

    def cells(experiment):
        return {(c.scenario, c.method.name): c for c in plan(experiment, "full")}

    overcooked = cells("overcooked")
    assert set(overcooked) == {(s, m) for s in ("overcooked-A", "overcooked-B", "overcooked-C")
                               for m in ("tomacvf", "mac_iaicc", "mac_niacc", "mac_cac")}
    assert [overcooked[(s, "tomacvf")].episodes for s in ("overcooked-A", "overcooked-B", "overcooked-C")] == [
        100_000, 120_000, 100_000]
    cell = overcooked[("overcooked-A", "tomacvf")]
    assert cell.seeds == 4 and cell.config() == scenario_config("overcooked-A")  # the paper's budget and schedules
    assert cell.end_early == SettledRule(40_000, 20_000, 0.02, "eval_disc_return")
    assert cells("warehouse")[("warehouse-A", "tomacvf")].end_early.column == "eval_return"
    assert set(cells("ablation")) >= {("overcooked-B", m) for m in
                                      ("tomacvf", "tomacvf-wo-atpg", "tomacvf-wo-sjert", "tomacvf-wo-both")}
    assert {m for s, m in cells("mixers") if s == "overcooked-A"} == {
        "tomacvf", "tomacvf-vdn", "tomacvf-qplex", "tomacvf-qtran"}
    assert {m for s, m in cells("mixers") if s != "overcooked-A"} == {"tomacvf"}
    assert {m for s, m in cells("warehouse") if s == "warehouse-E"} == {"tomacvf", "mac_iaicc", "mac_niacc", "mac_cac"}
    left_out = not_run_cells("overcooked", "full") + not_run_cells("mixers", "full")
    assert all(why for _, _, why in left_out) and ("overcooked-B", "tomacvf-qplex") in {(s, m) for s, m, _ in left_out}
