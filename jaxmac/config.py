"""Typed, frozen, validated training configurations: the trainer's shared settings plus one learner's block.

``TrainConfig`` holds what the shared trainer reads (budget, collection and update schedule, replay, optimiser,
targets, exploration, evaluation, the divergence guard); its field ``algo`` is the learner's own settings block, a
frozen dataclass deriving from ``LearnerSettings`` and defined in the learner's module. A block class names its
learner in its class statement (``class MacDecQSettings(..., algorithm="macdec_q")``), which registers it here: this
module imports nothing of the learners, and a configuration of a learner can be built once its module is imported
(``jaxmac.algos.registry`` imports them all; ``jaxmac.presets.scenario_config`` builds a scenario's configuration).

``config.override(**values)`` and ``config.override_strings(["lr=3e-4"])`` (the CLI's ``--set``) take shared and
block names alike and return a validated copy; a name of another learner's block is refused, naming that learner.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, ClassVar

from envs_jax.validation import has_type, is_integer, parse_value, type_name
from jaxmac.scenarios import SCENARIOS

COLLECTIONS = ("whole", "first_finished")
# Settings that only watch a run: they decide when the divergence guard stops it, never what it computes until then.
# Two runs that differ in nothing else are the same run (``TrainConfig.run_settings``): a sweep cell, a protocol and a
# measured rate are identified without them, so a new guard default does not make finished runs read as other runs.
WATCH_SETTINGS = ("divergence_guard", "divergence_margin")

_SETTINGS: dict[str, type] = {}  # learner name -> its settings block class, filled by LearnerSettings subclasses


@dataclasses.dataclass(frozen=True)
class LearnerSettings:
    """Base of every learner's settings block. A subclass that names its learner registers itself::

        @dataclasses.dataclass(frozen=True)
        class MySettings(LearnerSettings, algorithm="my_learner"):
            hidden: int = 64

    ``length_buckets``: whether the learner's update can run on the batch's real length (``TrainConfig.
    length_buckets`` > 1). ``check_config`` refuses shared settings the learner cannot run with."""

    algorithm: ClassVar[str] = ""
    supports_length_buckets: ClassVar[bool] = False

    def __init_subclass__(cls, algorithm: str | None = None, length_buckets: bool | None = None, **kwargs):
        super().__init_subclass__(**kwargs)
        if length_buckets is not None:
            cls.supports_length_buckets = length_buckets
        if algorithm is not None:
            if algorithm in _SETTINGS and _SETTINGS[algorithm].__qualname__ != cls.__qualname__:
                raise ValueError(f"learner name {algorithm!r} is taken by {_SETTINGS[algorithm].__qualname__}")
            cls.algorithm = algorithm
            _SETTINGS[algorithm] = cls

    def check_config(self, config: "TrainConfig") -> None:
        """Refuse shared settings this learner cannot honour (called by ``TrainConfig`` after its own checks)."""
        if config.length_buckets != 1 and not self.supports_length_buckets:
            raise ValueError(f"length_buckets={config.length_buckets} is not supported by algorithm="
                             f"{config.algorithm!r} (it always runs the full length: use 1); algorithms with length "
                             f"buckets: {[n for n, c in _SETTINGS.items() if c.supports_length_buckets]}")
        self.check_batch_fits_buffer(config)

    def check_batch_fits_buffer(self, config: "TrainConfig") -> None:
        """A batch of ``batch_size`` stored episodes needs a ring of at least that many."""
        if config.buffer_episodes < config.batch_size:
            raise ValueError(f"buffer_episodes={config.buffer_episodes} must be >= batch_size={config.batch_size}")


def registered_algorithms() -> tuple[str, ...]:
    """The learners whose settings blocks are registered (every learner once ``jaxmac.algos.registry`` is imported)."""
    return tuple(_SETTINGS)


def settings_class(algorithm: str) -> type:
    """The settings block class of ``algorithm`` (a ValueError naming the valid learners otherwise)."""
    if not _SETTINGS:
        raise ValueError(f"algorithm={algorithm!r}: no learner is registered yet; import jaxmac.algos.registry (or "
                         "jaxmac.presets) first, which registers every learner's settings")
    if algorithm not in _SETTINGS:
        raise ValueError(f"algorithm={algorithm!r} is not valid; choices: {list(_SETTINGS)}")
    return _SETTINGS[algorithm]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One training run (per seed). Episode counts are primitive-step episodes of the env."""

    scenario: str = "boxpushing-6x6"
    algorithm: str = "tomacvf"
    episodes: int = 40_000  # training episodes per seed (D20)
    num_envs: int = 16  # E episodes collected per round (D13)
    updates_per_round: int = 1  # gradient steps per collection round (D13: max(1, E/10) for BP)
    # > 0: instead, one gradient step per this many env steps collected (the originals' value-based train_freq)
    train_every_steps: int = 0
    batch_size: int = 128  # episodes (or windows) per gradient step (D7)
    buffer_episodes: int = 5000  # ring capacity N (D7)
    start_train_episodes: int = 0  # no gradient step before this many episodes (and a batch) are stored
    lr: float = 1e-3
    grad_clip: float = 10.0  # global-norm clip (D8); 0 = none (the originals clip nothing)
    # hard target copy period in episodes (D13), more than one round (num_envs); 0 = a copy after every round
    target_update_episodes: int = 32
    target_update_steps: int = 0  # > 0: the period counts env steps instead (the originals' target_update_freq)
    target_polyak: float = 0.0  # > 0: Polyak averaging by this rate after every gradient step instead of copies
    eps_start: float = 1.0
    eps_end: float = 0.1
    eps_decay_episodes: int = 4000
    eps_decay_start: int = 0  # episodes before the linear decay starts (the originals count from start_train)
    eval_every_episodes: int = 100  # D15
    eval_episodes: int = 10  # D15
    horizon: int = 0  # env horizon override for smoke runs; 0 = the scenario's own
    discount: float = 0.0  # env discount γ override (learning and reported returns); 0 = the scenario's own (D12)
    # which episodes a round trains on and an evaluation averages: "whole" = num_envs (eval_episodes) episodes run
    # to their end; "first_finished" = the MacroMARL actor-critic runners' protocol, the first episodes to finish
    # among num_envs auto-resetting envs (short episodes over-represented; jaxmac.collect)
    collection: str = "whole"
    # also evaluate, every evaluation period, the greedy version of a stochastic evaluation policy (the actor-critics;
    # Algorithm.greedy_act); the final evaluation in summary.json is greedy either way
    eval_greedy: bool = True
    # the update runs on the shortest of this many static sequence lengths (halving from the full one) that holds
    # the batch's real entries: the same losses, less padding (jaxmac.buckets; the on-policy learners); 1 = always
    # the full length, one compilation
    length_buckets: int = 1
    # stop a run (keeping its last good checkpoint) when a value learner's mean value estimate leaves the env's
    # bounds on any discounted return (``jaxmac.runs.value_bounds_of``) by more than divergence_margin of the bound;
    # rounds outside are flagged in metrics.csv (value_out_of_bounds) either way. 0.05: over 401 committed seeds none
    # that learned passed 0.9 of its bound, every one above 1.0 failed (experiments/analysis/value_bound_survey.py)
    divergence_guard: bool = True
    divergence_margin: float = 0.05
    algo: Any = None  # the algorithm's settings block; None = its defaults

    def __post_init__(self):
        settings_cls = settings_class(self.algorithm)
        if self.algo is None:
            object.__setattr__(self, "algo", settings_cls())
        elif not isinstance(self.algo, settings_cls):
            raise ValueError(f"algo={self.algo!r} must be a {settings_cls.__name__} for algorithm {self.algorithm!r}")
        self._check_finite()
        if self.collection not in COLLECTIONS:
            raise ValueError(f"collection={self.collection!r} is not valid; choices: {list(COLLECTIONS)}")
        if self.scenario not in SCENARIOS:
            raise ValueError(f"scenario={self.scenario!r} is not valid; choices: {list(SCENARIOS)}")
        positive = ("episodes", "num_envs", "updates_per_round", "batch_size", "buffer_episodes",
                    "eval_every_episodes", "eval_episodes")
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)!r} must be >= 1")
        for name in ("train_every_steps", "start_train_episodes", "target_update_episodes", "target_update_steps",
                     "eps_decay_episodes",
                     "eps_decay_start", "horizon"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)!r} must be >= 0")
        if not is_integer(self.length_buckets) or self.length_buckets < 1:
            raise ValueError(f"length_buckets={self.length_buckets!r} must be a positive integer (1 = the full length)")
        if not 0.0 <= self.discount <= 1.0:
            raise ValueError(f"discount={self.discount!r} must be in (0, 1] (or 0 = the scenario's own)")
        if not 0.0 < self.lr < 1.0:
            raise ValueError(f"lr={self.lr!r} must be in (0, 1)")
        if not 0.0 <= self.eps_end <= self.eps_start <= 1.0:
            raise ValueError(f"need 0 <= eps_end <= eps_start <= 1, got eps_start={self.eps_start}, "
                             f"eps_end={self.eps_end}")
        if self.grad_clip < 0:
            raise ValueError(f"grad_clip={self.grad_clip!r} must be >= 0 (0 = no clipping)")
        if not (self.divergence_margin >= 0.0 and math.isfinite(self.divergence_margin)):
            raise ValueError(f"divergence_margin={self.divergence_margin!r} must be a finite number >= 0 (a fraction "
                             f"of each value bound)")
        if not 0.0 <= self.target_polyak < 1.0:
            raise ValueError(f"target_polyak={self.target_polyak!r} must be in [0, 1) (0 = hard copies)")
        self._check_target_period()
        self.algo.check_config(self)

    def _check_finite(self) -> None:
        """Every real-valued setting, shared or of the algorithm's block, is a finite number: a NaN or an infinity
        passes every range check (``nan < 0`` is false) and would surface only as a diverged run."""
        for owner, hints in ((self, _shared_hints()), (self.algo, typing.get_type_hints(type(self.algo)))):
            for name, kind in hints.items():
                value = getattr(owner, name, None)
                if kind is float and isinstance(value, (int, float)) and not math.isfinite(value):
                    raise ValueError(f"{name}={value!r} must be a finite number")

    def _check_target_period(self) -> None:
        """A hard copy every ``target_update_episodes`` episodes lands after a round's gradient steps; a period of
        at most one round (``num_envs`` episodes) copies after every round, so the target lags the online network by
        less than one round — with one step per round not at all: no target network. Refused, because that is
        never what a period asks for; 0 asks for it explicitly (a copy after every round)."""
        if self.target_polyak or self.target_update_steps or self.target_update_episodes == 0:
            return
        if self.target_update_episodes <= self.num_envs:
            raise ValueError(
                f"target_update_episodes={self.target_update_episodes} <= num_envs={self.num_envs}: the target would "
                f"be copied after every round of {self.num_envs} episodes, i.e. after every "
                f"{'gradient step' if self.updates_per_round == 1 and not self.train_every_steps else 'round'}, and "
                f"would never lag the online network by a round. Use a period of several rounds (e.g. "
                f"target_update_episodes={4 * self.num_envs}), or target_update_episodes=0 to train without a "
                f"target network on purpose (a copy after every round)")

    # --- overrides ----------------------------------------------------------------------
    @classmethod
    def create(cls, algorithm: str, **values: Any) -> "TrainConfig":
        """A validated configuration of ``algorithm`` from shared and block names alike (unset ones at their
        defaults), checked once as a whole."""
        shared, block = _route(algorithm, values)
        return cls(algorithm=algorithm, algo=settings_class(algorithm)(**block), **shared)

    @property
    def rounds(self) -> int:
        """Rounds the run trains: ``episodes`` in rounds of ``num_envs`` episodes per seed, the last one whole."""
        return -(-self.episodes // self.num_envs)

    def override(self, **values: Any) -> "TrainConfig":
        """A validated copy with ``values`` replaced: shared fields and fields of this algorithm's block (names
        and types checked). Changing ``algorithm`` starts from the new algorithm's default block."""
        algorithm = values.pop("algorithm", self.algorithm)
        shared, block = _route(algorithm, values)
        base = self.algo if algorithm == self.algorithm else settings_class(algorithm)()
        return dataclasses.replace(self, algorithm=algorithm, algo=dataclasses.replace(base, **block), **shared)

    def override_strings(self, assignments: list[str]) -> "TrainConfig":
        """Apply ``key=value`` strings (the CLI's ``--set``), parsing values by field type."""
        return self.override(**parse_assignments(assignments, self.algorithm))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: shared fields, with the block as a nested dict under ``algo``."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "algo"}
        out["algo"] = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self.algo).items()}
        return out

    def flat_dict(self) -> dict[str, Any]:
        """Shared and block fields in one dict (the names ``--set`` takes)."""
        out = self.to_dict()
        return {**{k: v for k, v in out.items() if k != "algo"}, **out["algo"]}

    def run_settings(self) -> dict[str, Any]:
        """``flat_dict`` without the settings that only watch the run (``WATCH_SETTINGS``): what identifies the run a
        configuration trains."""
        return {k: v for k, v in self.flat_dict().items() if k not in WATCH_SETTINGS}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "TrainConfig":
        """Inverse of ``to_dict``; also reads run folders of older versions: the flat layout written before the blocks
        existed, and hard-copy periods of at most one round (read as 0, which runs the same)."""
        values = dict(values)
        algorithm = values.get("algorithm", "tomacvf")
        settings_cls = settings_class(algorithm)
        block = values.pop("algo", None)
        if block is None:  # flat layout: ToMacVF's fields at the top level
            names = {f.name for f in dataclasses.fields(settings_cls)}
            block = {k: values.pop(k) for k in list(values) if k in names}
        block = {k: tuple(v) if isinstance(v, list) else v for k, v in block.items()}
        names = {f.name for f in dataclasses.fields(settings_cls)}
        if (not values.get("target_polyak") and not values.get("target_update_steps")
                and 0 < values.get("target_update_episodes", 1) <= values.get("num_envs", 0)):
            # written before periods of at most one round were refused: they copied after every round, which a
            # period of 0 now says (the same run)
            values["target_update_episodes"] = 0
        unknown = sorted(set(block) - names)
        if unknown:
            raise ValueError(f"settings {unknown} are not fields of {algorithm}'s settings (valid: {sorted(names)}); "
                             "the run was written by another version of jaxmac")
        return cls(**values, algo=settings_cls(**block))


def _route(algorithm: str, values: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``values`` split into shared fields and fields of ``algorithm``'s block, each name and type checked."""
    shared_hints = _shared_hints()
    algo_hints = _block_hints(settings_class(algorithm))
    shared, block = {}, {}
    for key, value in values.items():
        if key == "algo":
            raise ValueError("set the algorithm's settings by name (e.g. rnn_size=64), not as algo=")
        if key in shared_hints:
            _check_type(key, value, shared_hints[key])
            shared[key] = value
        elif key in algo_hints:
            _check_type(key, value, algo_hints[key])
            block[key] = value
        else:
            raise ValueError(_unknown_key_message(key, algorithm))
    return shared, block


def parse_assignments(assignments: list[str], algorithm: str) -> dict[str, Any]:
    """``key=value`` strings (the CLI's ``--set``) as typed values of the shared fields and ``algorithm``'s block
    (``algorithm=`` among them switches the block); unknown keys and unparsable values are refused."""
    values: dict[str, Any] = {}
    for item in assignments:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep:
            raise ValueError(f"--set expects key=value, got {item!r}")
        values[key] = raw.strip()
    algorithm = values.get("algorithm", algorithm)
    hints = {**_shared_hints(), **_block_hints(_SETTINGS[algorithm])} if algorithm in _SETTINGS \
        else _shared_hints()
    parsed = {}
    for key, raw in values.items():
        if key not in hints:
            raise ValueError(_unknown_key_message(key, algorithm))
        parsed[key] = parse_value(key, raw, hints[key])
    return parsed


def _shared_hints() -> dict[str, Any]:
    hints = typing.get_type_hints(TrainConfig)
    hints.pop("algo")
    return hints


def _block_hints(cls: type) -> dict[str, Any]:
    """The types of a settings block's fields (not its class variables: ``algorithm``, ``supports_length_buckets``)."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def _unknown_key_message(key: str, algorithm: str) -> str:
    owners = [name for name, cls in _SETTINGS.items() if key in _block_hints(cls)]
    own = sorted(_block_hints(settings_class(algorithm)))
    if owners:
        return (f"config key {key!r} belongs to algorithm(s) {owners}, not to {algorithm!r}; {algorithm}'s own "
                f"settings: {own}")
    return f"unknown config key {key!r}; shared keys: {sorted(_shared_hints())}; {algorithm}'s settings: {own}"


def _check_type(key: str, value: Any, expected: Any) -> None:
    if not has_type(value, expected):
        raise ValueError(f"config {key}={value!r} must be of type {type_name(expected)}")


def make_env(config: TrainConfig):
    """The scenario's env (with the ``horizon`` and ``discount`` overrides if set)."""
    import envs_jax

    overrides = {"horizon": config.horizon} if config.horizon else {}
    if config.discount:
        overrides["discount"] = config.discount
    return envs_jax.make(config.scenario, **overrides)
