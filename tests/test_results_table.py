"""``jaxmac table`` (jaxmac/study/results_table.py): mean, standard error, fraction of optimal and changed settings
per run."""

from __future__ import annotations

import json
import pathlib

from jaxmac.cli import main
from jaxmac.presets import scenario_config
from jaxmac.study import results_table


def _fake_run(path: pathlib.Path, returns: list[float], **changes) -> pathlib.Path:
    path.mkdir()
    config = scenario_config("boxpushing-6x6").override(episodes=800, **changes)
    (path / "config.json").write_text(json.dumps({"config": config.to_dict()}))
    (path / "summary.json").write_text(json.dumps({
        "scenario": "boxpushing-6x6", "seeds": len(returns), "episodes": 800, "wall_seconds": 120.0,
        "optimal_return": 270.605, "final_greedy_return": returns}))
    return path


def test_rows_report_mean_standard_error_and_changed_settings(tmp_path):
    a = _fake_run(tmp_path / "a", [260.0, 270.0], updates_per_round=4)
    b = _fake_run(tmp_path / "b", [37.26])
    header, rule, row_a, row_b = results_table.table_rows([a, b])
    assert header.count("|") == rule.count("|")
    cells = [c.strip() for c in row_a.strip("|").split("|")]
    assert cells[:6] == ["boxpushing-6x6", "tomacvf", "2", "800", "265.0 ± 5.0", "260.0 270.0"]
    assert cells[7] == "98%" and cells[8] == "updates_per_round=4" and cells[9] == "2 min"
    cells = [c.strip() for c in row_b.strip("|").split("|")]
    assert cells[4] == "37.3 ± –" and cells[8] == "defaults"


def test_a_baseline_is_compared_with_its_own_defaults(tmp_path):
    run = tmp_path / "cen"
    run.mkdir()
    config = scenario_config("boxpushing-6x6", "maccen_ddrqn").override(episodes=800, rnn_size=32)
    (run / "config.json").write_text(json.dumps({"config": config.to_dict()}))
    (run / "summary.json").write_text(json.dumps({
        "scenario": "boxpushing-6x6", "algorithm": "maccen_ddrqn", "seeds": 1, "episodes": 800, "wall_seconds": 60.0,
        "optimal_return": 270.605, "final_greedy_return": [270.6]}))
    cells = [c.strip() for c in results_table.table_rows([run])[2].strip("|").split("|")]
    assert cells[1] == "maccen_ddrqn" and cells[8] == "rnn_size=32"


def test_jaxmac_table_prints_the_rows_and_names_an_unfinished_run(tmp_path, capsys):
    a = _fake_run(tmp_path / "a", [260.0, 270.0])
    assert main(["table", str(a)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("| scenario | algorithm |") and out[2].startswith("| boxpushing-6x6 | tomacvf | 2 |")
    (tmp_path / "half").mkdir()
    assert main(["table", str(a), str(tmp_path / "half")]) == 2
    err = capsys.readouterr().err
    assert "no summary.json (run not finished?) in" in err and "half" in err and str(a) not in err
