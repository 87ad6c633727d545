"""Statistics of sweep results against hand computations (scipy only for distribution tails)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy import stats as sps

from jaxmac.scenarios import CEILINGS
from jaxmac.study.stats import (aggregate, bootstrap_ci, compare_methods, final_returns, load_sweep, welch_p,
                          who_wins)


def test_final_return_is_the_mean_of_the_last_ten_evaluations():
    curves = np.arange(24, dtype=float).reshape(2, 12)
    np.testing.assert_allclose(final_returns(curves), [np.mean(np.arange(2, 12)), np.mean(np.arange(14, 24))])
    np.testing.assert_allclose(final_returns(curves[:, :3]), [1.0, 13.0])  # fewer points: all of them
    with pytest.raises(ValueError, match="without evaluations"):
        final_returns(np.zeros((2, 0)))


def test_welch_p_is_welchs_test():
    a, b = np.array([1.0, 2.0, 4.0, 7.0]), np.array([3.0, 5.0, 9.0, 11.0, 15.0])
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    t = (a.mean() - b.mean()) / np.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))  # Welch–Satterthwaite
    assert welch_p(a, b) == pytest.approx(2 * sps.t.sf(abs(t), df), rel=1e-10)
    assert np.isnan(welch_p(a[:1], b))


def test_bootstrap_interval_brackets_the_mean():
    values = np.array([10.0, 12.0, 9.0, 15.0, 11.0, 13.0])
    lo, hi = bootstrap_ci(values)
    assert values.min() <= lo < values.mean() < hi <= values.max()
    assert bootstrap_ci(np.array([3.0, 3.0])) == (3.0, 3.0)


def _cell(scenario, method, finals):
    from jaxmac.study.stats import CellResult

    finals = np.asarray(finals, float)
    return CellResult(scenario, method, list(range(len(finals))), finals, np.arange(3), finals[:, None] * np.ones(3),
                      1000, 60.0)


def test_compare_methods_rows():
    cells = [_cell("boxpushing-6x6", "tomacvf", [260, 270, 250, 265]), _cell("boxpushing-6x6", "avf", [0, 40, 20, 10])]
    rows = {r["method"]: r for r in compare_methods(cells)}
    assert rows["tomacvf"]["best"] and not rows["avf"]["best"]
    assert rows["tomacvf"]["mean"] == pytest.approx(261.25)
    assert rows["tomacvf"]["of_ceiling"] == pytest.approx(261.25 / 270.605)
    assert rows["avf"]["se"] == pytest.approx(np.std([0, 40, 20, 10], ddof=1) / 2)
    assert np.isnan(rows["tomacvf"]["p_vs_reference"])
    assert rows["avf"]["p_vs_reference"] == pytest.approx(welch_p(np.array([260, 270, 250, 265.0]),
                                                                  np.array([0, 40, 20, 10.0])))


def test_who_wins_is_the_best_mean_and_those_welch_cannot_tell_from_it():
    best, close, far = [200.0, 210, 190, 205], [150.0, 230, 120, 220], [0.0, 10, 5, 8]
    cells = [_cell("boxpushing-6x6", "avf", far), _cell("boxpushing-6x6", "tomacvf", close),
             _cell("boxpushing-6x6", "mac_cac", best)]
    # by hand: Welch's t statistic and Welch-Satterthwaite degrees of freedom, two-sided tail from scipy
    def p_by_hand(a, b):
        a, b = np.array(a), np.array(b)
        va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
        t = (a.mean() - b.mean()) / np.sqrt(va + vb)
        dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
        return 2 * sps.t.sf(abs(t), dof)
    assert p_by_hand(best, close) >= 0.05 > p_by_hand(best, far)
    assert who_wins(cells) == ("mac_cac", ["tomacvf"])
    assert who_wins(cells[:1]) == ("avf", [])
    with pytest.raises(ValueError, match="no finished cell"):
        who_wins([])


def test_aggregate_iqm_and_probability_of_improvement():
    scen = ["boxpushing-6x6", "overcooked-A"]
    rng = np.random.default_rng(0)
    raw = {m: {s: rng.normal(100 + 50 * (m == "tomacvf"), 30, 4) for s in scen} for m in ("tomacvf", "avf")}
    results = {(s, m): _cell(s, m, raw[m][s]) for m in raw for s in scen}
    out = aggregate(results, scen, ["tomacvf", "avf"], reps=200)
    for m in raw:
        normalised = np.concatenate([raw[m][s] / CEILINGS[s] for s in scen])  # 8 values
        iqm = np.sort(normalised)[2:6].mean()  # the middle half
        assert out["iqm"][m][0] == pytest.approx(iqm)
        assert out["iqm"][m][1] <= iqm <= out["iqm"][m][2]
    # P(X > Y) + P(X = Y)/2 over all pairs of runs, per scenario, averaged over scenarios
    x = {s: raw["tomacvf"][s] / CEILINGS[s] for s in scen}
    y = {s: raw["avf"][s] / CEILINGS[s] for s in scen}
    poi = np.mean([np.mean((x[s][:, None] > y[s][None]) + 0.5 * (x[s][:, None] == y[s][None])) for s in scen])
    assert out["p_improvement"]["avf"][0] == pytest.approx(poi)
    with pytest.raises(ValueError, match="cells not finished"):
        aggregate(results, scen + ["warehouse-A"], ["tomacvf"])


def _fake_run(path, first, finals_per_seed, points=12, budget=96, undiscounted_extra=0.0):
    """A finished run folder at ``<sweep>/<scenario>/<method>/seeds<A>-<B>``; its undiscounted evaluation returns
    are the discounted ones plus ``undiscounted_extra``."""
    path.mkdir(parents=True)
    with open(path / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", "round", "episodes", "eval_disc_return", "eval_return"])
        for k, final in enumerate(finals_per_seed):
            for p in range(points):
                value = final if p >= points - 10 else -100.0
                w.writerow([first + k, p, 8 * (p + 1), value, value + undiscounted_extra])
    (path / "summary.json").write_text(json.dumps({"scenario": path.parent.parent.name, "seeds": len(finals_per_seed),
                                                   "seed_offset": first, "episodes": budget, "wall_seconds": 5.0}))


def test_load_sweep_merges_seed_ranges_and_skips_unfinished(tmp_path):
    _fake_run(tmp_path / "boxpushing-6x6" / "tomacvf" / "seeds0-2", 0, [1.0, 2.0])
    _fake_run(tmp_path / "boxpushing-6x6" / "tomacvf" / "seeds2-3", 2, [3.0], points=11)
    (tmp_path / "boxpushing-6x6" / "avf" / "seeds0-2").mkdir(parents=True)  # started, not finished
    results = load_sweep(str(tmp_path))
    assert list(results) == [("boxpushing-6x6", "tomacvf")]
    cell = results[("boxpushing-6x6", "tomacvf")]
    assert cell.seeds == [0, 1, 2] and cell.curves.shape == (3, 11) and cell.wall_seconds == 10.0
    np.testing.assert_allclose(cell.finals, [1.0, 2.0, 3.0])
    _fake_run(tmp_path / "boxpushing-6x6" / "tomacvf" / "seeds1-2", 1, [5.0])
    with pytest.raises(ValueError, match="seed ranges overlap"):
        load_sweep(str(tmp_path))


def test_warehouse_is_compared_on_undiscounted_returns_whatever_gamma_a_run_learned_with(tmp_path):
    # Warehouse's returns (and ceilings) are undiscounted: a run learning with γ 0.99 reports discounted ones too
    _fake_run(tmp_path / "warehouse-A" / "tomacvf" / "seeds0-2", 0, [300.0, 320.0], undiscounted_extra=200.0)
    _fake_run(tmp_path / "overcooked-A" / "tomacvf" / "seeds0-2", 0, [30.0, 50.0], undiscounted_extra=7.0)
    results = load_sweep(str(tmp_path))
    np.testing.assert_allclose(results[("warehouse-A", "tomacvf")].finals, [500.0, 520.0])
    np.testing.assert_allclose(results[("overcooked-A", "tomacvf")].finals, [30.0, 50.0])


def test_episodes_to_fraction_finds_the_first_smoothed_crossing_per_seed():
    from jaxmac.study.stats import episodes_to_fraction

    episodes = np.arange(1, 8) * 100
    curves = np.array([[0, 0, 10, 10, 10, 10, 10],    # trailing means over 2: 0 0 5 10 ...
                       [0, 9, 9, 0, 9, 9, 9],          # 4.5 9 4.5 4.5 9 9: first >= 8 at point 2
                       [0, 1, 2, 3, 4, 5, 6]])         # never
    got = episodes_to_fraction(episodes, curves, 8.0, window=2)
    np.testing.assert_array_equal(got[:2], [400, 300])
    assert np.isnan(got[2])
    # a slow plain-Python reference on random curves
    rng = np.random.default_rng(0)
    curves = rng.uniform(0, 10, (5, 30))
    for s, row in enumerate(curves):
        ref = next((episodes_ref for p, episodes_ref in enumerate(range(100, 3100, 100))
                    if p >= 9 and sum(row[p - 9:p + 1]) / 10 >= 6.0), np.nan)
        got = episodes_to_fraction(np.arange(100, 3100, 100), curves, 6.0)[s]
        assert (np.isnan(ref) and np.isnan(got)) or ref == got


def test_a_seed_range_that_ended_early_merges_with_one_that_ran_its_budget(tmp_path):
    # the budget is the configuration's episodes, not the summary's (which a run that ended early did not reach)
    for name, first, done in (("seeds0-2", 0, 80), ("seeds2-4", 2, 96)):
        path = tmp_path / "overcooked-A" / "tomacvf" / name
        _fake_run(path, first, [1.0, 2.0], budget=done)
        (path / "config.json").write_text(json.dumps({"config": {"episodes": 96}}))
    summary = tmp_path / "overcooked-A" / "tomacvf" / "seeds0-2" / "summary.json"
    summary.write_text(json.dumps(json.loads(summary.read_text()) | {"ended_early": "settled"}))
    cell = load_sweep(str(tmp_path))[("overcooked-A", "tomacvf")]
    assert (cell.budget, cell.trained, cell.seeds) == (96, 80, [0, 1, 2, 3])
    assert cell.ended_early == (("seeds0-2", "settled"),)
