"""The sweep layer: which cells an experiment has, and that finished cells are skipped and interrupted ones resumed."""

from __future__ import annotations

import dataclasses
import json
import os

import pytest

import jaxmac.runs
from jaxmac.study.sweep import EXPERIMENTS, cell_status, plan, run_sweep


def test_the_experiments_have_the_papers_cells():
    bp = plan("bp")
    assert len(bp) == 5 * 8 and {c.scenario for c in bp} == {f"boxpushing-{g}x{g}" for g in (6, 8, 10, 12, 14)}
    warehouse = {c.method.algorithm for c in plan("warehouse", "paper")}
    assert "maccen_ddrqn" not in warehouse and "macdec_ddrqn" not in warehouse and len(plan("warehouse", "paper")) == 30
    ablation = plan("ablation")
    assert {c.scenario for c in ablation} == {"overcooked-B", "warehouse-E"} and len(ablation) == 8
    wo_both = next(c for c in ablation if c.method.name == "tomacvf-wo-both").config()
    assert (wo_both.algo.mixer_params, wo_both.algo.buffer, wo_both.algo.obs_mode) == ("state", "mac_jert", "macro")
    mixers = {c.method.name: c.config().algo.mixer for c in plan("mixers") if c.scenario == "overcooked-A"}
    assert mixers == {"tomacvf": "qmix", "tomacvf-vdn": "vdn", "tomacvf-qplex": "qplex", "tomacvf-qtran": "qtran"}
    # a cell two experiments need is one folder: ToMacVF (QMIX) on Overcooked-B is the ablation's and overcooked's
    assert {c.path for c in plan("overcooked")} & {c.path for c in ablation} == {"overcooked-B/tomacvf/seeds0-4"}
    paper = plan("bp", "paper")
    assert all(c.seeds == 20 and c.episodes == 40_000 for c in paper)
    assert all(c.seeds == 4 and c.episodes == 4_000 for c in bp)
    assert len(plan("warehouse")) == 5 * 5  # the cpu protocol leaves AVF out on Warehouse


def test_tuned_tomacvf_changes_only_its_settings_per_scenario_and_family():
    from jaxmac.presets import scenario_config
    from jaxmac.study.sweep import method_by_name

    tuned = method_by_name("tomacvf-tuned")
    expected = {"boxpushing-6x6": {"overestimate_weight": 0.3, "updates_per_round": 4},
                "boxpushing-12x12": {"overestimate_weight": 0.3, "updates_per_round": 12},
                "warehouse-C": {}, "overcooked-B": {}}
    for scenario, changes in expected.items():
        own, config = scenario_config(scenario).flat_dict(), tuned.config(scenario)
        # these settings take effect and nothing else differs from the scenario's own
        assert {k: v for k, v in config.flat_dict().items() if own[k] != v} == changes, scenario
        if scenario.startswith("boxpushing"):  # one gradient step per 4 collected episodes on every grid
            assert config.num_envs == 4 * config.updates_per_round


def test_the_paper_method_runs_the_publications_table():
    from jaxmac.presets import scenario_config
    from jaxmac.study.sweep import method_by_name

    paper = method_by_name("tomacvf-paper")
    own = scenario_config("overcooked-B").flat_dict()
    config = paper.config("overcooked-B").flat_dict()
    # the learning defaults' changes undone, the paper's no-target period asked for explicitly
    assert {k: (own[k], v) for k, v in config.items() if own[k] != v} == {
        "target_update_episodes": (128, 0), "updates_per_round": (4, 1)}
    assert paper.config("warehouse-A").discount == 0.0 and scenario_config("warehouse-A").discount == 0.99


def test_seed_ranges_and_filters():
    more = plan("bp", seeds=(4, 4), only="boxpushing-6x6/tomacvf/")
    assert [c.path for c in more] == ["boxpushing-6x6/tomacvf/seeds4-8"] and more[0].first_seed == 4
    with pytest.raises(ValueError, match="unknown experiment 'bpp'; valid experiments: .*'bp'"):
        plan("bpp")
    with pytest.raises(ValueError, match="unknown protocol 'gpu'; valid protocols"):
        plan("bp", "gpu")
    with pytest.raises(ValueError, match="--only 'zzz' matches no cell"):
        plan("bp", only="zzz")
    assert set(EXPERIMENTS) == {"bp", "warehouse", "overcooked", "ablation", "mixers"}


def _fake_runs(monkeypatch, calls):
    """train_run / resume_run that only write the files a run folder would have."""

    def train_run(config, seeds, out, seed_offset=0, **kw):
        os.makedirs(out, exist_ok=True)
        meta = {"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset}
        (open(os.path.join(out, "config.json"), "w")).write(json.dumps(meta))
        open(os.path.join(out, "summary.json"), "w").write("{}")
        calls.append(("train", out))

    def resume_run(out, **kw):
        open(os.path.join(out, "summary.json"), "w").write("{}")
        calls.append(("resume", out) if kw.get("episodes") is None else ("resume", out, kw["episodes"]))

    monkeypatch.setattr(jaxmac.runs, "train_run", train_run)  # where jaxmac.study.sweep looks them up
    monkeypatch.setattr(jaxmac.runs, "resume_run", resume_run)


def test_finished_cells_are_skipped_and_interrupted_ones_resumed(tmp_path, monkeypatch):
    calls = []
    _fake_runs(monkeypatch, calls)
    cells = plan("ablation", "smoke")
    out = str(tmp_path)
    first = run_sweep(cells, out, log=lambda *_: None)
    assert set(first.values()) == {"trained"} and len(calls) == len(cells)
    os.remove(os.path.join(out, cells[2].path, "summary.json"))  # killed before it finished
    assert cell_status(out, cells[2]) == "interrupted" and cell_status(out, cells[0]) == "done"
    calls.clear()
    second = run_sweep(cells, out, log=lambda *_: None)
    assert calls == [("resume", os.path.join(out, cells[2].path))]
    assert [second[c.path] for c in cells] == ["skipped", "skipped", "resumed"] + ["skipped"] * (len(cells) - 3)


def test_a_cell_the_divergence_guard_stops_is_a_result_the_sweep_goes_on_from_and_does_not_rerun(tmp_path,
                                                                                                 monkeypatch, capsys):
    from jaxmac.runs import RunDiverged

    calls, lines = [], []
    _fake_runs(monkeypatch, calls)
    cells = plan("ablation", "smoke")
    stopped = os.path.join(str(tmp_path), cells[1].path)
    problem = "seed 1, round 3 (episode 64): q_tot_mean = 900.0 is outside [-20.0, 241.5]"
    train_ok = jaxmac.runs.train_run

    def train_run(config, seeds, out, seed_offset=0, **kw):
        if out != stopped:
            return train_ok(config, seeds, out, seed_offset, **kw)
        os.makedirs(out, exist_ok=True)  # the sweep made it, holding its lock
        meta = {"config": config.to_dict(), "seeds": seeds, "seed_offset": seed_offset}
        open(os.path.join(out, "config.json"), "w").write(json.dumps(meta))
        open(os.path.join(out, "diverged.json"), "w").write(json.dumps(
            {"problem": problem, "kind": "value out of bounds", "chunk": 2, "last_good_checkpoint": 1}))
        calls.append(("train", out))
        raise RunDiverged(f"the value estimate diverged at {problem}; stopped.")

    monkeypatch.setattr(jaxmac.runs, "train_run", train_run)
    first = run_sweep(cells, str(tmp_path), log=lines.append)
    assert [first[c.path] for c in cells] == ["trained", "diverged"] + ["trained"] * (len(cells) - 2)
    assert len(calls) == len(cells)  # the cells after it still ran
    assert f"[2/{len(cells)}] {cells[1].path}: diverged (stopped by the divergence guard after chunk 2: {problem})" \
        in lines
    assert cell_status(str(tmp_path), cells[1]) == "diverged"
    calls.clear()
    lines.clear()
    second = run_sweep(cells, str(tmp_path), log=lines.append)
    assert calls == [] and second[cells[1].path] == "diverged"  # an exact resume would only diverge again
    assert f"[2/{len(cells)}] {cells[1].path}: diverged, not rerun (stopped by the divergence guard after chunk 2: " \
           f"{problem})" in lines
    # --dry-run lists it as diverged, with nothing left to run
    from jaxmac.cli import main

    open(os.path.join(stopped, "metrics.csv"), "w").write("seed,round,episodes\n0,0,16\n")
    assert main(["sweep", "ablation", "--protocol", "smoke", "--only", cells[1].path.rsplit("/", 1)[0] + "/",
                 "--dry-run", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (f"{cells[1].path}: {cells[1].episodes} episodes per seed, diverged at 16 (stopped by the divergence "
            f"guard after chunk 2: {problem}), not rerun: nothing left to run") in out


def test_a_folder_of_another_run_is_refused_naming_what_differs(tmp_path, monkeypatch):
    _fake_runs(monkeypatch, [])
    cells = plan("ablation", "smoke", only="overcooked-B/tomacvf/")
    run_sweep(cells, str(tmp_path), log=lambda *_: None)
    shorter = type(cells[0])(**{**cells[0].__dict__, "episodes": 16})  # the folder's run is longer than this cell
    with pytest.raises(ValueError, match="holds another run than the sweep's cell .*episodes: 32 there, 16 here"):
        cell_status(str(tmp_path), shorter)
    other = type(cells[0])(**{**cells[0].__dict__, "method": dataclasses.replace(
        cells[0].method, overrides=cells[0].method.overrides + (("lr", 1e-3),))})
    with pytest.raises(ValueError, match="holds another run than the sweep's cell .*lr: "):
        cell_status(str(tmp_path), other)


def test_a_run_started_under_another_divergence_guard_is_the_cells_and_resumes_under_its_own(tmp_path, monkeypatch):
    calls, lines = [], []
    _fake_runs(monkeypatch, calls)
    cells = plan("ablation", "smoke", only="overcooked-B/tomacvf/")
    run_sweep(cells, str(tmp_path), log=lambda *_: None)
    watched = type(cells[0])(**{**cells[0].__dict__, "method": dataclasses.replace(
        cells[0].method, overrides=cells[0].method.overrides + (("divergence_margin", 0.5),
                                                                  ("divergence_guard", False)))})
    assert cell_status(str(tmp_path), watched) == "done"  # the guard never changes what the run computed
    os.remove(os.path.join(str(tmp_path), cells[0].path, "summary.json"))  # killed before it finished
    calls.clear()
    assert run_sweep([watched], str(tmp_path), log=lines.append) == {watched.path: "resumed"}
    margin = cells[0].config().divergence_margin
    assert f"[1/1] {watched.path}: goes on under the divergence guard its run started with (divergence_guard=True " \
           f"there, False here; divergence_margin={margin!r} there, 0.5 here)" in lines
    assert calls == [("resume", os.path.join(str(tmp_path), cells[0].path))]  # resumed exactly: its own config.json


def test_a_cell_whose_run_trained_a_smaller_budget_is_extended(tmp_path, monkeypatch):
    # e.g. a run trained to 80K episodes where the protocol's cell asks for 100K: resumed with the larger budget
    calls = []
    _fake_runs(monkeypatch, calls)
    cells = plan("ablation", "smoke", only="overcooked-B/tomacvf/")
    run_sweep(cells, str(tmp_path), log=lambda *_: None)
    longer = type(cells[0])(**{**cells[0].__dict__, "episodes": 64})
    assert cell_status(str(tmp_path), longer) == "shorter"
    calls.clear()
    assert run_sweep([longer], str(tmp_path), log=lambda *_: None) == {longer.path: "extended"}
    assert calls == [("resume", str(tmp_path / longer.path), 64)]
    attempts = (tmp_path / longer.path / "attempts.jsonl").read_text().splitlines()
    assert json.loads(attempts[-1])["action"] == "extend"


def test_seeds_that_existing_ranges_hold_are_taken_from_them_not_trained_twice(tmp_path, monkeypatch):
    # a cell run as two halves (--seeds 0:2 and 2:4, e.g. one process per core), then the sweep asked for seeds 0-3
    from jaxmac.study.sweep import fit_to_existing

    calls = []
    _fake_runs(monkeypatch, calls)
    out = str(tmp_path)
    first_half = plan("ablation", "smoke", seeds=(0, 2), only="overcooked-B/tomacvf/")
    run_sweep(first_half, out, log=lambda *_: None)
    four = plan("ablation", "smoke", seeds=(0, 4), only="overcooked-B/tomacvf/")
    fitted = fit_to_existing(four, out)
    assert [c.path for c in fitted] == ["overcooked-B/tomacvf/seeds0-2", "overcooked-B/tomacvf/seeds2-4"]
    assert [(c.first_seed, c.seeds) for c in fitted] == [(0, 2), (2, 2)] and fitted[0].config() == four[0].config()
    calls.clear()
    assert run_sweep(fitted, out, log=lambda *_: None) == {fitted[0].path: "skipped", fitted[1].path: "trained"}
    assert calls == [("train", str(tmp_path / fitted[1].path))]
    assert [c.path for c in fit_to_existing(four, out)] == [c.path for c in fitted]  # now both halves are done
    # seeds 4-7 are a new range of their own; seeds 1-4 would split seeds0-2 and are refused, naming it
    assert [c.path for c in fit_to_existing(plan("ablation", "smoke", seeds=(4, 4), only="overcooked-B/tomacvf/"),
                                            out)] == ["overcooked-B/tomacvf/seeds4-8"]
    with pytest.raises(ValueError, match=r"seeds0-2 holds seeds that another range or the asked seeds 1..4 only "
                                         r"partly hold; ask for seeds that the existing ranges \[\(0, 2\), \(2, 4\)\]"):
        fit_to_existing(plan("ablation", "smoke", seeds=(1, 4), only="overcooked-B/tomacvf/"), out)


def test_a_real_cell_runs_then_is_skipped(tmp_path):
    cells = plan("bp", "smoke", only="boxpushing-6x6/tomacvf/")
    assert run_sweep(cells, str(tmp_path), progress=False, log=lambda *_: None) == {cells[0].path: "trained"}
    summary = json.loads((tmp_path / cells[0].path / "summary.json").read_text())
    assert summary["episodes"] == 32 and summary["seeds"] == 1
    assert run_sweep(cells, str(tmp_path), progress=False, log=lambda *_: None) == {cells[0].path: "skipped"}


def test_cost_estimates_use_the_cells_own_rate_else_the_nearest_measured_scenario():
    from jaxmac.study.sweep import estimate_seconds, method_by_name

    rates = {"tomacvf@boxpushing-6x6": {"episodes_per_s": 20.0},
             "tomacvf@boxpushing-14x14": {"episodes_per_s": 5.0},
             "mac_cac@overcooked-B": {"episodes_per_s": 40.0}}
    cells = {c.path.split("/seeds")[0]: c for c in plan("bp", "cpu") + plan("overcooked", "cpu")}
    own = cells["boxpushing-6x6/tomacvf"]
    assert estimate_seconds(own, rates) == (own.seeds * own.episodes / 20.0, "tomacvf@boxpushing-6x6")
    # 12x12 is nearer 14x14 than 6x6; 8x8 nearer 6x6
    assert estimate_seconds(cells["boxpushing-12x12/tomacvf"], rates)[1] == "tomacvf@boxpushing-14x14"
    assert estimate_seconds(cells["boxpushing-8x8/tomacvf"], rates)[1] == "tomacvf@boxpushing-6x6"
    assert estimate_seconds(cells["overcooked-A/mac_cac"], rates)[1] == "mac_cac@overcooked-B"
    assert estimate_seconds(cells["overcooked-A/mac_iaicc"], rates) is None  # not measured anywhere
    # a whole run's rate beats a first-chunks rate (episodes at epsilon ~ 1 last to the time limit), even the cell's own
    rates = {"mac_cac@warehouse-E": {"episodes_per_s": 9.0, "chunks": 1},
             "mac_cac@warehouse-B": {"episodes_per_s": 300.0, "chunks": 1},
             "mac_cac@warehouse-C": {"episodes_per_s": 220.0, "source": "a whole run"},
             "mac_cac@warehouse-A": {"episodes_per_s": 250.0, "source": "a whole run"}}
    cells = {c.path.split("/seeds")[0]: c for c in plan("warehouse", "full")}
    wh_e = cells["warehouse-E/mac_cac"]
    assert estimate_seconds(wh_e, rates) == (wh_e.seeds * wh_e.episodes / 220.0, "mac_cac@warehouse-C")
    assert estimate_seconds(cells["warehouse-B/mac_cac"], rates)[1] == "mac_cac@warehouse-A"
    del rates["mac_cac@warehouse-C"], rates["mac_cac@warehouse-A"]  # first chunks only: the nearest, own first
    assert estimate_seconds(wh_e, rates)[1] == "mac_cac@warehouse-E"
    assert estimate_seconds(cells["warehouse-C/mac_cac"], rates)[1] == "mac_cac@warehouse-B"
    assert method_by_name("tomacvf-wo-sjert").overrides[0] == ("buffer", "mac_jert")
    with pytest.raises(ValueError, match="unknown method 'qmix'.*tomacvf-qplex"):
        method_by_name("qmix")


def test_the_cpu_protocol_shortens_budgets_and_schedules_in_proportion_and_says_what_it_leaves_out():
    from jaxmac.presets import scenario_config
    from jaxmac.study.sweep import not_run_cells

    cells = {c.path.split("/seeds")[0]: c for c in plan("overcooked", "cpu")}
    cell = cells["overcooked-A/tomacvf"]
    paper = scenario_config("overcooked-A")
    config = cell.config()
    fraction = config.episodes / paper.episodes
    assert config.episodes < paper.episodes and fraction == cell.episodes / paper.episodes
    assert config.eps_decay_episodes == round(paper.eps_decay_episodes * fraction)
    assert config.lr == paper.lr and config.target_update_episodes == paper.target_update_episodes
    iaicc = cells["overcooked-A/mac_iaicc"].config()
    assert iaicc.eps_decay_episodes == round(scenario_config("overcooked-A", "mac_iaicc").eps_decay_episodes * fraction)
    assert "overcooked-A/maccen_ddrqn" not in cells and "overcooked-A/macdec_ddrqn" not in cells
    left_out = not_run_cells("overcooked", "cpu")
    assert {(s, m) for s, m, _ in left_out} == {(s, m) for s in ("overcooked-A", "overcooked-B", "overcooked-C")
                                                 for m in ("maccen_ddrqn", "macdec_ddrqn", "avf")}
    assert all("per cell" in why for _, _, why in left_out)
    # the paper protocol changes nothing but the seeds
    paper_cell = [c for c in plan("overcooked", "paper") if c.path.startswith("overcooked-A/tomacvf/")][0]
    assert paper_cell.config() == paper and paper_cell.seeds == 20


def test_a_started_cell_is_costed_at_the_rate_it_has_trained_at(tmp_path, capsys):
    from jaxmac.cli import main
    from jaxmac.study.results_page import progress_text
    from jaxmac.study.stats import RangeProgress, own_rate

    cell = plan("bp", "smoke", only="boxpushing-6x6/tomacvf/")[0]  # 1 seed x 32 episodes
    run = tmp_path / cell.path
    run.mkdir(parents=True)
    config = cell.config()
    meta = {"config": config.to_dict(), "seeds": 1, "seed_offset": 0, "rounds_per_chunk": 1}
    (run / "config.json").write_text(json.dumps(meta))
    assert own_rate(str(run)) is None  # no checkpoint yet
    (run / "metrics.csv").write_text(f"seed,round,episodes\n0,0,{config.num_envs}\n")
    (run / "progress.json").write_text(json.dumps({"chunks_done": 1, "wall_seconds": 20.0}))
    assert own_rate(str(run)) is None  # 20 s is mostly compilation: not yet a pace to cost the rest at
    assert own_rate(str(run), min_seconds=20.0) == pytest.approx(config.num_envs / 20.0)  # one chunk of one round
    (run / "progress.json").write_text(json.dumps({"chunks_done": 1, "wall_seconds": 1200.0}))
    assert own_rate(str(run)) == pytest.approx(config.num_envs / 1200.0)
    (run / "attempts.jsonl").write_text(json.dumps({"devices": ["cpu:0"]}) + "\n"
                                        + json.dumps({"devices": ["cpu:0", "cpu:1"]}) + "\n")
    rate = own_rate(str(run))
    assert rate == pytest.approx(config.num_envs / 2400.0)  # core-seconds: the widest attempt used two cores
    left = 32 - config.num_envs
    assert main(["sweep", "bp", "--protocol", "smoke", "--only", "boxpushing-6x6/tomacvf/", "--dry-run",
                 "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"interrupted at {config.num_envs}, ~{left / rate / 3600:.1f} core-h left (its own rate so far)" in out
    assert "(1 started cell at its own rate so far)" in out
    # the results page: a range with a rate is costed at it, one without at the method's measured rate
    rates = {"tomacvf@overcooked-B": {"episodes_per_s": 0.1}}
    ranges = [RangeProgress("seeds0-2", 2, 100, 1000, rate=0.5)]  # 1,800 seed-episodes at 0.5 per s: 3,600 s
    assert progress_text(ranges, "overcooked-B", "tomacvf", rates) == (
        "100 of 1,000 episodes per seed (seeds 0–1); ~1.0 core-hours left at its own rate so far")
    ranges.append(RangeProgress("seeds2-4", 2, 820, 1000))  # 360 seed-episodes at 0.1 per s: 3,600 s
    assert progress_text(ranges, "overcooked-B", "tomacvf", rates).endswith(
        "; ~2.0 core-hours left at its own rate so far and the rate measured for tomacvf@overcooked-B")
