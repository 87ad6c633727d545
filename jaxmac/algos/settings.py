"""Typed, frozen, validated settings of each algorithm, and their values per scenario.

A run's configuration is ``TrainConfig`` (shared: budget, schedule, optimiser, replay, evaluation; see
``jaxmac.config``) plus one settings block of the algorithm it trains (``TrainConfig.algo``). Every
block is a frozen dataclass with its own validation; ``jaxmac.config`` routes ``--set NAME=VALUE`` to the
shared fields or to the block, and rejects a name that belongs to another algorithm.

``SCENARIO_VALUES[algorithm][scenario]`` holds the values of the original scripts (ToMacVF: the paper's
appendix tables as read by docs/decisions.md; baselines: MacroMARL's ``experiments/*.sh``, see
``docs/hyperparameters.md``), shared and block fields together in one flat dict.

This module imports nothing heavy, so the CLI validates a configuration before JAX starts.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jaxmac.scenarios import BOXPUSHING, OVERCOOKED, SCENARIOS, WAREHOUSE

MIXERS = ("qmix", "vdn", "qplex")  # AVF's
TOMACVF_MIXERS = ("qmix", "vdn", "qplex", "qtran")


def _check_choice(owner: str, name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{owner}: {name}={value!r} is not valid; choices: {list(choices)}")


def _check_positive(owner: str, obj: Any, names: tuple[str, ...]) -> None:
    for name in names:
        value = getattr(obj, name)
        if isinstance(value, tuple):
            if not value or any(v < 1 for v in value):
                raise ValueError(f"{owner}: {name}={value!r} must be a non-empty list of positive integers")
        elif value < 1:
            raise ValueError(f"{owner}: {name}={value!r} must be >= 1")


def _check_fraction(owner: str, name: str, value: float, low_open: bool = True) -> None:
    ok = (0.0 < value <= 1.0) if low_open else (0.0 <= value <= 1.0)
    if not ok:
        raise ValueError(f"{owner}: {name}={value!r} must be in {'(0' if low_open else '[0'}, 1]")


@dataclasses.dataclass(frozen=True)
class ToMacVFSettings:
    """ToMacVF (DECISIONS D1–D19)."""

    rnn_size: int = 32  # GRU width (D2)
    fc_size: int = 64
    n_step: int = 1  # micro-TD n (D11); 5 stopped the value divergence that idles Box Pushing 12x12 seeds (README §)
    macro_loss_weight: float = 1.0  # λ (D8)
    # D8: False = one step on L = micro + λ·macro; True = the paper's literal pseudocode, a micro-TD step then an
    # additional λ·macro-TD step (on the updated parameters) when the batch holds a completed macro-action
    sequential_updates: bool = False
    # the networks run on the sampled episodes packed back to back into the fewest of packed_row_sizes(B, length_buckets)
    # rows (``buffer.packing``; same losses) instead of one slot each cut to the longest (False, the reference)
    packing: bool = False
    # weight of squared TD errors where Q_tot is above its target; 1 = plain MSE (D18), < 1 = optimistic
    # weighting (OW-QMIX's weighting without its Q*, hysteretic Q-learning): keeps the value of a joint
    # action that succeeded when partners' exploration makes it fail elsewhere
    overestimate_weight: float = 1.0
    # anneal that weight linearly to overestimate_weight_end over overestimate_anneal_episodes training episodes,
    # starting after overestimate_anneal_start; 0 episodes (the default) keeps it constant. (0.3 → 1 over 8K–16K
    # episodes did not help Box Pushing 10x10 and 12x12: README, Results (Box Pushing) §)
    overestimate_weight_end: float = 1.0
    overestimate_anneal_start: int = 0
    overestimate_anneal_episodes: int = 0
    # D10: True = targets bootstrap at a time-limit truncation (the time limit is not part of the MDP; MacroMARL);
    # False = the last step of a truncated episode is terminal (``views.time_limit_as_termination``), which anchors
    # every value at the horizon — right when the agents see the absolute time step (``use_time_pe``); it did not
    # stop the diverging Box Pushing 12x12 seed (README §)
    bootstrap_time_limit: bool = True
    buffer: str = "mac_sjert"  # D16 ablation: "mac_jert"
    mixer: str = "qmix"  # D19: "qmix", "vdn", "qplex" (ToMacVF_QPLEX), "qtran" (ToMacVF_Qtran)
    mixer_params: str = "atpg"  # D16: "state" = ToMacVF w/o ATPG (the mixer conditioned on s_t only)
    obs_mode: str = "real"  # D1
    mixer_embed: int = 32
    hyper_hidden: int = 64  # hidden width of the mixer's hyper-networks (QTRAN: of Q_jt and V_jt)
    qtran_opt_weight: float = 1.0  # QTRAN's L_opt weight (pymarl's opt_loss)
    qtran_nopt_weight: float = 0.1  # QTRAN's L_nopt weight (pymarl's nopt_min_loss)
    attn_dim: int = 32
    attn_delta: float = 0.05  # agent-attention threshold δ (D5)
    attn_window: int = 0  # causal window in steps; 0 = whole episode (D4)
    time_pe_dim: int = 16  # D3
    progress_pe_dim: int = 8  # D3
    use_time_pe: bool = True  # D3 flag

    def __post_init__(self):
        owner = "tomacvf"
        _check_choice(owner, "buffer", self.buffer, ("mac_sjert", "mac_jert"))
        _check_choice(owner, "mixer", self.mixer, TOMACVF_MIXERS)
        _check_choice(owner, "mixer_params", self.mixer_params, ("atpg", "state"))
        if self.packing and self.buffer == "mac_jert":
            raise ValueError(f"{owner}: packing=True packs Mac-SJERT episode slots; buffer='mac_jert' trains on the "
                             f"squeezed sequence, which is not packed: add packing=false (the scenarios turn packing "
                             f"on for Mac-SJERT; length_buckets still cut the squeezed sequence)")
        if self.sequential_updates and self.buffer == "mac_jert":
            raise ValueError(f"{owner}: sequential_updates=True alternates micro- and macro-TD steps, but "
                             f"buffer='mac_jert' trains one TD loss; use buffer='mac_sjert' with it")
        if self.mixer != "qtran" and (self.qtran_opt_weight, self.qtran_nopt_weight) != (1.0, 0.1):
            raise ValueError(f"{owner}: qtran_opt_weight/qtran_nopt_weight are QTRAN's loss weights, but "
                             f"mixer={self.mixer!r}; set mixer='qtran' or leave them at 1.0/0.1")
        for name in ("qtran_opt_weight", "qtran_nopt_weight"):
            if getattr(self, name) < 0:
                raise ValueError(f"{owner}: {name}={getattr(self, name)!r} must be >= 0")
        _check_choice(owner, "obs_mode", self.obs_mode, ("real", "macro"))
        if self.buffer == "mac_jert" and self.obs_mode != "macro":
            raise ValueError(f"{owner}: buffer='mac_jert' keeps only the decision points' frozen macro-observations, so "
                             f"obs_mode={self.obs_mode!r} cannot be served; set obs_mode='macro' with it (or keep "
                             f"buffer='mac_sjert')")
        _check_positive(owner, self, ("rnn_size", "fc_size", "n_step", "mixer_embed", "hyper_hidden", "attn_dim",
                                      "time_pe_dim", "progress_pe_dim"))
        for name in ("time_pe_dim", "progress_pe_dim"):
            if getattr(self, name) % 2:
                raise ValueError(f"{owner}: {name}={getattr(self, name)!r} must be even (sine and cosine pairs)")
        if self.attn_window < 0:
            raise ValueError(f"{owner}: attn_window={self.attn_window!r} must be >= 0 (0 = whole episode)")
        if not 0.0 <= self.attn_delta < 1.0:
            raise ValueError(f"{owner}: attn_delta={self.attn_delta!r} must be in [0, 1)")
        _check_fraction(owner, "overestimate_weight", self.overestimate_weight)
        _check_fraction(owner, "overestimate_weight_end", self.overestimate_weight_end)
        for name in ("overestimate_anneal_start", "overestimate_anneal_episodes"):
            if getattr(self, name) < 0:
                raise ValueError(f"{owner}: {name}={getattr(self, name)!r} must be >= 0 (episodes; "
                                 f"overestimate_anneal_episodes=0 keeps overestimate_weight constant)")
        shape = (self.overestimate_weight_end, self.overestimate_anneal_start)
        if self.overestimate_anneal_episodes == 0 and shape != (1.0, 0):
            raise ValueError(f"{owner}: overestimate_weight_end={shape[0]!r} and overestimate_anneal_start="
                             f"{shape[1]!r} shape an annealing that overestimate_anneal_episodes=0 turns off; set "
                             f"overestimate_anneal_episodes >= 1 with them")
        if self.macro_loss_weight < 0:
            raise ValueError(f"{owner}: macro_loss_weight={self.macro_loss_weight!r} must be >= 0")


@dataclasses.dataclass(frozen=True)
class DRQNSettings:
    """Fields every MacroMARL-style recurrent value learner shares (docs/baselines.md §1.0–1.3).

    ``trace_len`` > 0 samples windows of that many primitive steps from stored episodes (the originals on
    Box Pushing); 0 samples whole episodes (``sample_epi``). ``h_explore`` keeps the recurrent state while
    acting (the Overcooked scripts); without it the behaviour policy restarts its GRU from zero at every
    decision (memoryless exploration, as the original runner). Greedy evaluation always keeps the state.
    """

    mlp_sizes: tuple[int, ...] = (32, 32)
    rnn_size: int = 32
    trace_len: int = 10
    h_explore: bool = False

    def _validate(self, owner: str) -> None:
        _check_positive(owner, self, ("mlp_sizes", "rnn_size"))
        if len(self.mlp_sizes) != 2:
            raise ValueError(f"{owner}: mlp_sizes={self.mlp_sizes!r} must have two widths (before and after the GRU)")
        if self.trace_len < 0:
            raise ValueError(f"{owner}: trace_len={self.trace_len!r} must be >= 0 (0 = whole episodes)")

    def __post_init__(self):
        self._validate(type(self).__name__)


@dataclasses.dataclass(frozen=True)
class HystereticDRQNSettings(DRQNSettings):
    """A DRQN learner with hysteresis β: TD errors where Q is above its target are scaled by β (δ ← max(βδ, δ));
    β linear from ``hysteresis_start`` to ``hysteresis_end`` over ``hysteresis_episodes`` training episodes
    counted from ``start_train_episodes`` (the originals' ``dynamic_h``)."""

    hysteresis_start: float = 0.2
    hysteresis_end: float = 0.4
    hysteresis_episodes: int = 4000

    def _validate(self, owner: str) -> None:
        super()._validate(owner)
        _check_positive(owner, self, ("hysteresis_episodes",))
        for name in ("hysteresis_start", "hysteresis_end"):
            _check_fraction(owner, name, getattr(self, name))


@dataclasses.dataclass(frozen=True)
class MacCenDDRQNSettings(DRQNSettings):
    """Mac-Cen-DDRQN (MacCen-Q, docs/baselines.md §1.2): one centralised recurrent Q over the joint action space (plain
    MSE: the scripts' hysteresis is 1)."""

    rnn_size: int = 64
    max_joint_actions: int = 4096  # refuse envs whose joint macro-action space is larger

    def __post_init__(self):
        self._validate("maccen_ddrqn")
        _check_positive("maccen_ddrqn", self, ("max_joint_actions",))


@dataclasses.dataclass(frozen=True)
class MacDecQSettings(HystereticDRQNSettings):
    """MacDec-Q (Dec-HDDRQN on Mac-CERT, docs/baselines.md §1.1): per-agent DRQNs, hysteretic double-Q."""

    def __post_init__(self):
        self._validate("macdec_q")


@dataclasses.dataclass(frozen=True)
class MacDecDDRQNSettings(HystereticDRQNSettings):
    """Mac-Dec-MADDRQN (docs/baselines.md §1.3): MacCen-Q plus per-agent DRQNs whose targets take their component of
    the centralised conditional argmax. ``rnn_size``/``mlp_sizes`` are the decentralised nets'."""

    trace_len: int = 15
    cen_rnn_size: int = 64
    cen_mlp_sizes: tuple[int, ...] = (32, 32)
    # behaviour policy: centralised conditional ε-greedy until cen_explore_episodes, then decentralised
    cen_explore_episodes: int = 1_000_000
    max_joint_actions: int = 4096

    def __post_init__(self):
        self._validate("macdec_ddrqn")
        _check_positive("macdec_ddrqn", self, ("cen_rnn_size", "cen_mlp_sizes", "max_joint_actions"))
        if len(self.cen_mlp_sizes) != 2:
            raise ValueError(f"macdec_ddrqn: cen_mlp_sizes={self.cen_mlp_sizes!r} must have two widths")
        if self.cen_explore_episodes < 0:
            raise ValueError(f"macdec_ddrqn: cen_explore_episodes={self.cen_explore_episodes!r} must be >= 0")


@dataclasses.dataclass(frozen=True)
class AVFSettings(DRQNSettings):
    """AVF (docs/baselines.md §1.7): per-agent recurrent Q on Mac-JERT, mixed into Q_tot, conditional double-Q.

    ``scheme``: 'd0' trains every agent's utility at every joint transition; 'd1' gives agents whose
    macro-action is still running zero gradient (their utility enters Q_tot detached); 'd2' gives them zero
    utility in the mixer. ``macro_state``: the mixer is conditioned on the concatenation of every agent's
    macro-state (the env state when it selected its running macro-action; the "MS" variants) instead of the
    state at the joint decision point.
    """

    rnn_size: int = 64
    mlp_sizes: tuple[int, ...] = (64, 64)
    mixer: str = "qmix"
    scheme: str = "d0"
    macro_state: bool = True
    mixer_embed: int = 32
    hyper_hidden: int = 32

    def __post_init__(self):
        self._validate("avf")
        _check_choice("avf", "mixer", self.mixer, MIXERS)
        _check_choice("avf", "scheme", self.scheme, ("d0", "d1", "d2"))
        _check_positive("avf", self, ("mixer_embed", "hyper_hidden"))


@dataclasses.dataclass(frozen=True)
class ActorCriticSettings:
    """What the macro-action actor-critics share (docs/baselines.md §1.0, §1.4–1.6). The actor's learning rate is the
    shared ``lr``; ``critic_lr`` the critic's. ``n_step`` macro transitions per critic target (the scripts'
    ``n_step_TD``: 0 and 1 both mean one-step, written 1 here). Networks as the originals: fc–fc–GRU–fc–fc actors
    and history critics, ``critic_mid_size`` the middle layer of a state critic."""

    critic_lr: float = 1e-3
    n_step: int = 1
    actor_mlp_sizes: tuple[int, ...] = (32, 32)
    actor_rnn_size: int = 32
    critic_mlp_sizes: tuple[int, ...] = (32, 32)
    critic_rnn_size: int = 32

    def _validate(self, owner: str) -> None:
        _check_positive(owner, self, ("n_step", "actor_mlp_sizes", "actor_rnn_size", "critic_mlp_sizes",
                                      "critic_rnn_size"))
        for name in ("actor_mlp_sizes", "critic_mlp_sizes"):
            if len(getattr(self, name)) != 2:
                raise ValueError(f"{owner}: {name}={getattr(self, name)!r} must have two widths (before and after "
                                 "the GRU)")
        if not 0.0 < self.critic_lr < 1.0:
            raise ValueError(f"{owner}: critic_lr={self.critic_lr!r} must be in (0, 1)")


@dataclasses.dataclass(frozen=True)
class IndependentActorsSettings(ActorCriticSettings):
    """Decentralised actors with a centralised critic that reads either the joint macro-observation history
    (``critic='history'``, the originals' ``*ICC``/``*ACC``) or the global state at decision points
    (``critic='state'``, ``*ISC``/``*ASC``, the Box Pushing scripts; a 5-layer MLP with ``critic_mid_size``)."""

    critic: str = "history"
    critic_mid_size: int = 32

    def _validate(self, owner: str) -> None:
        super()._validate(owner)
        _check_choice(owner, "critic", self.critic, ("history", "state"))
        _check_positive(owner, self, ("critic_mid_size",))
        if self.critic == "state" and self.critic_mlp_sizes[0] != self.critic_mlp_sizes[1]:
            raise ValueError(f"{owner}: critic='state' needs equal critic_mlp_sizes (its fc3 reads mlp[1] inputs, "
                             f"as the original); got {self.critic_mlp_sizes!r}")


@dataclasses.dataclass(frozen=True)
class MacIAICCSettings(IndependentActorsSettings):
    """Mac-IAICC (docs/baselines.md §1.6): per-agent actors, an individual centralised critic V_i per agent."""

    def __post_init__(self):
        self._validate("mac_iaicc")


@dataclasses.dataclass(frozen=True)
class MacNIACCSettings(IndependentActorsSettings):
    """Mac-NIACC (docs/baselines.md §1.5): per-agent actors, one joint critic, the joint ("naive") advantage."""

    def __post_init__(self):
        self._validate("mac_niacc")


@dataclasses.dataclass(frozen=True)
class MacCACSettings(ActorCriticSettings):
    """Mac-CAC (docs/baselines.md §1.4): one joint actor over the joint macro-action space and one joint history critic."""

    max_joint_actions: int = 4096

    def __post_init__(self):
        self._validate("mac_cac")
        _check_positive("mac_cac", self, ("max_joint_actions",))


# --- per-scenario values (flat: shared TrainConfig fields and the block's fields together) -------------


_BP = dict(length_buckets=4, packing=True, batch_size=128, eps_end=0.1, eps_decay_episodes=4000, buffer_episodes=5000, n_step=1)
_OC = dict(length_buckets=4, packing=True, lr=3e-4, rnn_size=32, n_step=5, eps_end=0.05, eps_decay_episodes=20_000,
           buffer_episodes=2000, target_update_episodes=16, updates_per_round=1)
_WH = dict(length_buckets=4, packing=True, batch_size=32, num_envs=8, rnn_size=64, n_step=5, eps_decay_episodes=10_000,
           buffer_episodes=2000, updates_per_round=1)

TOMACVF_PAPER: dict[str, dict[str, Any]] = {
    # Every scenario: the networks of the update run on the sampled episodes packed back to back into the fewest of
    # packed_row_sizes(B, 4) rows (``packing``; with packing=False on the batch cut to the shortest of 4 lengths
    # H/8 … H that holds it; length_buckets=1 and packing=False = the full horizon, the reference path).
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

# What jaxmac changes in the paper's table so that ToMacVF learns (docs/tomacvf-settings.md has the probes behind
# each value): on Overcooked the paper's target copy every 16 episodes happens after every gradient step of a round
# of 32-64 episodes (no target network: the values grow without bound) and one step per round is too few (the
# parameters barely move in 20K episodes); on Warehouse gamma = 1 bootstraps the time limit with nothing to
# contract it and the values leave the return bounds (learning gamma 0.99; returns are reported undiscounted).
TOMACVF_LEARNING_CHANGES: dict[str, dict[str, Any]] = {
    **{name: dict(target_update_episodes=128, updates_per_round=4) for name in OVERCOOKED},
    **{name: dict(discount=0.99) for name in WAREHOUSE},
}
TOMACVF: dict[str, dict[str, Any]] = {
    name: dict(values, **TOMACVF_LEARNING_CHANGES.get(name, {})) for name, values in TOMACVF_PAPER.items()
}

# MacroMARL's value-based scripts (mac_cen_q.sh / mac_dec_q.sh, docs/hyperparameters.md): one gradient step every
# train_freq env steps after start_train episodes, hard target copy every 5000 env steps (the default), no
# gradient clipping, ε 1 → eps_end linearly over eps_l_d_steps episodes counted from start_train, one greedy
# evaluation episode per 100 (we run 10: the same policy, a less noisy curve). Where a scenario has no block the
# nearest one is used (BP-6 → BP-8, BP-14 → BP-12, OC-C → OC-B; Warehouse-D/E → Warehouse-C). Box Pushing
# samples trace_len windows from a buffer of 100K windows (~2,500 episodes of the early ~31 steps + 9 of
# padding); elsewhere whole episodes. ``num_envs`` 4: the original's single env updates the policy mid-episode;
# four episodes per round keep the policy lag to about one episode's worth of gradient steps.
_VALUE = dict(grad_clip=0.0, target_update_steps=5000, num_envs=4, eval_every_episodes=100, eval_episodes=10,
              eps_start=1.0)


def _value_bp(batch, every, eps_decay, **extra):
    return dict(_VALUE, episodes=40_000, batch_size=batch, train_every_steps=every, trace_len=every, lr=1e-3,
                eps_end=0.05, eps_decay_episodes=eps_decay, start_train_episodes=500, eps_decay_start=500,
                buffer_episodes=2500, **extra)


def _value_epi(batch, every, buffer, lr, eps_decay, start, episodes, **extra):
    return dict(_VALUE, episodes=episodes, batch_size=batch, train_every_steps=every, trace_len=0, lr=lr,
                eps_end=0.05, eps_decay_episodes=eps_decay, start_train_episodes=start, eps_decay_start=start,
                buffer_episodes=buffer, **extra)


_CEN_BP8 = _value_bp(64, 10, 4000)
_CEN_BP12 = _value_bp(128, 20, 6000)
_CEN_OCB = _value_epi(64, 64, 500, 1e-4, 20_000, 500, 100_000, mlp_sizes=(128, 64), h_explore=True)
_CEN_WHC = _value_epi(64, 64, 2000, 5e-5, 10_000, 2000, 80_000)
MACCEN: dict[str, dict[str, Any]] = {
    "boxpushing-6x6": _CEN_BP8, "boxpushing-8x8": _CEN_BP8, "boxpushing-10x10": _value_bp(128, 14, 6000),
    "boxpushing-12x12": _CEN_BP12, "boxpushing-14x14": _CEN_BP12,
    "overcooked-A": _value_epi(64, 64, 1000, 3e-5, 20_000, 1000, 100_000, mlp_sizes=(128, 64), h_explore=True),
    "overcooked-B": _CEN_OCB, "overcooked-C": _CEN_OCB,
    "warehouse-A": _value_epi(64, 128, 2000, 1e-4, 10_000, 2000, 40_000),
    "warehouse-B": _value_epi(64, 128, 2000, 1e-4, 10_000, 2000, 40_000),
    "warehouse-C": _CEN_WHC, "warehouse-D": _CEN_WHC, "warehouse-E": _CEN_WHC,
}

_DEC_BP12 = _value_bp(32, 20, 6000)
_DEC_OCA = _value_epi(64, 64, 1000, 5e-4, 20_000, 1000, 100_000, h_explore=True, hysteresis_start=1.0,
                      hysteresis_end=1.0)
_DEC_WHC = _value_epi(64, 128, 2000, 5e-5, 10_000, 2000, 80_000)
MACDEC_Q: dict[str, dict[str, Any]] = {
    "boxpushing-6x6": _value_bp(64, 10, 4000), "boxpushing-8x8": _value_bp(64, 10, 4000),
    "boxpushing-10x10": _value_bp(32, 14, 6000), "boxpushing-12x12": _DEC_BP12, "boxpushing-14x14": _DEC_BP12,
    "overcooked-A": _DEC_OCA,
    "overcooked-B": dict(_DEC_OCA, batch_size=32, buffer_episodes=3000, start_train_episodes=3000,
                         eps_decay_start=3000),
    "overcooked-C": dict(_DEC_OCA, batch_size=32, buffer_episodes=3000, start_train_episodes=3000,
                         eps_decay_start=3000),
    "warehouse-A": _value_epi(64, 128, 2000, 1e-4, 10_000, 2000, 40_000),
    "warehouse-B": _value_epi(64, 128, 2000, 5e-5, 10_000, 2000, 40_000),
    "warehouse-C": _DEC_WHC, "warehouse-D": _DEC_WHC, "warehouse-E": _DEC_WHC,
}

# Mac-Dec-MADDRQN has no script in MacroMARL; the ICRA'20 README commands (docs/baselines.md §1.3): Box Pushing
# trace_len = train_freq = 15, batch 128, ε → 0.1, start_train 2 episodes, centralised exploration throughout,
# 15K episodes on BP-10 (we keep 40K like every other BP learner); elsewhere the MacDec-Q values with
# centralised exploration.
_DDRQN_BP = dict(_value_bp(128, 15, 4000), eps_end=0.1, start_train_episodes=2, eps_decay_start=2)
MACDEC_DDRQN: dict[str, dict[str, Any]] = {
    **{name: _DDRQN_BP for name in BOXPUSHING},
    **{name: dict(MACDEC_Q[name], cen_mlp_sizes=(128, 64)) for name in OVERCOOKED},
    **{name: MACDEC_Q[name] for name in WAREHOUSE},
}

# AVF (docs/baselines.md §1.7): the value learners' schedule with AVF's own optimiser, buffer and target settings:
# lr 5e-4, batch 32, 2,500 episodes, Polyak ω = 0.995 after every step; windows as the value learners.
_AVF = dict(lr=5e-4, batch_size=32, buffer_episodes=2500, target_polyak=0.005)
AVF: dict[str, dict[str, Any]] = {
    name: dict(MACCEN[name], **_AVF, mlp_sizes=(64, 64),
               start_train_episodes=min(MACCEN[name]["start_train_episodes"], 2500),
               h_explore=True)  # AVF is not MacroMARL's runner: it keeps its recurrent state while exploring
    for name in SCENARIOS
}


# MacroMARL's actor-critic scripts (experiments/*/mac_cac.sh, mac_iaicc.sh, mac_naive_iacc.sh; docs/hyperparameters.md):
# on-policy, one critic and one actor step per round of n_env = train_freq episodes, hard target copy every
# c_target_update_freq episodes, no gradient clipping, ε 1 → eps_end over eps_stable_at episodes from the start,
# 10 evaluation episodes every eval_freq − eval_freq % train_freq episodes, both training and evaluation episodes
# being the first to finish among n_env parallel envs (``collection='first_finished'``, jaxmac.collect; 'whole'
# is the unbiased alternative). Box Pushing runs the state critics
# (MacIAISC / NaiveMacIASC). Columns: a_lr, c_lr, n_env, c_target_update_freq, n_step_TD, eps_end, eps_stable_at,
# total_epi, a_rnn, c_rnn, c_mlp ("·" = the default). A c_target_update_freq of at most n_env copies the target
# critic after every update in the original (no target critic): written 0 here, which runs the same.
_D = None
_AC_COLUMNS = ("lr", "critic_lr", "num_envs", "target_update_episodes", "n_step", "eps_end", "eps_decay_episodes",
               "episodes", "actor_rnn_size", "critic_rnn_size", "critic_mlp_sizes")


def _ac_rows(rows: dict[str, tuple], **extra) -> dict[str, dict[str, Any]]:
    out = {}
    for scenario, row in rows.items():
        values = {k: v for k, v in zip(_AC_COLUMNS, row) if v is not _D}
        e = values["num_envs"]
        values.update(grad_clip=0.0, batch_size=e, buffer_episodes=e, updates_per_round=1, eps_start=1.0,
                      eps_decay_start=0, start_train_episodes=0, train_every_steps=0, target_update_steps=0,
                      target_polyak=0.0, eval_every_episodes=100 - 100 % e, eval_episodes=10,
                      collection="first_finished", length_buckets=4,
                      n_step=max(1, values["n_step"]), **extra.get(scenario.split("-")[0], {}))
        out[scenario] = values
    return out


_OC_C = (128, 64)
_STATE_BP = {"boxpushing": dict(critic="state")}
MAC_CAC = _ac_rows({
    "boxpushing-6x6": (1e-3, 3e-3, 2, 64, 3, 0.01, 4000, 40_000, _D, _D, _D),
    "boxpushing-8x8": (3e-4, 3e-3, 32, 0, 3, 0.01, 4000, 40_000, _D, _D, _D),  # the script: 32
    "boxpushing-10x10": (5e-4, 1e-3, 32, 128, 3, 0.01, 6000, 40_000, _D, _D, _D),
    "boxpushing-12x12": (1e-3, 3e-3, 8, 128, 0, 0.01, 6000, 40_000, _D, _D, _D),
    "boxpushing-14x14": (1e-3, 1e-3, 16, 128, 3, 0.01, 8000, 40_000, _D, _D, _D),
    "overcooked-A": (1e-4, 3e-3, 8, 32, 5, 0.05, 20_000, 100_000, _D, 64, _OC_C),
    "overcooked-B": (1e-4, 3e-3, 4, 16, 3, 0.05, 20_000, 120_000, _D, 64, _OC_C),
    "overcooked-C": (1e-4, 3e-3, 8, 32, 3, 0.05, 20_000, 100_000, _D, 64, _OC_C),
    "warehouse-A": (3e-4, 3e-3, 4, 32, 5, 0.05, 10_000, 40_000, 64, 64, _D),
    "warehouse-B": (3e-4, 3e-3, 4, 16, 5, 0.05, 10_000, 40_000, 64, 64, _D),
    "warehouse-C": (5e-4, 1e-3, 8, 64, 5, 0.01, 10_000, 80_000, 64, 64, _D),
    "warehouse-D": (3e-4, 3e-3, 8, 64, 3, 0.01, 10_000, 80_000, 64, 64, _D),
    "warehouse-E": (3e-4, 3e-3, 8, 64, 3, 0.01, 10_000, 100_000, 64, 64, _D),
})
MAC_IAICC = _ac_rows({
    "boxpushing-6x6": (3e-4, 3e-3, 32, 128, 0, 0.01, 4000, 40_000, _D, _D, _D),
    "boxpushing-8x8": (3e-4, 3e-3, 32, 64, 0, 0.01, 4000, 40_000, _D, _D, _D),
    "boxpushing-10x10": (3e-4, 3e-3, 32, 64, 0, 0.01, 6000, 40_000, _D, _D, _D),
    "boxpushing-12x12": (3e-4, 3e-3, 48, 144, 0, 0.01, 6000, 40_000, _D, _D, _D),
    "boxpushing-14x14": (5e-4, 3e-3, 48, 0, 0, 0.01, 8000, 40_000, _D, _D, _D),  # the script: 48
    "overcooked-A": (3e-4, 3e-3, 8, 32, 5, 0.05, 20_000, 100_000, _D, 64, _OC_C),
    "overcooked-B": (3e-4, 3e-3, 4, 32, 5, 0.05, 20_000, 120_000, _D, 64, _OC_C),
    "overcooked-C": (3e-4, 3e-3, 8, 32, 5, 0.05, 20_000, 100_000, _D, 64, _OC_C),
    "warehouse-A": (5e-4, 5e-4, 4, 32, 5, 0.05, 10_000, 40_000, 32, 64, _D),
    "warehouse-B": (5e-4, 5e-4, 4, 32, 5, 0.05, 10_000, 40_000, 32, 64, _D),
    "warehouse-C": (3e-4, 3e-3, 4, 64, 5, 0.01, 10_000, 80_000, 32, 64, _D),
    "warehouse-D": (3e-4, 3e-3, 8, 64, 5, 0.01, 10_000, 80_000, 32, 64, _D),
    "warehouse-E": (3e-4, 3e-3, 8, 64, 5, 0.01, 10_000, 100_000, 32, 64, _D),
}, **_STATE_BP)
MAC_NIACC = _ac_rows({
    "boxpushing-6x6": (3e-4, 3e-3, 32, 128, 0, 0.01, 4000, 40_000, _D, _D, _D),
    "boxpushing-8x8": (5e-4, 1e-3, 32, 128, 0, 0.01, 4000, 40_000, _D, _D, _D),
    "boxpushing-10x10": (5e-4, 1e-3, 32, 128, 0, 0.01, 6000, 40_000, _D, _D, _D),
    "boxpushing-12x12": (5e-4, 5e-4, 48, 0, 0, 0.01, 6000, 40_000, _D, _D, _D),  # the script: 48
    "boxpushing-14x14": (5e-4, 5e-4, 32, 128, 0, 0.01, 8000, 40_000, _D, _D, _D),
    "overcooked-A": (3e-4, 3e-3, 4, 16, 5, 0.05, 20_000, 100_000, _D, 64, _OC_C),
    "overcooked-B": (3e-4, 3e-3, 8, 16, 5, 0.05, 20_000, 120_000, _D, 64, _OC_C),
    "overcooked-C": (3e-4, 3e-3, 8, 16, 5, 0.05, 20_000, 100_000, _D, 64, _OC_C),
    "warehouse-A": (3e-4, 3e-3, 4, 32, 3, 0.01, 10_000, 40_000, 32, 64, _D),
    "warehouse-B": (3e-4, 3e-3, 4, 32, 3, 0.01, 10_000, 40_000, 32, 64, _D),
    "warehouse-C": (3e-4, 3e-3, 16, 64, 5, 0.01, 10_000, 80_000, 32, 64, _D),
    "warehouse-D": (3e-4, 3e-3, 8, 64, 5, 0.01, 10_000, 80_000, 32, 64, _D),
    "warehouse-E": (5e-4, 5e-4, 4, 32, 5, 0.01, 10_000, 100_000, 32, 64, _D),
}, **_STATE_BP)
