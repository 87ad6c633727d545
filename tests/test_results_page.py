"""The results page of a sweep from tiny fake run folders: figure, tables, "not run" cells, aggregates, and what a
page of fewer than 2 seeds per cell refuses to say (``jaxmac results``)."""

from __future__ import annotations

import json
import pathlib
import re

from test_stats import _fake_run

from jaxmac.study.results_page import write_page


def test_results_page_from_run_folders(tmp_path):
    sweep = tmp_path / "sweep"
    for s in ("overcooked-B", "warehouse-E"):
        for m, base in (("tomacvf", 140.0), ("tomacvf-wo-atpg", 100.0), ("tomacvf-wo-sjert", 90.0),
                        ("tomacvf-wo-both", 60.0)):
            _fake_run(sweep / s / m / "seeds0-2", 0, [base, base + 10])
    _fake_run(sweep / "overcooked-A" / "tomacvf" / "seeds0-2", 0, [150.0, 160.0])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["ablation", "mixers"])).read_text()
    assert (tmp_path / "out" / "ablation.png").stat().st_size > 5000 and (tmp_path / "out" / "ablation.pdf").exists()
    assert "| ToMacVF | 2 | 96 | **145.0 ± 5.0** |" in page  # the best mean in bold
    assert "| ToMacVF w/o ATPG | 2 | 96 | 105.0 ± 5.0 |" in page
    # two seeds 10 apart each: 145 vs 105 gives Welch p ≈ 0.03, so every other method is told apart
    assert "Who wins: **ToMacVF**; every other method is below it (Welch's p < 0.05)." in page
    # the headline: one row per scenario, the fraction of the ceiling (overcooked-B: 149.8), unfinished cells "…"
    assert "| ablation | overcooked-B | **145.0 (97 %)** | 105.0 (70 %) | 95.0 (63 %) | 65.0 (43 %) |" in page
    assert "| mixers | overcooked-A | **155.0 (94 %)** | … | … | … |" in page
    # the four questions, from the same cells: ToMacVF minus each ablation (Welch's p of 145±5 against 105±5: 0.030)
    assert "- overcooked-B: +40.0 (p 0.030)" in page.split("Does ATPG help?")[1].split("**3.")[0]
    assert "- overcooked-B: +50.0 (p 0.019)" in page.split("Mac-SJERT help")[1].split("**4.")[0]
    assert ("- Verdict: ToMacVF above ToMacVF w/o ATPG, told apart, on 2 of 2 scenarios; below it, told apart, on 0."
            in page)
    assert "- no scenario with all four mixers finished yet" in page
    assert "| ToMacVF_VDN | not finished yet |" in page  # the mixers experiment has only ToMacVF (QMIX) on Overcooked-A
    # a lone finished cell wins nothing: no "every other method is below it" over methods that have not run
    overcooked_a = page.split("## mixers")[1].split("**overcooked-A**")[1]
    assert "Who wins: not decided; only ToMacVF_QMIX has finished." in overcooked_a
    assert "IQM" in page.split("## mixers")[0] and "not every method has finished" in page.split("## mixers")[1]


def test_cells_a_protocol_leaves_out_are_listed_with_the_reason(tmp_path):
    sweep = tmp_path / "cpu"
    _fake_run(sweep / "overcooked-A" / "tomacvf" / "seeds0-2", 0, [150.0, 160.0])
    _fake_run(sweep / "overcooked-A" / "mac_cac" / "seeds0-2", 0, [20.0, 30.0])
    _fake_run(sweep / "overcooked-B" / "tomacvf" / "seeds0-2", 0, [10.0, 20.0])
    _fake_run(sweep / "overcooked-B" / "mac_iaicc" / "seeds0-2", 0, [100.0, 110.0])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["overcooked"])).read_text()
    assert ("- ToMacVF, 2 scenarios with baselines finished: best mean on 1 (overcooked-A); not told apart from the best "
            "on 0; below the best, told apart, on 1 (overcooked-B (Mac-IAICC)).") in page
    assert "| Mac-Cen-DDRQN | not run: a step over 64 episodes" in page  # the folder name is the protocol
    # a cell the protocol plans that no run has begun: its budget (the cpu protocol's 4 seeds x 2,000 episodes)
    assert "| Mac-IAICC | not started: 4 seeds × 2,000 episodes |" in page.split("**overcooked-A**")[1]
    assert "**Not started: 11 cells** the protocol plans (their costs need measured rates" in page
    assert "| overcooked | overcooked-C/mac_iaicc/seeds0-4 | 4 × 2,000 | no rates given |" in page
    assert "| overcooked | overcooked-A | **155.0 (94 %)** | … | 25.0 (15 %) | … | … | n.r. | n.r. | n.r. |" in page


def test_aggregates_leave_out_the_methods_a_protocol_does_not_run(tmp_path):
    # cpu leaves the value baselines out on Overcooked: the aggregates run over the five methods that ran everywhere
    sweep = tmp_path / "cpu"
    for i, s in enumerate(("overcooked-A", "overcooked-B", "overcooked-C")):
        for j, m in enumerate(("tomacvf", "tomacvf-paper", "mac_cac", "mac_iaicc", "mac_niacc")):
            _fake_run(sweep / s / m / "seeds0-2", 0, [10.0 * j + i, 10.0 * j + i + 5])
    overcooked = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["overcooked"])).read_text()
    aggregates = overcooked.split("## overcooked")[1].split("Aggregates")[1]
    assert "without Mac-Dec-MADDRQN, Mac-Cen-DDRQN, AVF, not run on every scenario under this protocol" in aggregates
    for label in ("ToMacVF", "ToMacVF (paper's settings)", "Mac-CAC", "Mac-IAICC", "Mac-NIACC"):
        assert f"\n| {label} | " in aggregates
    assert "| AVF |" not in aggregates
    # one runnable cell missing: no aggregates yet
    (sweep / "overcooked-C" / "mac_niacc" / "seeds0-2" / "summary.json").unlink()
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out2"), ["overcooked"])).read_text()
    assert "Aggregates: not every method has finished every scenario yet." in page


def test_the_mixer_question_names_the_winner_told_apart(tmp_path):
    sweep = tmp_path / "sweep"
    for m, base in (("tomacvf", 150.0), ("tomacvf-vdn", 10.0), ("tomacvf-qplex", 20.0), ("tomacvf-qtran", 0.0)):
        _fake_run(sweep / "overcooked-A" / m / "seeds0-2", 0, [base, base + 10])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["mixers"])).read_text()
    mixer_answer = page.split("**4. Which mixer")[1].split("## mixers")[0]
    assert "- overcooked-A: **ToMacVF_QMIX**; the others told apart below it" in mixer_answer
    assert "- Verdict: ToMacVF_QMIX is best and told apart from the other three on 1 of 1 scenarios." in mixer_answer


_ABLATION = (("tomacvf", 140.0), ("tomacvf-wo-atpg", 100.0), ("tomacvf-wo-sjert", 90.0), ("tomacvf-wo-both", 60.0))
_EVERY_EXPERIMENT = ["bp", "warehouse", "overcooked", "ablation", "mixers"]


def _ablation_sweep(sweep: pathlib.Path, first: int, points: int = 12, skip: tuple[str, str] | None = None) -> None:
    """One seed (``first``) of each ablation cell, a range folder ``seeds<first>-<first + 1>`` per cell."""
    for s in ("overcooked-B", "warehouse-E"):
        for m, base in _ABLATION:
            if (s, m) != skip:
                _fake_run(sweep / s / m / f"seeds{first}-{first + 1}", first, [base + 10 * first], points=points)


def test_a_one_seed_sweep_names_no_winner_and_says_why(tmp_path, monkeypatch):
    import jaxmac.study.results_page as results_page

    figures = {}
    real_save = results_page.save_figure
    monkeypatch.setattr(results_page, "save_figure",
                        lambda fig, path, pdf=False: (figures.__setitem__(path, fig), real_save(fig, path, pdf)))
    sweep = tmp_path / "smoke"  # the folder jaxmac sweep --protocol smoke writes by default
    _ablation_sweep(sweep, 0, points=1)
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), _EVERY_EXPERIMENT)).read_text()
    head = page.split("## Headline")[0]
    # the header: the protocol and where it was read, the finished cells, their seeds and budgets, the unrun
    assert "**Protocol: smoke** (the sweep folder's name): 1 seed, 32 episodes, tiny networks" in head
    assert "**Finished cells: 8** of the 109 this protocol plans" in head
    assert "**seeds per cell: 1**; episodes per seed: 96 on every cell." in head
    assert "Not run (no finished cell): bp." in head and "## bp" not in page
    assert "| bp |" not in page.split("## Cells not started")[0]  # no headline row; its cells in the closing table:
    assert "| bp | boxpushing-6x6/mac_cac/seeds0-1 | 1 × 32 | no rates given |" in page.split("## Cells not started")[1]
    assert "every finished cell has fewer than 2 seeds" in head
    assert "a winner, an interval and a test need at least 2 seeds per method" in head
    # no winner, no test, no interval, no bold "best" anywhere; one reason per scenario instead
    assert "who wins" not in page.lower() and "**140.0" not in page
    assert "(p " not in page and not re.search(r"\| (\d\.\d{3}|<0\.001) \|", page)
    assert "| ToMacVF w/o ATPG | 1 | 96 | 100.0 | n = 1: no interval | 67 % | never | n = 1: no test | 0 min |" in page
    reason = "No winner, interval or test here: every method has one seed, and a winner and a test need at least 2 "
    assert page.split("## ablation")[1].count(reason) == 2
    # the paper's questions: not answered; aggregates: not computed
    assert "- overcooked-B: not answered: fewer than 2 seeds (ToMacVF 1, ToMacVF w/o ATPG 1)" in page
    assert page.count("- Verdict: not answered: fewer than 2 seeds.") == 2
    assert "Aggregates: not computed: some cells have fewer than 2 seeds" in page
    # scenarios no method has finished: one line, not tables or headline rows of "…"
    assert "No method has finished on warehouse-A, warehouse-B, warehouse-C, warehouse-D yet." in page
    assert "| warehouse | warehouse-A |" not in page and "**warehouse-A**" not in page
    # one evaluation point per curve: markers, not invisible one-point lines
    ax = figures[str(tmp_path / "out" / "ablation") + ".png"].axes[0]
    assert [(c.get_label(), c.lines[0].get_marker()) for c in ax.containers] == [
        ("ToMacVF", "o"), ("ToMacVF w/o ATPG", "o"), ("ToMacVF w/o Mac-SJERT", "o"),
        ("ToMacVF w/o ATPG and Mac-SJERT", "o")]


def test_a_second_seed_brings_the_winner_and_the_tests_back(tmp_path):
    sweep = tmp_path / "smoke"
    _ablation_sweep(sweep, 0)
    _ablation_sweep(sweep, 1, skip=("warehouse-E", "tomacvf-wo-atpg"))  # that cell keeps one seed
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["ablation"])).read_text()
    head = page.split("## Headline")[0]
    assert "**Finished cells: 8** of the 8 this protocol plans" in head
    assert "**seeds per cell: 1–2 (min–max)**" in head and "1 of 8 cells have fewer than 2 seeds" in head
    overcooked_b, warehouse_e = page.split("## ablation")[1].split("**warehouse-E**")
    # two seeds 10 apart each: 145 vs 105 gives Welch p ≈ 0.03 (as in test_results_page_from_run_folders)
    assert "Who wins: **ToMacVF**; every other method is below it (Welch's p < 0.05)." in overcooked_b
    assert "| ToMacVF w/o ATPG | 2 | 96 | 105.0 ± 5.0 | [100.0, 110.0] | 70 % | never | 0.030 | 0 min |" in overcooked_b
    assert "Who wins" not in warehouse_e.split("Aggregates")[0]
    assert "No winner, interval or test here: ToMacVF w/o ATPG has one seed" in warehouse_e
    assert "| ToMacVF w/o Mac-SJERT | 2 | 96 | 95.0 ± 5.0 | [90.0, 100.0] | 9 % | never | 0.019 | 0 min |" in warehouse_e
    questions = page.split("**2. Does ATPG help?**")[1].split("**3.")[0]
    assert "- overcooked-B: +40.0 (p 0.030)" in questions
    assert "- warehouse-E: not answered: fewer than 2 seeds (ToMacVF 2, ToMacVF w/o ATPG 1)" in questions
    assert "- Verdict: ToMacVF above ToMacVF w/o ATPG, told apart, on 1 of 1 scenarios" in questions
    assert "| ablation | overcooked-B | **145.0 (97 %)** |" in page and "| ablation | warehouse-E | 145.0" in page


def test_the_protocol_is_read_from_the_cells_configurations(tmp_path):
    from jaxmac.study.results_page import find_protocol
    from jaxmac.study.stats import load_sweep
    from jaxmac.study.sweep import plan

    sweep = tmp_path / "my-sweep"
    cell = next(c for c in plan("ablation", "smoke") if c.path == "overcooked-B/tomacvf/seeds0-1")
    _fake_run(sweep / cell.path, 0, [140.0], budget=cell.episodes)
    assert find_protocol(str(sweep), load_sweep(str(sweep)))[0] is None  # no configuration to read
    (sweep / cell.path / "config.json").write_text(json.dumps({"config": cell.config().to_dict()}))
    assert find_protocol(str(sweep), load_sweep(str(sweep))) == ("smoke", "the cells' configurations match it")
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["ablation"])).read_text()
    assert "**Protocol: smoke** (the cells' configurations match it)" in page


def test_jaxmac_results_writes_beside_the_sweep_by_default(tmp_path, capsys):
    from jaxmac.cli import main

    sweep = tmp_path / "smoke"
    _ablation_sweep(sweep, 0)
    assert main(["results", str(sweep), "--out", str(tmp_path / "page"), "--experiments", "ablation"]) == 0
    assert f"wrote {tmp_path / 'page' / 'RESULTS.md'}" in capsys.readouterr().out
    assert "**Protocol: smoke**" in (tmp_path / "page" / "RESULTS.md").read_text()
    # default: SWEEP_DIR/results, outside the package tree; a second run reads the sweep with its page inside
    for _ in range(2):
        assert main(["results", str(sweep), "--experiments", "ablation"]) == 0
        assert f"wrote {sweep / 'results' / 'RESULTS.md'}" in capsys.readouterr().out
    assert (sweep / "results" / "ablation.png").exists()
    assert main(["results", str(tmp_path / "nowhere")]) == 2
    assert "no such sweep folder" in capsys.readouterr().err


def test_cells_that_ended_early_or_are_still_running_say_how_far_they_got(tmp_path):
    # the full protocol: a seed range may end before its budget (summary.json's ended_early), another still runs
    sweep = tmp_path / "full"
    done = sweep / "overcooked-B" / "tomacvf" / "seeds0-2"
    _fake_run(done, 0, [140.0, 150.0])  # 12 evaluations, the last 10 at the final level: 90 % reached at 96
    summary = json.loads((done / "summary.json").read_text())
    (done / "summary.json").write_text(json.dumps(summary | {"ended_early": "settled at 96 episodes per seed"}))
    (done / "config.json").write_text(json.dumps({"config": {"episodes": 200}}))
    running = sweep / "overcooked-B" / "tomacvf" / "seeds2-4"
    running.mkdir(parents=True)
    (running / "config.json").write_text(json.dumps({"config": {"episodes": 200}}))
    (running / "metrics.csv").write_text("seed,round,episodes,eval_disc_return,eval_return\n"
                                         "2,0,8,1,1\n3,0,8,1,1\n2,1,48,1,1\n3,1,40,1,1\n")
    _fake_run(sweep / "overcooked-B" / "mac_iaicc" / "seeds0-2", 0, [140.0, -100.0])  # one seed never reaches 90 %
    idle = sweep / "overcooked-C" / "mac_cac" / "seeds0-2"
    idle.mkdir(parents=True)
    (idle / "config.json").write_text(json.dumps({"config": {"episodes": 100}}))
    rates = {"tomacvf@overcooked-B": {"episodes_per_s": 0.08}}  # 2 seeds x 160 episodes left: 4,000 s
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["overcooked"], rates=rates)).read_text()
    table = page.split("**overcooked-B** (ceiling")[1].split("**overcooked-C**")[0]
    assert "| ToMacVF | 2 | 96 of 200 (ended early) | **145.0 ± 5.0** |" in table
    assert "| 97 % | 96 | – |" in table  # the fraction of the ceiling (149.8), then the episodes to 90 % of it
    assert "| 13 % | 96 (1 of 2 seeds) |" in table  # Mac-IAICC: mean 20 of 149.8
    progress = "40 of 200 episodes per seed (seeds 2–3); ~1.1 core-hours left at the rate measured for tomacvf@overcooked-B"
    assert f"More seeds not finished yet (the rows above are the finished seeds only): ToMacVF: {progress}." in table
    assert "- overcooked-B/tomacvf/seeds0-2: settled at 96 episodes per seed" in page.split("## Headline")[0]
    assert f"- overcooked-B/tomacvf: {progress}" in page.split("## Headline")[0]
    # a cell that has not logged an episode yet, on a map no method finished, with no measured rate
    assert "- overcooked-C/mac_cac: 0 of 100 episodes per seed (seeds 0–1)\n" in page
    assert "| Mac-CAC | not finished yet: 0 of 100 episodes per seed (seeds 0–1) |" in page.split("**overcooked-C**")[1]
    # cells no run has begun: their cost at the measured rate of the nearest map (4 seeds x 100K / 0.08 per s), or why
    # there is none; the header counts them, a closing table lists them
    overcooked_c = page.split("**overcooked-C**")[1]
    assert ("| ToMacVF | not started: 4 seeds × 100,000 episodes, ~1389 core-hours at the rate measured for "
            "tomacvf@overcooked-B |") in overcooked_c
    assert "| Mac-NIACC | not started: 4 seeds × 100,000 episodes, no rate measured for mac_niacc |" in overcooked_c
    assert ("**Not started: 9 cells** the protocol plans (~2778 core-hours at the measured rates, 7 cells without a "
            "measured rate not counted;") in page.split("## Headline")[0]
    closing = page.split("## Cells not started")[1]
    assert "| overcooked | overcooked-A/tomacvf/seeds0-4 | 4 × 100,000 | ~1389 core-hours at the rate" in closing
    assert "overcooked-B/tomacvf/" not in closing and "overcooked-C/mac_cac/" not in closing  # finished or begun


def test_a_scenario_the_protocol_leaves_out_says_so_instead_of_waiting(tmp_path):
    # the full protocol runs the ablation on Overcooked-B only: warehouse-E is not "not finished yet" but not run
    sweep = tmp_path / "full"
    _fake_run(sweep / "overcooked-B" / "tomacvf" / "seeds0-2", 0, [140.0, 150.0])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["ablation"])).read_text()
    ablation = page.split("## ablation")[1].split("## Cells not started")[0]
    assert "Not run on warehouse-E under this protocol: ablation on Overcooked-B only in this protocol." in ablation
    assert "No method has finished on warehouse-E" not in page
    assert "| ToMacVF w/o ATPG | not started: 4 seeds × 120,000 episodes |" in ablation
    # the mixers run on Overcooked-A only: the finished ToMacVF cells of B and C (the baselines comparison's) make no
    # mixers table, headline row, figure panel or aggregate there
    _fake_run(sweep / "overcooked-C" / "tomacvf" / "seeds0-2", 0, [120.0, 130.0])
    _fake_run(sweep / "overcooked-A" / "tomacvf" / "seeds0-2", 0, [150.0, 160.0])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["mixers"])).read_text()
    mixers = page.split("## mixers")[1].split("## Cells not started")[0]
    assert ("Not run on overcooked-B, overcooked-C under this protocol: the mixers on Overcooked-A only in this "
            "protocol.") in mixers
    assert "**overcooked-A**" in mixers and "**overcooked-B**" not in mixers and "**overcooked-C**" not in mixers
    assert "| mixers | overcooked-A |" in page and "| mixers | overcooked-B |" not in page
    assert "Aggregates: not every method has finished every scenario yet." in mixers


def test_an_experiment_whose_finished_cells_are_all_on_scenarios_it_leaves_out_has_no_section(tmp_path):
    # ToMacVF's Overcooked-C cell belongs to the baselines comparison; the full protocol runs the mixers on A only, so
    # the mixers have nothing to show yet: no section, no headline row, named in the header's "Not run" line
    sweep = tmp_path / "full"
    _fake_run(sweep / "overcooked-C" / "tomacvf" / "seeds0-2", 0, [120.0, 130.0])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["mixers"], protocol="full")).read_text()
    shown = page.split("## Cells not started")[0]  # the closing list of cells not begun names every experiment
    assert "## mixers" not in shown and "| mixers |" not in shown
    assert "Not run (no finished cell): mixers." in page.split("## Headline")[0]
    assert "No finished cell yet." in page


def test_question_one_weighs_the_claim_and_who_got_to_90_percent_first(tmp_path):
    # Overcooked-A: ToMacVF has the best mean but Welch's test cannot tell it from Mac-IAICC, which also got to 90 %
    # of the ceiling (147.9) sooner (its 10 last evaluations start 4 points earlier); Overcooked-B: ToMacVF is best,
    # told apart, and the only one there
    sweep = tmp_path / "full"
    _fake_run(sweep / "overcooked-A" / "tomacvf" / "seeds0-2", 0, [155.0, 165.0], points=16, budget=128)
    _fake_run(sweep / "overcooked-A" / "mac_iaicc" / "seeds0-2", 0, [150.0, 160.0])
    _fake_run(sweep / "overcooked-A" / "mac_cac" / "seeds0-2", 0, [20.0, 30.0])
    _fake_run(sweep / "overcooked-B" / "tomacvf" / "seeds0-2", 0, [140.0, 150.0])
    _fake_run(sweep / "overcooked-B" / "mac_iaicc" / "seeds0-2", 0, [100.0, 110.0])
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["overcooked"])).read_text()
    question = page.split("**1.")[1].split("**2.")[0]
    assert "best mean on 2 (overcooked-A, overcooked-B)" in question
    assert ("  - Episodes to 90 % of the ceiling, ToMacVF against the baseline that got there first: overcooked-A 128 vs "
            "Mac-IAICC 96; overcooked-B 96 vs never (every baseline).") in question
    assert ("  - Verdict: the paper's claim that ToMacVF beats every baseline holds (best mean, told apart from every "
            "baseline) on 1 of 2 scenarios (overcooked-B); ToMacVF gets to 90 % of the ceiling first (on more of its "
            "seeds, or on as many and sooner) on 1 of 2 (overcooked-B).") in question


def test_a_cell_the_divergence_guard_stopped_is_reported_as_diverged_and_costs_nothing_more(tmp_path):
    sweep = tmp_path / "full"
    _fake_run(sweep / "overcooked-B" / "tomacvf" / "seeds0-2", 0, [140.0, 150.0])
    stopped = sweep / "overcooked-B" / "tomacvf-wo-sjert" / "seeds0-2"
    stopped.mkdir(parents=True)
    (stopped / "config.json").write_text(json.dumps({"config": {"episodes": 200}}))
    (stopped / "metrics.csv").write_text("seed,round,episodes,eval_disc_return,eval_return\n"
                                         "0,0,8,1,1\n1,0,8,1,1\n0,1,16,1,1\n1,1,16,1,1\n")
    problem = "seed 1, round 1 (episode 16): q_tot_mean = 900.0 is outside [-20.0, 241.5]"
    (stopped / "diverged.json").write_text(json.dumps({"problem": problem, "kind": "value out of bounds",
                                                       "chunk": 1, "last_good_checkpoint": None}))
    rates = {"tomacvf-wo-sjert@overcooked-B": {"episodes_per_s": 0.08}}
    page = pathlib.Path(write_page(str(sweep), str(tmp_path / "out"), ["ablation"], rates=rates)).read_text()
    diverged = (f"**diverged** at 16 of 200 episodes per seed (seeds 0–1; the divergence guard stopped it: "
                f"{problem})")
    assert f"| ToMacVF w/o Mac-SJERT | {diverged} |" in page.split("**overcooked-B** (ceiling")[1]
    assert f"- overcooked-B/tomacvf-wo-sjert: {diverged}\n" in page.split("## Headline")[0]
    assert "core-hours left" not in page.split("## Headline")[0]  # nothing to resume, so nothing it still costs
