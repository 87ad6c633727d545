"""The example learner of docs/learners.md is complete: registered with one line, it trains on the shared trainer
(run folder, metrics, final evaluation) and its policy loads and acts like any learner's."""

from __future__ import annotations

import csv
import importlib.util
import pathlib
import sys

import numpy as np
import pytest

import jaxmac
from jaxmac.algos import registry

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "docs" / "examples" / "independent_drqn.py"


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("independent_drqn", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve the module's annotations through it
    spec.loader.exec_module(module)
    return module


def test_the_example_stays_short():
    code = [line for line in EXAMPLE.read_text().splitlines() if line.strip()]
    assert len(code) <= 60, len(code)


def test_the_example_learner_trains_once_registered(example, tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="independent_drqn"):  # unknown until registered: valid names listed
        registry.learner("independent_drqn")
    monkeypatch.setitem(registry.REGISTRY, "independent_drqn", example.LEARNER)  # the one line in LEARNERS
    run = jaxmac.train(scenario="boxpushing-6x6", algorithm="independent_drqn", tiny=True, out_dir=str(tmp_path / "r"),
                       progress=False, horizon=20, episodes=64, target_update_episodes=16)
    with open(tmp_path / "r" / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    losses = [float(r["loss"]) for r in rows if r["loss"] not in ("", "nan")]
    assert losses and np.all(np.isfinite(losses))  # gradient steps ran
    assert int(rows[-1]["episodes"]) == 64
    assert run.config.algo.rnn_size == 8 and run.config.batch_size == 8  # tiny values on the scenario's
    returns = run.evaluate(seed=0, episodes=2)
    assert returns["discounted"].shape == (2,)
