"""Mac-Dec-MADDRQN (MacDec-DDRQN, ICRA'20; docs/baselines.md §1.3): a centralised joint Q teaches decentralised agents.

Two networks trained together on the same windows:

* the Mac-Cen-DDRQN net (``jaxmac.algos.families.centralised``) on Mac-JERT with the conditional double-Q target;
* one DRQN per agent (``jaxmac.algos.families.decentralised``) on its Mac-CERT entries with the hysteretic target
  ``y_i = R_i + γ^{τ_i} Q_i⁻(h′_i, [argmax_{m′ | m_busy} Q_cen(h^J′, m′)]_i)``: the next action of agent i is its
  component of the centralised conditional argmax at the joint decision point that follows its termination
  (``views.cert_to_jert_index`` aligns agent i's entry with that joint entry).

Behaviour: the centralised conditional ε-greedy controller for the first ``cen_explore_episodes`` episodes
(the original's ``--cen_explore``), decentralised ε-greedy after; evaluation is decentralised and greedy.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from envs_jax.validation import check_positive
from jaxmac.algos.base import Algorithm, Learner, default_optimizer
from jaxmac.algos.families import centralised, decentralised
from jaxmac.algos.families.drqn_settings import (
    DEC_SCRIPT_VALUES,
    TINY_VALUES,
    HystereticDRQNSettings,
    window_schedule,
)
from jaxmac.buffer import views, windows
from jaxmac.config import TrainConfig
from jaxmac.networks.drqn import DRQN, AgentDRQN
from jaxmac.scenarios import BOXPUSHING, OVERCOOKED, WAREHOUSE


@dataclasses.dataclass(frozen=True)
class MacDecDDRQNSettings(HystereticDRQNSettings, algorithm="macdec_ddrqn"):
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
        check_positive("macdec_ddrqn", self, ("cen_rnn_size", "cen_mlp_sizes", "max_joint_actions"))
        if len(self.cen_mlp_sizes) != 2:
            raise ValueError(f"macdec_ddrqn: cen_mlp_sizes={self.cen_mlp_sizes!r} must have two widths")
        if self.cen_explore_episodes < 0:
            raise ValueError(f"macdec_ddrqn: cen_explore_episodes={self.cen_explore_episodes!r} must be >= 0")


# Mac-Dec-MADDRQN has no script in MacroMARL; the ICRA'20 README commands (docs/baselines.md §1.3): Box Pushing
# trace_len = train_freq = 15, batch 128, ε → 0.1, start_train 2 episodes, centralised exploration throughout,
# 15K episodes on BP-10 (we keep 40K like every other BP learner); elsewhere the MacDec-Q values with
# centralised exploration.
_DDRQN_BP = dict(window_schedule(128, 15, 4000), eps_end=0.1, start_train_episodes=2, eps_decay_start=2)
SCENARIO_VALUES: dict[str, dict[str, Any]] = {
    **{name: _DDRQN_BP for name in BOXPUSHING},
    **{name: dict(DEC_SCRIPT_VALUES[name], cen_mlp_sizes=(128, 64)) for name in OVERCOOKED},
    **{name: DEC_SCRIPT_VALUES[name] for name in WAREHOUSE},
}


def make_macdec_ddrqn(config: TrainConfig, env: MacroEnv) -> Algorithm:
    settings, spec = config.algo, env.spec
    counts = spec.num_actions
    cen = DRQN(mlp=settings.cen_mlp_sizes, hidden=settings.cen_rnn_size,
               out=centralised.check_joint_space(env, settings.max_joint_actions, "macdec_ddrqn"))
    dec = AgentDRQN(mlp=settings.mlp_sizes, hidden=settings.rnn_size, out=spec.max_actions)

    def init_params(key):
        k_cen, k_dec = jax.random.split(key)
        x = jnp.zeros((1, spec.num_agents * spec.obs_dim))
        return {"cen": cen.init(k_cen, x, jnp.zeros((1,), bool), jnp.zeros((settings.cen_rnn_size,))),
                "dec": decentralised.init_agent_drqn(dec, k_dec, spec.num_agents, spec.obs_dim)}

    def init_carry(n: int):
        return {"cen": jnp.zeros((settings.cen_rnn_size,), jnp.float32),
                "dec": jnp.zeros((n, settings.rnn_size), jnp.float32)}

    def act(params, carry, ts, key, epsilon):
        dec_carry, actions = decentralised.agents_step(dec, params["dec"], carry["dec"], ts, key, epsilon, True)
        return dict(carry, dec=dec_carry), actions

    def behaviour_act(params, carry, ts, key, epsilon, episodes):
        keep = settings.h_explore
        cen_carry, cen_actions = centralised.controller_step(cen, params["cen"], carry["cen"], ts, key, epsilon,
                                                             counts, keep)
        dec_carry, dec_actions = decentralised.agents_step(dec, params["dec"], carry["dec"], ts, key, epsilon, keep)
        actions = jnp.where(episodes < settings.cen_explore_episodes, cen_actions, dec_actions)
        return {"cen": cen_carry, "dec": dec_carry}, actions

    def loss(params, target_params, batch, key, progress):
        cen_loss, cen_metrics, best, jert = centralised.conditional_double_q_loss(
            cen, params["cen"], target_params["cen"], batch, counts)

        def next_actions(cert):  # agent i's component of the centralised argmax after its termination
            joint = views.cert_to_jert_index(cert.step, cert.mask, jert.step, jert.mask)  # [B, n, L]
            agent = jnp.arange(spec.num_agents)[None, :, None]
            return best[jnp.arange(best.shape[0])[:, None, None], joint, agent]

        beta = decentralised.hysteresis(settings, config, progress.episodes)
        dec_loss, dec_metrics, _ = decentralised.hysteretic_double_q_loss(
            dec, params["dec"], target_params["dec"], batch, beta, next_actions)
        return cen_loss + dec_loss, {**cen_metrics, **dec_metrics}

    return Algorithm(name="macdec_ddrqn", init_params=init_params, init_carry=init_carry, act=act, loss=loss,
                     optimizer=default_optimizer(config),
                     store=windows.store_views(jert=True, cert=True),
                     sample=windows.window_source(config.batch_size, settings.trace_len), behaviour_act=behaviour_act,
                     values=lambda p, c, ts: decentralised.agents_values(dec, p["dec"], c["dec"], ts, True)[0])


LEARNER = Learner("macdec_ddrqn", MacDecDDRQNSettings, make_macdec_ddrqn, SCENARIO_VALUES,
                  dict(TINY_VALUES, cen_mlp_sizes=(8, 8), cen_rnn_size=8),
                  "Mac-Dec-MADDRQN: decentralised DRQNs whose targets follow a centralised conditional joint Q")
