"""Ready-made configurations: a learner's settings for a scenario, and the named presets of ``jaxmac train``.

``scenario_config("overcooked-A")`` is ToMacVF's configuration of that scenario (jaxmac's defaults: the paper's
table with the changes that make it learn; ``paper=True``: the publication's own values);
``scenario_config(s, "mac_iaicc")`` a baseline's, from its original script. Each learner keeps its table in its own
module (``Learner.scenario_values``); this module only looks them up through ``jaxmac.algos.registry``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jaxmac.algos.registry import learner
from jaxmac.config import TrainConfig
from jaxmac.scenarios import SCENARIOS


def scenario_config(scenario: str, algorithm: str = "tomacvf", tiny: bool = False, paper: bool = False,
                    overrides: dict[str, Any] | None = None) -> TrainConfig:
    """``algorithm``'s configuration of ``scenario`` (optionally shrunk to test size): jaxmac's defaults, which are
    the original scripts' values except where a learner records changes that make it learn (ToMacVF); ``paper``:
    the publication's own values. ``overrides`` are applied with the table's values in one validation (a setting
    that is only valid together with an override, such as the paper's Overcooked target period, can be run)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; valid scenarios: {list(SCENARIOS)}")
    entry = learner(algorithm)
    table = entry.paper_values if paper and entry.paper_values is not None else entry.scenario_values
    values = dict(table.get(scenario, {}))
    if tiny:
        values.update(TINY, **entry.tiny_values)
    values.update(overrides or {})
    return TrainConfig.create(algorithm, scenario=scenario, **values)


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named configuration for ``jaxmac train --preset NAME``: a scenario, a learner, overrides of that learner's
    scenario settings (the paper's or the original script's), and a seed count; command-line flags apply on top."""

    scenario: str
    algorithm: str
    overrides: dict
    seeds: int
    about: str


PRESETS = {
    # the README's main command: ToMacVF's curve climbing on Box Pushing 6x6 in a few minutes on a 2-core CPU
    "quickstart": Preset(
        "boxpushing-6x6", "tomacvf",
        dict(episodes=2048, batch_size=32, updates_per_round=4, overestimate_weight=0.3, eps_decay_episodes=1000,
             eval_every_episodes=50),
        seeds=2,
        about="ToMacVF on Box Pushing 6x6, 2,048 episodes: batch 32 (paper 128), 4 gradient steps per round of 16 "
              "episodes (paper 1), optimistic weighting 0.3 (paper: plain MSE), epsilon decayed over 1,000 episodes "
              "(paper 4,000)"),
    # the README's result on Box Pushing 6x6 (mean 263.8 of 270.6 over 8 seeds)
    "boxpushing-6x6-solved": Preset(
        "boxpushing-6x6", "tomacvf", dict(episodes=6496, updates_per_round=4, overestimate_weight=0.3), seeds=8,
        about="ToMacVF on Box Pushing 6x6 with the paper's settings but 4 gradient steps per round and optimistic "
              "weighting 0.3, 6,496 episodes"),
}


def preset_config(name: str) -> tuple[TrainConfig, Preset]:
    """The configuration of preset ``name`` (see ``PRESETS``) and the preset itself."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; valid presets: {list(PRESETS)}")
    preset = PRESETS[name]
    return scenario_config(preset.scenario, preset.algorithm).override(**preset.overrides), preset


# Tiny shared settings for tests and smoke runs (seconds, not hours); each learner adds its own.
TINY = dict(episodes=64, num_envs=8, batch_size=8, buffer_episodes=32, eval_every_episodes=32, eval_episodes=2,
            target_update_episodes=16, eps_decay_episodes=32)
