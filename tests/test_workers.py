"""Multi-process training: seed split and the merge of worker folders (no subprocess here)."""

from __future__ import annotations

import csv
import json

import pytest

from jaxmac.runs.workers import merge, split_seeds


def test_split_seeds_covers_every_seed_once():
    assert split_seeds(8, 2) == [(0, 4), (4, 4)]
    assert split_seeds(5, 2) == [(0, 3), (3, 2)]
    assert split_seeds(3, 3) == [(0, 1), (1, 1), (2, 1)]
    with pytest.raises(ValueError, match="workers=3 must be between 1 and seeds=2"):
        split_seeds(2, 3)


def test_merge_concatenates_workers_in_seed_order(tmp_path):
    jobs = []
    for k, seeds in enumerate(([0, 1], [2])):
        d = tmp_path / f"worker{k}"
        d.mkdir()
        with open(d / "metrics.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["seed", "round", "episodes", "eval_disc_return"])
            for s in seeds:
                w.writerows([[s, 0, 8, "nan"], [s, 1, 16, float(10 * s)]])
        (d / "summary.json").write_text(json.dumps({
            "scenario": "boxpushing-6x6", "algorithm": "tomacvf", "episodes": 16, "discount": 0.98,
            "optimal_return": 270.605, "wall_seconds": 1.0 + k, "final_greedy_return": [float(s) for s in seeds],
            "final_greedy_return_undiscounted": [2.0 * s for s in seeds]}))
        jobs.append(str(d))
    summary = merge(str(tmp_path), jobs, wall_seconds=1.5)
    assert summary["wall_seconds"] == 2.0  # a resumed run: the longest worker's accumulated time
    assert summary["final_greedy_return"] == [0.0, 1.0, 2.0] and summary["seeds"] == 3
    assert summary["final_greedy_return_mean"] == pytest.approx(1.0)
    assert summary["final_greedy_return_undiscounted_mean"] == pytest.approx(2.0)
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    assert [r["seed"] for r in rows] == ["0", "0", "1", "1", "2", "2"]
    assert (tmp_path / "curve.png").exists() and json.loads((tmp_path / "summary.json").read_text())["workers"] == 2
