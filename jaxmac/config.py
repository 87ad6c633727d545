"""Typed, frozen, validated training configurations and the paper's 13 scenarios.

``scenario_config("boxpushing-6x6")`` returns the ToMacVF settings of the paper's appendix
tables (``shared/design/HYPERPARAMS.md``) as interpreted by ``DECISIONS.md`` (D2, D7, D8,
D11, D13, D15); ``config.override(**values)`` or ``config.override_strings(["lr=3e-4"])``
(the CLI's ``--set``) returns a validated copy. Every choice the paper leaves open is a
field here, so alternatives stay measurable.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

CHOICES: dict[str, tuple[str, ...]] = {
    "algorithm": ("tomacvf",),
    "buffer": ("mac_sjert", "mac_jert"),  # D16 ablation
    "mixer": ("qmix", "vdn"),  # D19
    "mixer_params": ("atpg", "state"),  # D16: "state" = ToMacVF w/o ATPG (vanilla QMIX hypernets)
    "obs_mode": ("real", "macro"),  # D1
}


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One training run (per seed). Episode counts are primitive-step episodes of the env."""

    scenario: str = "boxpushing-6x6"
    algorithm: str = "tomacvf"
    episodes: int = 40_000  # training episodes per seed (D20)
    num_envs: int = 16  # E episodes collected per round (D13)
    updates_per_round: int = 1  # gradient steps per collection round (D13: max(1, E/10) for BP)
    batch_size: int = 128  # episodes per gradient step (D7)
    buffer_episodes: int = 5000  # ring capacity N (D7)
    lr: float = 1e-3
    grad_clip: float = 10.0  # global-norm clip (D8)
    target_update_episodes: int = 32  # hard target copy period (D13)
    eps_start: float = 1.0
    eps_end: float = 0.1
    eps_decay_episodes: int = 4000
    rnn_size: int = 32  # GRU width (D2)
    fc_size: int = 64
    n_step: int = 1  # micro-TD n (D11)
    macro_loss_weight: float = 1.0  # λ (D8)
    # weight of squared TD errors where Q_tot is above its target; 1 = plain MSE (D18), < 1 = optimistic
    # weighting (OW-QMIX's weighting without its Q*, hysteretic Q-learning): keeps the value of a joint
    # action that succeeded when partners' exploration makes it fail elsewhere
    overestimate_weight: float = 1.0
    buffer: str = "mac_sjert"
    mixer: str = "qmix"
    mixer_params: str = "atpg"
    obs_mode: str = "real"
    mixer_embed: int = 32
    attn_dim: int = 32
    attn_delta: float = 0.05  # agent-attention threshold δ (D5)
    attn_window: int = 0  # causal window in steps; 0 = whole episode (D4)
    time_pe_dim: int = 16  # D3
    progress_pe_dim: int = 8  # D3
    use_time_pe: bool = True  # D3 flag
    eval_every_episodes: int = 100  # D15
    eval_episodes: int = 10  # D15
    horizon: int = 0  # env horizon override for smoke runs; 0 = the scenario's own

    def __post_init__(self):
        for name, choices in CHOICES.items():
            value = getattr(self, name)
            if value not in choices:
                raise ValueError(f"{name}={value!r} is not valid; choices: {list(choices)}")
        positive = ("episodes", "num_envs", "updates_per_round", "batch_size", "buffer_episodes",
                    "target_update_episodes", "rnn_size", "fc_size", "n_step", "mixer_embed", "attn_dim",
                    "time_pe_dim", "progress_pe_dim", "eval_every_episodes", "eval_episodes")
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)!r} must be >= 1")
        for name in ("time_pe_dim", "progress_pe_dim"):
            if getattr(self, name) % 2:
                raise ValueError(f"{name}={getattr(self, name)!r} must be even (sine and cosine pairs)")
        if not 0.0 < self.lr < 1.0:
            raise ValueError(f"lr={self.lr!r} must be in (0, 1)")
        if not 0.0 <= self.eps_end <= self.eps_start <= 1.0:
            raise ValueError(f"need 0 <= eps_end <= eps_start <= 1, got eps_start={self.eps_start}, "
                             f"eps_end={self.eps_end}")
        if self.eps_decay_episodes < 0 or self.attn_window < 0 or self.horizon < 0:
            raise ValueError("eps_decay_episodes, attn_window and horizon must be >= 0")
        if not 0.0 <= self.attn_delta < 1.0:
            raise ValueError(f"attn_delta={self.attn_delta!r} must be in [0, 1)")
        if self.buffer_episodes < self.batch_size:
            raise ValueError(f"buffer_episodes={self.buffer_episodes} must be >= batch_size={self.batch_size}")
        if not 0.0 < self.overestimate_weight <= 1.0:
            raise ValueError(f"overestimate_weight={self.overestimate_weight!r} must be in (0, 1] (1 = plain MSE)")
        if self.macro_loss_weight < 0 or self.grad_clip <= 0:
            raise ValueError("macro_loss_weight must be >= 0 and grad_clip > 0")

    # --- overrides ----------------------------------------------------------------------
    def override(self, **values: Any) -> "TrainConfig":
        """A validated copy with ``values`` replaced (names and types checked)."""
        hints = typing.get_type_hints(TrainConfig)
        for key, value in values.items():
            if key not in hints:
                raise ValueError(f"unknown config key {key!r}; valid keys: {sorted(hints)}")
            expected = hints[key]
            ok = (isinstance(value, bool) if expected is bool else
                  isinstance(value, int) and not isinstance(value, bool) if expected is int else
                  isinstance(value, (int, float)) and not isinstance(value, bool) if expected is float else
                  isinstance(value, str))
            if not ok:
                raise ValueError(f"config {key}={value!r} must be of type {expected.__name__}")
        return dataclasses.replace(self, **values)

    def override_strings(self, assignments: list[str]) -> "TrainConfig":
        """Apply ``key=value`` strings (the CLI's ``--set``), parsing values by field type."""
        hints = typing.get_type_hints(TrainConfig)
        values: dict[str, Any] = {}
        for item in assignments:
            key, sep, raw = item.partition("=")
            key = key.strip()
            if not sep:
                raise ValueError(f"--set expects key=value, got {item!r}")
            if key not in hints:
                raise ValueError(f"unknown config key {key!r}; valid keys: {sorted(hints)}")
            values[key] = _parse(key, raw.strip(), hints[key])
        return self.override(**values)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def make_env(config: TrainConfig):
    """The scenario's env (with the ``horizon`` override if set)."""
    import envs_jax

    overrides = {"horizon": config.horizon} if config.horizon else {}
    return envs_jax.make(config.scenario, **overrides)


def _parse(key: str, raw: str, kind: type) -> Any:
    try:
        if kind is bool:
            if raw.lower() in ("true", "1", "yes"):
                return True
            if raw.lower() in ("false", "0", "no"):
                return False
            raise ValueError
        if kind is int:
            return int(raw.replace("_", ""))
        if kind is float:
            return float(raw)
        return raw
    except ValueError:
        raise ValueError(f"config {key}={raw!r} is not a valid {kind.__name__}") from None


# --- the paper's scenarios (HYPERPARAMS.md, interpreted by DECISIONS.md) -----------------------

_BP = dict(batch_size=128, eps_end=0.1, eps_decay_episodes=4000, buffer_episodes=5000, n_step=1)
_OC = dict(lr=3e-4, rnn_size=32, n_step=5, eps_end=0.05, eps_decay_episodes=20_000, buffer_episodes=2000,
           target_update_episodes=16, updates_per_round=1)
_WH = dict(batch_size=32, num_envs=8, rnn_size=64, n_step=5, eps_decay_episodes=10_000, buffer_episodes=2000,
           updates_per_round=1)

SCENARIOS: dict[str, dict[str, Any]] = {
    # Box Pushing: E = "episodes per train", max(1, E/10) updates per round (D13); 12/14: rnn 64, lr 5e-4.
    "boxpushing-6x6": dict(_BP, lr=1e-3, num_envs=16, updates_per_round=1, target_update_episodes=32, rnn_size=32),
    "boxpushing-8x8": dict(_BP, lr=1e-3, num_envs=16, updates_per_round=1, target_update_episodes=32, rnn_size=32),
    "boxpushing-10x10": dict(_BP, lr=1e-3, num_envs=32, updates_per_round=3, target_update_episodes=48,
                             rnn_size=48),
    "boxpushing-12x12": dict(_BP, lr=5e-4, num_envs=48, updates_per_round=4, target_update_episodes=144,
                             rnn_size=64),
    "boxpushing-14x14": dict(_BP, lr=5e-4, num_envs=48, updates_per_round=4, target_update_episodes=144,
                             rnn_size=64),
    # Overcooked: E = "train freq" (32/32/64), one update per round.
    "overcooked-A": dict(_OC, episodes=100_000, batch_size=64, num_envs=32),
    "overcooked-B": dict(_OC, episodes=120_000, batch_size=128, num_envs=32),
    "overcooked-C": dict(_OC, episodes=100_000, batch_size=128, num_envs=64),
    # Warehouse A..E = WTD-D, WTD-D1, WTD-T, WTD-T1, WTD-Q.
    "warehouse-A": dict(_WH, episodes=40_000, lr=5e-4, target_update_episodes=32, eps_end=0.05),
    "warehouse-B": dict(_WH, episodes=40_000, lr=5e-4, target_update_episodes=32, eps_end=0.05),
    "warehouse-C": dict(_WH, episodes=80_000, lr=3e-4, target_update_episodes=32, eps_end=0.01),
    "warehouse-D": dict(_WH, episodes=80_000, lr=3e-4, target_update_episodes=64, eps_end=0.01),
    "warehouse-E": dict(_WH, episodes=100_000, lr=1e-4, target_update_episodes=64, eps_end=0.01),
}

# Tiny settings for tests and smoke runs (seconds, not hours).
TINY = dict(episodes=64, num_envs=8, batch_size=8, buffer_episodes=32, rnn_size=8, fc_size=16, mixer_embed=8,
            attn_dim=8, time_pe_dim=4, progress_pe_dim=4, eval_every_episodes=32, eval_episodes=2,
            target_update_episodes=16, eps_decay_episodes=32)


def scenario_config(scenario: str, tiny: bool = False) -> TrainConfig:
    """The paper's configuration of ``scenario`` (optionally shrunk to test size)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; valid scenarios: {list(SCENARIOS)}")
    values = dict(SCENARIOS[scenario], scenario=scenario)
    if tiny:
        values.update(TINY)
    return TrainConfig(**values)
