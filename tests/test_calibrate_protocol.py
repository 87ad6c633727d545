"""calibrate_protocol's rates from finished run folders: a sweep cell's whole-run rate, wrong settings refused."""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "experiments"))
from calibrate_protocol import rate_from_run, sweep_cells  # noqa: E402

from jaxmac.study.sweep import plan  # noqa: E402


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
    with pytest.raises(SystemExit, match="lr"):
        rate_from_run("mac_cac", "boxpushing-6x6", str(other))
    with pytest.raises(SystemExit, match="no finished cell"):
        sweep_cells(str(tmp_path / "empty"))
