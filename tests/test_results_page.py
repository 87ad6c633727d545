"""The results page of a sweep from tiny fake run folders: figure, tables, "not run" cells, aggregates."""

from __future__ import annotations

import sys
import pathlib

from test_stats import _fake_run

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "experiments"))
from results_page import write_page  # noqa: E402


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
    assert "| Mac-IAICC | not finished yet |" in page.split("**overcooked-A**")[1]
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
