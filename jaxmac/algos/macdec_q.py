"""MacDec-Q (Dec-HDDRQN with Mac-CERTs, CoRL'19; docs/baselines.md §1.1): independent recurrent Q per agent.

Each agent's DRQN reads its own frozen macro-observations at its own decision points and is trained on its
Mac-CERT transitions (reward accumulated over its own macro-action, γ^τ bootstrap) with hysteretic double-Q
(``jaxmac.algos.families.decentralised``); acting is decentralised ε-greedy. The building block of Mac-Dec-MADDRQN.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.algos.base import Algorithm, Learner, default_optimizer
from jaxmac.algos.families import decentralised
from jaxmac.algos.families.drqn_settings import DEC_SCRIPT_VALUES, TINY_VALUES, HystereticDRQNSettings
from jaxmac.buffer import windows
from jaxmac.config import TrainConfig
from jaxmac.networks.drqn import AgentDRQN


@dataclasses.dataclass(frozen=True)
class MacDecQSettings(HystereticDRQNSettings, algorithm="macdec_q"):
    """MacDec-Q (Dec-HDDRQN on Mac-CERT, docs/baselines.md §1.1): per-agent DRQNs, hysteretic double-Q."""

    def __post_init__(self):
        self._validate("macdec_q")


# mac_dec_q.sh's values (docs/hyperparameters.md)
SCENARIO_VALUES = DEC_SCRIPT_VALUES


def make_macdec_q(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    net = AgentDRQN(mlp=settings.mlp_sizes, hidden=settings.rnn_size, out=spec.max_actions)

    def act(params, carry, ts, key, epsilon):
        return decentralised.agents_step(net, params, carry, ts, key, epsilon, keep_history=True)

    def behaviour_act(params, carry, ts, key, epsilon, episodes):
        return decentralised.agents_step(net, params, carry, ts, key, epsilon, settings.h_explore)

    def loss(params, target_params, batch, key, progress):
        beta = decentralised.hysteresis(settings, config, progress.episodes)
        value, metrics, _ = decentralised.hysteretic_double_q_loss(net, params, target_params, batch, beta)
        return value, metrics

    return Algorithm(
        name="macdec_q",
        init_params=lambda key: decentralised.init_agent_drqn(net, key, spec.num_agents, spec.obs_dim),
        init_carry=lambda n: jnp.zeros((n, settings.rnn_size), jnp.float32), act=act, loss=loss,
        optimizer=default_optimizer(config), store=windows.store_views(jert=False, cert=True),
        sample=windows.window_source(config.batch_size, settings.trace_len),
        behaviour_act=behaviour_act, values=lambda p, c, ts: decentralised.agents_values(net, p, c, ts, True)[0])


LEARNER = Learner("macdec_q", MacDecQSettings, make_macdec_q, SCENARIO_VALUES, TINY_VALUES,
                  "MacDec-Q: independent recurrent Q per agent on Mac-CERT, hysteretic double-Q")
