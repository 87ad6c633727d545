"""experiments/results_table.py: mean, standard error, fraction of optimal and changed settings per run."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import pytest

from jaxmac.config import scenario_config

_SPEC = importlib.util.spec_from_file_location(
    "results_table", pathlib.Path(__file__).parents[1] / "experiments" / "results_table.py")
results_table = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(results_table)


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
    assert cells[:5] == ["boxpushing-6x6", "2", "800", "265.0 ± 5.0", "260.0 270.0"]
    assert cells[6] == "98%" and cells[7] == "updates_per_round=4" and cells[8] == "2 min"
    cells = [c.strip() for c in row_b.strip("|").split("|")]
    assert cells[3] == "37.3 ± –" and cells[7] == "defaults"


def test_unfinished_run_is_named(tmp_path):
    (tmp_path / "half").mkdir()
    with pytest.raises(SystemExit, match="half"):
        results_table.main([str(tmp_path / "half")])
