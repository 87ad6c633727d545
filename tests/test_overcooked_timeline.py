"""experiments/analysis/overcooked_timeline.py reads an episode's reward times, plating phase and plate fetches
correctly, from arrays and from an env's timesteps."""

from __future__ import annotations

import importlib.util
import json
import pathlib
import sys
from types import SimpleNamespace

import numpy as np
import pytest

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "analysis" / "overcooked_timeline.py"
NAMES = ("stay", "get tomato", "get plate 1", "get plate 2", "deliver")


@pytest.fixture(scope="module")
def timeline_module():
    spec = importlib.util.spec_from_file_location("overcooked_timeline", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_a_hand_made_episode(timeline_module):
    h, n = 12, 2
    rewards = np.full(h, -0.1, np.float32)
    rewards[[2, 4]] = 9.9, 19.9  # a chop at step 3, two at step 5
    rewards[9] = 199.9  # delivery at step 10, the episode's end
    done = np.zeros(h, bool)
    done[9] = True
    mac = np.zeros((h, n), np.int32)
    chosen = np.zeros((h, n), bool)
    mac[3:, 1] = 3  # agent 2 runs "get plate 2" from step 4 ...
    chosen[3, 1] = True  # ... chosen once, at step 4
    mac[10, 0], chosen[10, 0] = 2, True  # a choice after the episode's end is not counted
    out = timeline_module.timeline(rewards, done, chosen, mac, NAMES)
    assert out == {"length": 10, "return": pytest.approx(float(rewards[:10].sum()), abs=0.05), "chops": [3, 5, 5],
                   "delivery": [10], "plating_steps": 5, "plate_fetches": [(4, "A2", "get plate 2")]}
    done[:] = False
    rewards[9] = -0.1
    assert "plating_steps" not in timeline_module.timeline(rewards, done, chosen, mac, NAMES)  # never delivered


def test_an_episode_from_timesteps(timeline_module):
    """``episode_timeline`` reads the env's traj fields: an agent chooses at step t when it was free after t − 1."""
    h = 6
    reward = np.array([-0.1, 9.9, -0.1, -0.1, 199.9, 0.0], np.float32)
    traj = SimpleNamespace(reward=reward, done=np.arange(h) >= 4, mac=np.array([[1], [1], [2], [2], [4], [4]]),
                           mac_done=np.array([[False], [True], [False], [True], [True], [True]]))
    env = SimpleNamespace(spec=SimpleNamespace(action_names=(NAMES,)))
    out = timeline_module.episode_timeline(env, SimpleNamespace(mac_done=np.array([True])), traj)
    assert (out["chops"], out["delivery"], out["plating_steps"]) == ([2], [5], 3)
    assert out["plate_fetches"] == [(3, "A1", "get plate 1")]  # chosen at step 3 (free after step 2)


def test_a_run_of_another_env_is_refused(timeline_module, tmp_path, capsys):
    (tmp_path / "config.json").write_text(json.dumps({"config": {"scenario": "warehouse-A"}, "seeds": 1, "seed_offset": 0}))
    with pytest.raises(SystemExit):
        timeline_module.main([str(tmp_path)])
    assert "warehouse-A" in capsys.readouterr().err
