"""An example learner, complete: independent recurrent Q per agent with plain double-Q on Mac-CERT windows.

It is what docs/learners.md walks through: a settings block that names the learner, per-scenario values, a factory
returning the trainer's ``Algorithm``, and the ``LEARNER`` the registry lists. To ship it, save it as
``jaxmac/algos/independent_drqn.py`` and add ``independent_drqn.LEARNER`` to ``LEARNERS`` in
``jaxmac/algos/registry.py``; ``tests/test_example_learner.py`` trains it for a few rounds.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from envs_jax.validation import check_positive
from jaxmac.algos.base import Algorithm, Learner, default_optimizer
from jaxmac.algos.families import decentralised
from jaxmac.buffer import windows
from jaxmac.config import LearnerSettings
from jaxmac.networks.drqn import AgentDRQN


@dataclasses.dataclass(frozen=True)
class IndependentDRQNSettings(LearnerSettings, algorithm="independent_drqn"):
    mlp_sizes: tuple[int, ...] = (32, 32)  # widths before and after the GRU
    rnn_size: int = 32
    trace_len: int = 0  # 0: whole episodes; L > 0: windows of L primitive steps

    def __post_init__(self):
        check_positive("independent_drqn", self, ("mlp_sizes", "rnn_size"))


def make_independent_drqn(config, env) -> Algorithm:
    settings, spec = config.algo, env.spec
    net = AgentDRQN(mlp=settings.mlp_sizes, hidden=settings.rnn_size, out=spec.max_actions)

    def act(params, carry, ts, key, epsilon):
        return decentralised.agents_step(net, params, carry, ts, key, epsilon, keep_history=True)

    def loss(params, target_params, batch, key, progress):
        value, metrics, _ = decentralised.hysteretic_double_q_loss(net, params, target_params, batch, 1.0)
        return value, metrics

    return Algorithm(
        name="independent_drqn", act=act, loss=loss, optimizer=default_optimizer(config),
        init_params=lambda key: decentralised.init_agent_drqn(net, key, spec.num_agents, spec.obs_dim),
        init_carry=lambda n: jnp.zeros((n, settings.rnn_size), jnp.float32),
        store=windows.store_views(jert=False, cert=True),
        sample=windows.window_source(config.batch_size, settings.trace_len))


LEARNER = Learner(
    "independent_drqn", IndependentDRQNSettings, make_independent_drqn,
    scenario_values={"boxpushing-6x6": dict(lr=1e-3, batch_size=32, target_update_episodes=64)},
    tiny_values=dict(mlp_sizes=(8, 8), rnn_size=8), summary="independent DRQNs, plain double-Q, on Mac-CERT")
