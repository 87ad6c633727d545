"""What the macro-action actor-critics share: their settings blocks and how a row of MacroMARL's actor-critic
scripts (``mac_cac.sh``, ``mac_iaicc.sh``, ``mac_naive_iacc.sh``; docs/hyperparameters.md) becomes a scenario's
values. Each learner module holds its own rows."""

from __future__ import annotations

import dataclasses
from typing import Any

from envs_jax.validation import check_choice, check_positive
from jaxmac.config import LearnerSettings


@dataclasses.dataclass(frozen=True)
class ActorCriticSettings(LearnerSettings, length_buckets=True):
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
        check_positive(owner, self, ("n_step", "actor_mlp_sizes", "actor_rnn_size", "critic_mlp_sizes",
                                      "critic_rnn_size"))
        for name in ("actor_mlp_sizes", "critic_mlp_sizes"):
            if len(getattr(self, name)) != 2:
                raise ValueError(f"{owner}: {name}={getattr(self, name)!r} must have two widths (before and after "
                                 "the GRU)")
        if not 0.0 < self.critic_lr < 1.0:
            raise ValueError(f"{owner}: critic_lr={self.critic_lr!r} must be in (0, 1)")

    def check_config(self, config) -> None:
        """The actor-critics train on the ``num_envs`` episodes of each round: refuse settings that say otherwise."""
        super().check_config(config)
        algorithm = config.algorithm
        if config.batch_size != config.num_envs:
            raise ValueError(f"{algorithm} learns on-policy from the num_envs={config.num_envs} episodes collected "
                             f"each round; batch_size={config.batch_size} must equal num_envs")
        if config.train_every_steps or config.start_train_episodes or config.target_update_steps or config.target_polyak:
            raise ValueError(f"{algorithm} updates once per round of num_envs episodes and copies its target critic "
                             f"every target_update_episodes; train_every_steps={config.train_every_steps}, "
                             f"start_train_episodes={config.start_train_episodes}, target_update_steps="
                             f"{config.target_update_steps} and target_polyak={config.target_polyak} must be 0")


@dataclasses.dataclass(frozen=True)
class IndependentActorsSettings(ActorCriticSettings):
    """Decentralised actors with a centralised critic that reads either the joint macro-observation history
    (``critic='history'``, the originals' ``*ICC``/``*ACC``) or the global state at decision points
    (``critic='state'``, ``*ISC``/``*ASC``, the Box Pushing scripts; a 5-layer MLP with ``critic_mid_size``)."""

    critic: str = "history"
    critic_mid_size: int = 32

    def _validate(self, owner: str) -> None:
        super()._validate(owner)
        check_choice(owner, "critic", self.critic, ("history", "state"))
        check_positive(owner, self, ("critic_mid_size",))
        if self.critic == "state" and self.critic_mlp_sizes[0] != self.critic_mlp_sizes[1]:
            raise ValueError(f"{owner}: critic='state' needs equal critic_mlp_sizes (its fc3 reads mlp[1] inputs, "
                             f"as the original); got {self.critic_mlp_sizes!r}")


# values of an actor-critic for tests and smoke runs (with jaxmac.presets.TINY); on-policy: the batch is the round's
# episodes, the ring keeps only their lengths; one length bucket: one compilation per test
TINY_VALUES = dict(actor_mlp_sizes=(8, 8), actor_rnn_size=8, critic_mlp_sizes=(8, 8), critic_rnn_size=8,
                   critic_mid_size=8, batch_size=8, buffer_episodes=8, grad_clip=0.0, length_buckets=1)


# MacroMARL's actor-critic scripts (experiments/*/mac_cac.sh, mac_iaicc.sh, mac_naive_iacc.sh; docs/hyperparameters.md):
# on-policy, one critic and one actor step per round of n_env = train_freq episodes, hard target copy every
# c_target_update_freq episodes, no gradient clipping, ε 1 → eps_end over eps_stable_at episodes from the start,
# 10 evaluation episodes every eval_freq − eval_freq % train_freq episodes, both training and evaluation episodes
# being the first to finish among n_env parallel envs (``collection='first_finished'``, jaxmac.collect; 'whole'
# is the unbiased alternative). Box Pushing runs the state critics
# (MacIAISC / NaiveMacIASC). A row names the script's values: a_lr → lr, c_lr → critic_lr, n_env → num_envs,
# c_target_update_freq → target_update_episodes, n_step_TD → n_step, eps_stable_at → eps_decay_episodes, total_epi →
# episodes, a_rnn / c_rnn / c_mlp → actor_rnn_size / critic_rnn_size / critic_mlp_sizes (absent = the block's
# default). A c_target_update_freq of at most n_env copies the target critic after every update in the original
# (no target critic): written 0 here, which runs the same.
def script_values(rows: dict[str, dict[str, Any]], **family_extra: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per-scenario values of an actor-critic script: each row's named values plus what every such script shares
    (on-policy batches of the round, one update per round, no clipping, evaluation every 100 − 100 % n_env
    episodes); ``family_extra[family]`` is added on that scenario family (e.g. ``boxpushing=dict(critic="state")``)."""
    out = {}
    for scenario, row in rows.items():
        values = dict(row)
        e = values["num_envs"]
        values.update(grad_clip=0.0, batch_size=e, buffer_episodes=e, updates_per_round=1, eps_start=1.0,
                      eps_decay_start=0, start_train_episodes=0, train_every_steps=0, target_update_steps=0,
                      target_polyak=0.0, eval_every_episodes=100 - 100 % e, eval_episodes=10,
                      collection="first_finished", length_buckets=4,
                      n_step=max(1, values["n_step"]), **family_extra.get(scenario.split("-")[0], {}))
        out[scenario] = values
    return out
