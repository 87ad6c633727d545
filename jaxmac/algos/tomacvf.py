"""ToMacVF: temporal agent networks + ATPG-parameterised QMIX, micro- and macro-TD (DECISIONS D2–D18).

Parameters are ``{"agent": …, "mixer": …}`` (the mixer holds ATPG). On a sampled batch of
episode slots (leaves ``[B, H, …]``, rows ``T = H + 1``):

* the agent GRUs run over every row (``slot_inputs``), giving ``q [B, T, n, A]`` valued at the
  progress ``tau`` of the action each agent executes from that row (0 for free agents);
* the mixer's hyper-networks (ATPG over the same rows) give ``MixWeights [B, T]``;
* **micro-TD** (D11): every valid step t, ``y = Σ_{k<m} γ^k r_{t+k} + γ^m Q̄_tot(t+m)``;
* **macro-TD** (D10): every complete Mac-SJERT segment, ``Q_tot`` at its start row with the
  joint action in force there, ``y = R_m + γ^τ Q̄_tot(end+1)``;
* bootstrap values use the conditional (To-Mac-IGM) target (D9): free agents take the online
  argmax at τ = 0 (double Q), busy agents keep their macro-action; the value comes from the
  target networks through the target mixer;
* ``L = mean δ_micro² + λ · mean δ_macro²`` (D8).

``buffer="mac_jert"`` (the w/o-Mac-SJERT ablation, D16) trains the same networks on the
Mac-JERT view instead: the GRU and ATPG run over the squeezed sequence of joint decision
rows with frozen macro-observations, one TD loss with the conditional target.

Acting (D17) is decentralised: each agent's GRU steps on its own observation stream and a
free agent picks ε-greedily among its available macro-actions (τ = 0); the mixer is never
used. In ``mac_jert`` mode the GRU steps only at joint decision points, as in training.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.acting import epsilon_greedy
from jaxmac.algos.base import Algorithm, default_optimizer
from jaxmac.buffer import views
from jaxmac.buffer.episode import EpisodeSlot
from jaxmac.config import TrainConfig
from jaxmac.encodings import EncodingConfig
from jaxmac.losses import masked_mean, td_mse
from jaxmac.networks import (
    AgentNetConfig,
    ATPGConfig,
    Mixer,
    MixerConfig,
    TemporalAgentNet,
    init_agent_params,
    init_mixer_params,
    initial_carry,
    jert_sequence,
    mix,
    slot_inputs,
    take_rows,
    timestep_inputs,
)
from jaxmac.targets import conditional_greedy, gather_q


def network_configs(config: TrainConfig, env: MacroEnv) -> tuple[AgentNetConfig, MixerConfig]:
    spec, config = env.spec, config.algo
    enc = EncodingConfig(dim_t=config.time_pe_dim, dim_tm=config.progress_pe_dim, use_t=config.use_time_pe)
    agent = AgentNetConfig.from_spec(spec, hidden=config.rnn_size, fc=config.fc_size, encoding=enc)
    kind = "vdn" if config.mixer == "vdn" else ("atpg_qmix" if config.mixer_params == "atpg" else "qmix")
    atpg = ATPGConfig.from_spec(spec, embed=config.attn_dim, delta=config.attn_delta,
                                attn_window=config.attn_window or None, encoding=enc)
    mixer = MixerConfig.from_spec(spec, kind=kind, embed=config.mixer_embed, atpg=atpg)
    return agent, mixer


def make_tomacvf(config: TrainConfig, env: MacroEnv) -> Algorithm:
    agent_cfg, mixer_cfg = network_configs(config, env)
    net = TemporalAgentNet(agent_cfg)
    mixer = Mixer(mixer_cfg)
    settings = config.algo
    obs_mode = settings.obs_mode  # "macro" whenever buffer="mac_jert" (the settings refuse anything else)
    squeezed = settings.buffer == "mac_jert"
    lam = settings.macro_loss_weight
    weight = settings.overestimate_weight

    def init_params(key):
        k_agent, k_mixer = jax.random.split(key)
        return {"agent": init_agent_params(agent_cfg, k_agent), "mixer": init_mixer_params(mixer_cfg, k_mixer)}

    # --- acting -------------------------------------------------------------------------
    def init_carry(num_agents: int):
        return initial_carry(agent_cfg)

    def act(params, carry, ts, key, epsilon):
        inputs = timestep_inputs(ts)
        if obs_mode == "macro":
            inputs = inputs.replace(obs=jnp.asarray(ts.obs_macro, jnp.float32))
        tau = jnp.zeros_like(ts.t_m)  # free agents value their choice at τ = 0
        q, new_carry = net.apply(params["agent"], inputs, carry, tau, method="step")
        if squeezed:  # the GRU only sees joint decision points
            new_carry = jnp.where(jnp.any(ts.mac_done), new_carry, carry)
        return new_carry, epsilon_greedy(key, q, ts.avail_actions, ts.mac_done, ts.mac, epsilon)

    # --- learning on Mac-SJERT ------------------------------------------------------------
    def forward(params, inputs, tau, state):
        b = inputs.t.shape[:-1]
        q, _, _ = net.apply(params["agent"], inputs, initial_carry(agent_cfg, b), tau)
        weights, _ = mixer.apply(params["mixer"], state, inputs)
        return q, weights

    def bootstrap(q_online, q_target, w_target, rows, avail, free, pinned):
        """Q̄_tot at bootstrap ``rows`` [B, ...] with the conditional double-Q joint action."""
        qo, qt, wt = (take_rows(x, rows, batch_ndim=1) for x in (q_online, q_target, w_target))
        joint = conditional_greedy(qo, avail, free, pinned)
        return mix(wt, gather_q(qt, joint))

    def sjert_loss(params, target_params, batch: EpisodeSlot):
        inputs, tau = slot_inputs(batch, obs_mode)
        state = batch.decode_state()
        q, w = forward(params, inputs, tau, state)
        q_tgt, w_tgt = forward(target_params, inputs, tau, state)
        q_detached = jax.lax.stop_gradient(q)
        h = batch.mac.shape[-2]

        micro = views.micro_view(batch, settings.n_step)
        first_rows = lambda tree, k: jax.tree_util.tree_map(lambda x: x[:, :k], tree)  # noqa: E731
        q_tot = mix(first_rows(w, h), gather_q(q[:, :h], micro.mac))
        boot = bootstrap(q_detached, q_tgt, w_tgt, micro.boot_row, micro.boot_avail, micro.boot_free,
                         micro.boot_mac)
        y_micro = jax.lax.stop_gradient(micro.ret + micro.boot_discount * boot)
        micro_loss = td_mse(q_tot - y_micro, micro.mask, weight)

        macro = views.macro_view(batch)  # leaves [B, n, K, ...]
        q_start = take_rows(q, macro.start, batch_ndim=1)  # [B, n, K, n, A]
        w_start = take_rows(w, macro.start, batch_ndim=1)
        q_tot_m = mix(w_start, gather_q(q_start, macro.start_mac))
        boot_m = bootstrap(q_detached, q_tgt, w_tgt, macro.boot_row, macro.boot_avail, macro.boot_free,
                           macro.boot_mac)
        y_macro = jax.lax.stop_gradient(macro.reward + macro.discount * boot_m)
        macro_loss = td_mse(q_tot_m - y_macro, macro.mask, weight)
        total = micro_loss + lam * macro_loss
        return total, {"micro_loss": micro_loss, "macro_loss": macro_loss,
                       "q_tot_mean": masked_mean(q_tot, micro.mask)}

    # --- learning on Mac-JERT (ablation) ---------------------------------------------------
    def jert_loss(params, target_params, batch: EpisodeSlot):
        jv, inputs, tau, state = jert_sequence(batch)
        q, w = forward(params, inputs, tau, state)
        q_tgt, w_tgt = forward(target_params, inputs, tau, state)
        kk = jv.mask.shape[-1]
        q_tot = mix(jax.tree_util.tree_map(lambda x: x[:, :kk], w), gather_q(q[:, :kk], jv.mac))
        nxt = jnp.broadcast_to(jnp.arange(1, kk + 1), jv.mask.shape)
        boot = bootstrap(jax.lax.stop_gradient(q), q_tgt, w_tgt, nxt, jv.avail_next, jv.free_next, jv.next_mac)
        y = jax.lax.stop_gradient(jv.reward + jv.discount * boot)
        loss = td_mse(q_tot - y, jv.mask, weight)
        return loss, {"micro_loss": loss, "macro_loss": jnp.zeros(()),
                      "q_tot_mean": masked_mean(q_tot, jv.mask)}

    def loss(params, target_params, batch: EpisodeSlot, key, progress):
        del key, progress
        return (jert_loss if squeezed else sjert_loss)(params, target_params, batch)

    return Algorithm(name="tomacvf", init_params=init_params, init_carry=init_carry, act=act, loss=loss,
                     optimizer=default_optimizer(config))
