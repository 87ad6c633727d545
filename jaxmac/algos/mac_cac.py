"""Mac-CAC (centralised macro-action actor-critic; docs/baselines.md §1.4): one joint actor, one joint critic.

The actor π(m^J | h^J) reads the joint macro-observation history at every joint decision point (Mac-JERT) and
outputs logits over the joint macro-action space |M_1|·…·|M_n|. Acting samples from ``π_ε`` *conditionally*:
only joint actions whose busy agents keep their running macro-action (and whose free agents pick available ones)
can be drawn, and only the free agents' components are executed. Training uses the log-probability of the
executed joint action under the *unconditioned* ``π_ε``, as the original does. The joint history critic V(h^J),
its n-step macro returns and the critic-then-actor update are Mac-NIACC's (``jaxmac.algos.families.actor_critic``)::

    A_j = G_j − V(h^J_j),   L_actor = −Σ_j γ^{t_j} log π_ε(m^J_j | h^J_j) A_j / Σ_j 1
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from envs_jax.validation import check_positive
from jaxmac.algos.base import (
    Algorithm,
    Learner,
    clipped_adam,
    per_part_optimizer,
)
from jaxmac.algos.families import actor_critic as ac
from jaxmac.algos.families import centralised
from jaxmac.algos.families.actor_critic_settings import TINY_VALUES, ActorCriticSettings, script_values
from jaxmac.algos.targets import ravel_joint
from jaxmac.buffer.sources import on_policy_source, store_length
from jaxmac.config import TrainConfig
from jaxmac.losses import masked_mean
from jaxmac.networks.drqn import DRQN


@dataclasses.dataclass(frozen=True)
class MacCACSettings(ActorCriticSettings, algorithm="mac_cac"):
    """Mac-CAC (docs/baselines.md §1.4): one joint actor over the joint macro-action space and one joint history critic."""

    max_joint_actions: int = 4096

    def __post_init__(self):
        self._validate("mac_cac")
        check_positive("mac_cac", self, ("max_joint_actions",))


# mac_cac.sh's rows (docs/hyperparameters.md)
_OC_CRITIC = (128, 64)  # the Overcooked scripts' critic MLP
SCENARIO_VALUES = script_values({
    "boxpushing-6x6": dict(lr=1e-3, critic_lr=3e-3, num_envs=2, target_update_episodes=64, n_step=3, eps_end=0.01,
                           eps_decay_episodes=4000, episodes=40_000),
    "boxpushing-8x8": dict(lr=3e-4, critic_lr=3e-3, num_envs=32, target_update_episodes=0, n_step=3, eps_end=0.01,
                           eps_decay_episodes=4000, episodes=40_000),  # the script: 32
    "boxpushing-10x10": dict(lr=5e-4, critic_lr=1e-3, num_envs=32, target_update_episodes=128, n_step=3,
                             eps_end=0.01, eps_decay_episodes=6000, episodes=40_000),
    "boxpushing-12x12": dict(lr=1e-3, critic_lr=3e-3, num_envs=8, target_update_episodes=128, n_step=0, eps_end=0.01,
                             eps_decay_episodes=6000, episodes=40_000),
    "boxpushing-14x14": dict(lr=1e-3, critic_lr=1e-3, num_envs=16, target_update_episodes=128, n_step=3,
                             eps_end=0.01, eps_decay_episodes=8000, episodes=40_000),
    "overcooked-A": dict(lr=1e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=32, n_step=5, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=100_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "overcooked-B": dict(lr=1e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=16, n_step=3, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=120_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "overcooked-C": dict(lr=1e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=32, n_step=3, eps_end=0.05,
                         eps_decay_episodes=20_000, episodes=100_000, critic_rnn_size=64,
                         critic_mlp_sizes=_OC_CRITIC),
    "warehouse-A": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=32, n_step=5, eps_end=0.05,
                        eps_decay_episodes=10_000, episodes=40_000, actor_rnn_size=64, critic_rnn_size=64),
    "warehouse-B": dict(lr=3e-4, critic_lr=3e-3, num_envs=4, target_update_episodes=16, n_step=5, eps_end=0.05,
                        eps_decay_episodes=10_000, episodes=40_000, actor_rnn_size=64, critic_rnn_size=64),
    "warehouse-C": dict(lr=5e-4, critic_lr=1e-3, num_envs=8, target_update_episodes=64, n_step=5, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=80_000, actor_rnn_size=64, critic_rnn_size=64),
    "warehouse-D": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=64, n_step=3, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=80_000, actor_rnn_size=64, critic_rnn_size=64),
    "warehouse-E": dict(lr=3e-4, critic_lr=3e-3, num_envs=8, target_update_episodes=64, n_step=3, eps_end=0.01,
                        eps_decay_episodes=10_000, episodes=100_000, actor_rnn_size=64, critic_rnn_size=64),
})


def make_mac_cac(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    counts = spec.num_actions
    joint = centralised.check_joint_space(env, settings.max_joint_actions, "mac_cac")
    actor = DRQN(mlp=settings.actor_mlp_sizes, hidden=settings.actor_rnn_size, out=joint)
    critic = DRQN(mlp=settings.critic_mlp_sizes, hidden=settings.critic_rnn_size, out=1)
    gamma = spec.discount

    def init_params(key):
        k_actor, k_critic = jax.random.split(key)
        x = jnp.zeros((1, spec.num_agents * spec.obs_dim))
        reset = jnp.zeros((1,), bool)
        return {"actor": actor.init(k_actor, x, reset, jnp.zeros((settings.actor_rnn_size,))),
                "critic": critic.init(k_critic, x, reset, jnp.zeros((settings.critic_rnn_size,)))}

    def act(params, carry, ts, key, epsilon):
        return ac.joint_actor_step(actor, params["actor"], carry, ts, key, epsilon, counts)

    def greedy_act(params, carry, ts, key, epsilon):
        return ac.joint_actor_step(actor, params["actor"], carry, ts, key, epsilon, counts, greedy=True)

    def values(critic_params, jert):  # f32[E, H + 1]: V(h^J_k), then the value after the last entry
        obs = ac.joint_history(jert)
        return centralised.sequence_q(critic, critic_params, obs.reshape(obs.shape[:2] + (1, -1)))[..., 0]

    def critic_values(critic_params, batch):
        return values(critic_params, batch.jert)[:, None, :-1]

    def critic_targets(target_critic, batch):
        jert = batch.jert
        returns = ac.macro_returns(jert.reward, jert.discount, values(target_critic, jert)[:, 1:], jert.mask,
                                   settings.n_step)
        return returns[:, None], jert.mask[:, None]

    def actor_loss(actor_params, batch, advantage, epsilon):
        jert = batch.jert
        logits = centralised.sequence_q(actor, actor_params, jert.obs)  # [E, H, J]
        log_probs = ac.epsilon_mixed_log_probs(logits, jnp.ones((joint,), bool), epsilon)
        taken = jnp.take_along_axis(log_probs, ravel_joint(jert.mac, counts)[..., None], -1)[..., 0]
        value = ac.policy_gradient_loss(taken, advantage[:, 0], jert.step, gamma, jert.mask)
        entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, -1)
        return value, {"policy_entropy": masked_mean(entropy, jert.mask),
                       "jert_entries": jert.mask.sum() / jert.mask.shape[0]}

    optimizers = {"actor": clipped_adam(config.lr, config.grad_clip),
                  "critic": clipped_adam(settings.critic_lr, config.grad_clip)}
    return Algorithm(
        name="mac_cac", init_params=init_params,
        init_carry=lambda n: jnp.zeros((settings.actor_rnn_size,), jnp.float32), act=act, loss=None,
        optimizer=per_part_optimizer(optimizers),
        update=ac.critic_then_actor_update(critic_targets, critic_values, actor_loss, optimizers, config),
        store=store_length, sample=on_policy_source(ac.prepare_on_policy(cert=False, jert=True)),
        greedy_act=greedy_act)


LEARNER = Learner("mac_cac", MacCACSettings, make_mac_cac, SCENARIO_VALUES,
                  {k: v for k, v in TINY_VALUES.items() if k != "critic_mid_size"},
                  "Mac-CAC: a joint actor over joint macro-actions and a joint history critic, on-policy")
