"""``jaxmac calibrate`` (jaxmac/study/calibrate.py): rates from finished run folders — a sweep cell's whole-run rate,
wrong settings refused — written to the rates file ``jaxmac sweep --rates`` reads."""

from __future__ import annotations

import json

import pytest

from jaxmac.cli import main
from jaxmac.study.calibrate import rate_from_run, sweep_cells
from jaxmac.study.sweep import load_rates, plan


def _finished_cell(root, cell, config, wall_seconds):
    run = root / cell.path
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"config": config.to_dict()}))
    (run / "summary.json").write_text(json.dumps({"seeds": cell.seeds, "episodes": cell.episodes,
                                                  "wall_seconds": wall_seconds}))
    return run


def test_a_sweep_cells_rate_is_seeds_times_episodes_over_wall_time(tmp_path):
    cell = next(c for c in plan("bp", "cpu") if c.path == "boxpushing-6x6/mac_cac/seeds0-4")
    # the cpu protocol's cell has shorter budget and schedules than the method's own settings: still its rate
    run = _finished_cell(tmp_path, cell, cell.config(), wall_seconds=100.0)
    _finished_cell(tmp_path, next(c for c in plan("bp", "cpu") if c.path == "boxpushing-8x8/avf/seeds0-4"),
                   cell.config(), 1.0).joinpath("summary.json").unlink()  # started, not finished: not listed
    assert sweep_cells(str(tmp_path)) == [f"mac_cac@boxpushing-6x6={run}"]
    rate = rate_from_run("mac_cac", "boxpushing-6x6", str(run))
    assert rate["episodes_per_s"] == pytest.approx(4 * 4000 / 100.0)
    # a folder trained with other settings than the method's is refused, naming them
    other = _finished_cell(tmp_path / "other", cell, cell.config().override(lr=0.123), 100.0)
    with pytest.raises(ValueError, match="lr"):
        rate_from_run("mac_cac", "boxpushing-6x6", str(other))
    with pytest.raises(ValueError, match="no finished cell"):
        sweep_cells(str(tmp_path / "empty"))


def test_jaxmac_calibrate_from_sweep_writes_the_rates_file_sweep_reads(tmp_path, capsys):
    """``jaxmac calibrate --from-sweep DIR --out FILE``: one line per cell, the rate kept in FILE (its folder made),
    read back by ``jaxmac sweep``'s ``load_rates``; a pair already in the file is kept, not measured again."""
    cell = next(c for c in plan("bp", "cpu") if c.path == "boxpushing-6x6/mac_cac/seeds0-4")
    _finished_cell(tmp_path / "sweep", cell, cell.config(), wall_seconds=100.0)
    out = tmp_path / "rates" / "protocol_rates.json"
    assert main(["calibrate", "--from-sweep", str(tmp_path / "sweep"), "--out", str(out)]) == 0
    assert "mac_cac@boxpushing-6x6: 160.00 episodes/s" in capsys.readouterr().out
    assert load_rates(str(out))["mac_cac@boxpushing-6x6"]["episodes_per_s"] == pytest.approx(160.0)
    assert main(["calibrate", "--out", str(out)]) == 2  # nothing to measure: one line, no traceback
    assert "nothing to measure" in capsys.readouterr().err
    assert main(["calibrate", "--pairs", "mac_cac@boxpushing-6x6", "--out", str(out)]) == 0  # measured: kept
    assert "mac_cac@boxpushing-6x6: 160.00 episodes/s (kept)" in capsys.readouterr().out


def test_a_measurement_times_chunks_after_the_ring_is_filled_in_a_child_process():
    """``measure_in_child`` (what ``--pairs`` runs for a method's configuration), on tiny settings: the episodes of
    all seeds over the timed chunks only, their env steps, positive times."""
    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.presets import scenario_config
    from jaxmac.study.calibrate import measure_in_child
    from jaxmac.trainer import make_train

    config = scenario_config("boxpushing-6x6", tiny=True).override(horizon=20, num_envs=4, batch_size=4,
                                                                    buffer_episodes=8)
    m = measure_in_child(config, seeds=2, chunks=2)
    env = make_env(config)
    rounds = make_train(config, env, make_algorithm(config, env)).rounds_per_chunk
    assert m["episodes"] == 2 * 2 * rounds * 4
    assert 0 < m["env_steps"] <= m["episodes"] * 20
    assert m["wall_s"] > 0 and m["cpu_s"] > 0 and m["compile_s"] > 0
