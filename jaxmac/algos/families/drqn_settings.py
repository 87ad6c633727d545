"""What MacroMARL's recurrent value learners share: the DRQN settings blocks and the per-scenario values of the
original value-based scripts (``mac_cen_q.sh``, ``mac_dec_q.sh``; docs/hyperparameters.md), which the learner
modules start their own tables from."""

from __future__ import annotations

import dataclasses
from typing import Any

from envs_jax.validation import check_fraction, check_positive
from jaxmac.config import LearnerSettings


@dataclasses.dataclass(frozen=True)
class DRQNSettings(LearnerSettings):
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
        check_positive(owner, self, ("mlp_sizes", "rnn_size"))
        if len(self.mlp_sizes) != 2:
            raise ValueError(f"{owner}: mlp_sizes={self.mlp_sizes!r} must have two widths (before and after the GRU)")
        if self.trace_len < 0:
            raise ValueError(f"{owner}: trace_len={self.trace_len!r} must be >= 0 (0 = whole episodes)")

    def __post_init__(self):
        self._validate(type(self).__name__)

    def check_batch_fits_buffer(self, config) -> None:
        if not self.trace_len:  # windows: a batch of windows may come from fewer stored episodes
            super().check_batch_fits_buffer(config)


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
        check_positive(owner, self, ("hysteresis_episodes",))
        for name in ("hysteresis_start", "hysteresis_end"):
            check_fraction(owner, name, getattr(self, name))


# block values of a DRQN learner for tests and smoke runs (with jaxmac.presets.TINY)
TINY_VALUES = dict(mlp_sizes=(8, 8), rnn_size=8, start_train_episodes=0, eps_decay_start=0, train_every_steps=20,
                   target_update_steps=200)


# --- the original value-based scripts' values ----------------------------------------------------------

# MacroMARL's value-based scripts (mac_cen_q.sh / mac_dec_q.sh, docs/hyperparameters.md): one gradient step every
# train_freq env steps after start_train episodes, hard target copy every 5000 env steps (the default), no
# gradient clipping, ε 1 → eps_end linearly over eps_l_d_steps episodes counted from start_train, one greedy
# evaluation episode per 100 (we run 10: the same policy, a less noisy curve). Where a scenario has no block the
# nearest one is used (BP-6 → BP-8, BP-14 → BP-12, OC-C → OC-B; Warehouse-D/E → Warehouse-C). Box Pushing
# samples trace_len windows from a buffer of 100K windows (~2,500 episodes of the early ~31 steps + 9 of
# padding); elsewhere whole episodes. ``num_envs`` 4: the original's single env updates the policy mid-episode;
# four episodes per round keep the policy lag to about one episode's worth of gradient steps.
SCRIPT_DEFAULTS = dict(grad_clip=0.0, target_update_steps=5000, num_envs=4, eval_every_episodes=100,
                       eval_episodes=10, eps_start=1.0)


def window_schedule(batch, every, eps_decay, **extra):
    """A Box Pushing block of the scripts: trace_len = train_freq windows, 40K episodes, warm-up 500."""
    return dict(SCRIPT_DEFAULTS, episodes=40_000, batch_size=batch, train_every_steps=every, trace_len=every, lr=1e-3,
                eps_end=0.05, eps_decay_episodes=eps_decay, start_train_episodes=500, eps_decay_start=500,
                buffer_episodes=2500, **extra)


def episode_schedule(batch, every, buffer, lr, eps_decay, start, episodes, **extra):
    """An Overcooked or Warehouse block of the scripts: whole episodes."""
    return dict(SCRIPT_DEFAULTS, episodes=episodes, batch_size=batch, train_every_steps=every, trace_len=0, lr=lr,
                eps_end=0.05, eps_decay_episodes=eps_decay, start_train_episodes=start, eps_decay_start=start,
                buffer_episodes=buffer, **extra)


_CEN_BP8 = window_schedule(64, 10, 4000)
_CEN_BP12 = window_schedule(128, 20, 6000)
_CEN_OCB = episode_schedule(64, 64, 500, 1e-4, 20_000, 500, 100_000, mlp_sizes=(128, 64), h_explore=True)
_CEN_WHC = episode_schedule(64, 64, 2000, 5e-5, 10_000, 2000, 80_000)
# mac_cen_q.sh (Mac-Cen-DDRQN; AVF starts from it)
CEN_SCRIPT_VALUES: dict[str, dict[str, Any]] = {
    "boxpushing-6x6": _CEN_BP8, "boxpushing-8x8": _CEN_BP8, "boxpushing-10x10": window_schedule(128, 14, 6000),
    "boxpushing-12x12": _CEN_BP12, "boxpushing-14x14": _CEN_BP12,
    "overcooked-A": episode_schedule(64, 64, 1000, 3e-5, 20_000, 1000, 100_000, mlp_sizes=(128, 64), h_explore=True),
    "overcooked-B": _CEN_OCB, "overcooked-C": _CEN_OCB,
    "warehouse-A": episode_schedule(64, 128, 2000, 1e-4, 10_000, 2000, 40_000),
    "warehouse-B": episode_schedule(64, 128, 2000, 1e-4, 10_000, 2000, 40_000),
    "warehouse-C": _CEN_WHC, "warehouse-D": _CEN_WHC, "warehouse-E": _CEN_WHC,
}

_DEC_BP12 = window_schedule(32, 20, 6000)
_DEC_OCA = episode_schedule(64, 64, 1000, 5e-4, 20_000, 1000, 100_000, h_explore=True, hysteresis_start=1.0,
                      hysteresis_end=1.0)
_DEC_WHC = episode_schedule(64, 128, 2000, 5e-5, 10_000, 2000, 80_000)
# mac_dec_q.sh (MacDec-Q; Mac-Dec-MADDRQN starts from it)
DEC_SCRIPT_VALUES: dict[str, dict[str, Any]] = {
    "boxpushing-6x6": window_schedule(64, 10, 4000), "boxpushing-8x8": window_schedule(64, 10, 4000),
    "boxpushing-10x10": window_schedule(32, 14, 6000), "boxpushing-12x12": _DEC_BP12, "boxpushing-14x14": _DEC_BP12,
    "overcooked-A": _DEC_OCA,
    "overcooked-B": dict(_DEC_OCA, batch_size=32, buffer_episodes=3000, start_train_episodes=3000,
                         eps_decay_start=3000),
    "overcooked-C": dict(_DEC_OCA, batch_size=32, buffer_episodes=3000, start_train_episodes=3000,
                         eps_decay_start=3000),
    "warehouse-A": episode_schedule(64, 128, 2000, 1e-4, 10_000, 2000, 40_000),
    "warehouse-B": episode_schedule(64, 128, 2000, 5e-5, 10_000, 2000, 40_000),
    "warehouse-C": _DEC_WHC, "warehouse-D": _DEC_WHC, "warehouse-E": _DEC_WHC,
}
