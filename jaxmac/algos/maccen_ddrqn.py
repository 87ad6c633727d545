"""Mac-Cen-DDRQN (MacCen-Q of MacroMARL, docs/baselines.md §1.2): one centralised recurrent Q over joint macro-actions.

The net reads the concatenation of every agent's frozen macro-observation and outputs one value per joint
macro-action. It is trained on Mac-JERT — the steps where any macro-action ended, with the joint reward
accumulated since the previous such step — in windows of ``trace_len`` primitive steps (Box Pushing) or whole
episodes, the GRU starting from zero at each window's first kept entry. Target (double Q, conditional): at the
next joint decision point the online net's argmax over the joint actions whose busy agents keep their running
macro-action, valued by the target net::

    y = R^J + γ^{τ^J} Q⁻(h^J′, argmax_{m′ | m_busy} Q(h^J′, m′)) · (1 − terminal),   L = mean (Q(h^J, m^J) − y)²

Acting is centralised (``jaxmac.algos.families.centralised.controller_step``); without ``h_explore`` the behaviour policy
values each decision from a zero state (as the original runner), greedy evaluation keeps the history.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from envs_jax.core import MacroEnv
from envs_jax.validation import check_positive
from jaxmac.algos.base import Algorithm, Learner, default_optimizer
from jaxmac.algos.families import centralised
from jaxmac.algos.families.drqn_settings import CEN_SCRIPT_VALUES, TINY_VALUES, DRQNSettings
from jaxmac.buffer import windows
from jaxmac.config import TrainConfig
from jaxmac.networks.drqn import DRQN


@dataclasses.dataclass(frozen=True)
class MacCenDDRQNSettings(DRQNSettings, algorithm="maccen_ddrqn"):
    """Mac-Cen-DDRQN (MacCen-Q, docs/baselines.md §1.2): one centralised recurrent Q over the joint action space (plain
    MSE: the scripts' hysteresis is 1)."""

    rnn_size: int = 64
    max_joint_actions: int = 4096  # refuse envs whose joint macro-action space is larger

    def __post_init__(self):
        self._validate("maccen_ddrqn")
        check_positive("maccen_ddrqn", self, ("max_joint_actions",))


# mac_cen_q.sh's values (docs/hyperparameters.md)
SCENARIO_VALUES = CEN_SCRIPT_VALUES


def make_maccen_ddrqn(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    counts = spec.num_actions
    net = DRQN(mlp=settings.mlp_sizes, hidden=settings.rnn_size,
               out=centralised.check_joint_space(env, settings.max_joint_actions, "maccen_ddrqn"))

    def init_params(key):
        x = jnp.zeros((1, spec.num_agents * spec.obs_dim))
        return net.init(key, x, jnp.zeros((1,), bool), jnp.zeros((settings.rnn_size,)))

    def act(params, carry, ts, key, epsilon):
        return centralised.controller_step(net, params, carry, ts, key, epsilon, counts, keep_history=True)

    def behaviour_act(params, carry, ts, key, epsilon, episodes):
        return centralised.controller_step(net, params, carry, ts, key, epsilon, counts, settings.h_explore)

    def loss(params, target_params, batch, key, progress):
        value, metrics, _, _ = centralised.conditional_double_q_loss(net, params, target_params, batch, counts)
        return value, metrics

    return Algorithm(name="maccen_ddrqn", init_params=init_params,
                     init_carry=lambda n: jnp.zeros((settings.rnn_size,), jnp.float32), act=act, loss=loss,
                     optimizer=default_optimizer(config), store=windows.store_views(jert=True, cert=False),
                     sample=windows.window_source(config.batch_size, settings.trace_len),
                     behaviour_act=behaviour_act)


LEARNER = Learner("maccen_ddrqn", MacCenDDRQNSettings, make_maccen_ddrqn, SCENARIO_VALUES, TINY_VALUES,
                  "Mac-Cen-DDRQN: centralised recurrent joint Q on Mac-JERT, conditional double-Q")
