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

import chex
import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from envs_jax.policies import uniform_random_actions
from jaxmac import views
from jaxmac.config import TrainConfig
from jaxmac.encodings import EncodingConfig
from jaxmac.episode import EpisodeSlot
from jaxmac.networks import (
    AgentNetConfig,
    ATPGConfig,
    Mixer,
    MixerConfig,
    NetInputs,
    TemporalAgentNet,
    conditional_greedy,
    gather_q,
    init_agent_params,
    init_mixer_params,
    initial_carry,
    jert_inputs,
    masked_argmax,
    mix,
    slot_inputs,
    take_rows,
    timestep_inputs,
)
from jaxmac.trainer import Algorithm


def network_configs(config: TrainConfig, env: MacroEnv) -> tuple[AgentNetConfig, MixerConfig]:
    spec = env.spec
    enc = EncodingConfig(dim_t=config.time_pe_dim, dim_tm=config.progress_pe_dim, use_t=config.use_time_pe)
    agent = AgentNetConfig.from_spec(spec, hidden=config.rnn_size, fc=config.fc_size, encoding=enc)
    kind = "vdn" if config.mixer == "vdn" else ("atpg_qmix" if config.mixer_params == "atpg" else "qmix")
    atpg = ATPGConfig.from_spec(spec, embed=config.attn_dim, delta=config.attn_delta,
                                attn_window=config.attn_window or None, encoding=enc)
    mixer = MixerConfig.from_spec(spec, kind=kind, embed=config.mixer_embed, atpg=atpg)
    return agent, mixer


def _mse(delta: chex.Array, mask: chex.Array, overestimate_weight: float = 1.0) -> chex.Array:
    """Mean over ``mask`` of ``w · delta²`` with ``delta = Q_tot − y``; ``w = overestimate_weight`` where
    ``delta > 0`` and 1 elsewhere (1 everywhere by default: plain MSE)."""
    mask = mask.astype(jnp.float32)
    if overestimate_weight != 1.0:
        mask = mask * jnp.where(delta > 0, overestimate_weight, 1.0)
    return jnp.sum(mask * delta**2) / jnp.maximum((mask > 0).sum(), 1.0)


def jert_sequence(batch: EpisodeSlot):
    """The squeezed Mac-JERT sequence (D16) plus its bootstrap row, for a batch of slots.

    Entries ``0..c-1`` are the ``c`` real joint decision rows (``networks.jert_inputs``); entry ``c``
    is the row after the last kept step (its observation, state, time and progress), from which the
    last transition bootstraps when the episode was truncated; later entries are padding. The
    sequence has ``K + 1`` entries so that ``c = K`` fits.

    Args:
      batch: ``EpisodeSlot`` with leaves ``[B, H, ...]``.
    Returns:
      jv: ``views.jert_view(batch)`` (leaves ``[B, K, ...]``).
      inputs: ``NetInputs`` with ``T = K + 1``.
      tau: i32[B, K + 1, n] progress at each entry (0 for free agents).
      state: f32[B, K + 1, S] global state at each entry.
    """
    jv = views.jert_view(batch)
    inputs, tau = jert_inputs(batch, jv)
    count = jv.mask.sum(-1)  # [B]
    last = jnp.maximum(count - 1, 0)
    is_boot = jnp.arange(jv.mask.shape[-1] + 1) == count[:, None]  # [B, K + 1]

    def at_last(x):  # x [B, K, ...] -> [B, ...]
        return jnp.take_along_axis(x, last.reshape((-1,) + (1,) * (x.ndim - 1)), 1)[:, 0]

    def with_boot_row(x, boot):  # x [B, K, ...], boot [B, ...] -> [B, K + 1, ...]
        x = jnp.concatenate([x, jnp.zeros_like(x[:, :1])], axis=1)
        where = is_boot.reshape(is_boot.shape + (1,) * (x.ndim - 2))
        return jnp.where(where, boot[:, None].astype(x.dtype), x)

    last_step = at_last(jv.step)
    t_m_at_last_step = jnp.take_along_axis(batch.t_m, last_step[:, None, None], axis=1)[:, 0]  # [B, n]
    inputs = NetInputs(
        obs=with_boot_row(inputs.obs, at_last(jv.obs_next)),
        t=with_boot_row(inputs.t, last_step + 1),
        prev_t=with_boot_row(inputs.prev_t, last_step),
        prev_mac=with_boot_row(inputs.prev_mac, at_last(jv.mac)),
        prev_t_m=with_boot_row(inputs.prev_t_m, t_m_at_last_step),
        reset=with_boot_row(inputs.reset, count == 0),
    )
    tau = with_boot_row(tau, at_last(jv.next_t_m))
    state = with_boot_row(jv.state, at_last(jv.state_next))
    return jv, inputs, tau, state


def make_tomacvf(config: TrainConfig, env: MacroEnv) -> Algorithm:
    agent_cfg, mixer_cfg = network_configs(config, env)
    net = TemporalAgentNet(agent_cfg)
    mixer = Mixer(mixer_cfg)
    obs_mode = config.obs_mode if config.buffer == "mac_sjert" else "macro"
    squeezed = config.buffer == "mac_jert"
    lam = config.macro_loss_weight

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
        k_explore, k_random = jax.random.split(key)
        explore = jax.random.uniform(k_explore, ts.mac_done.shape) < epsilon
        chosen = jnp.where(explore, uniform_random_actions(k_random, ts.avail_actions),
                           masked_argmax(q, ts.avail_actions))
        return new_carry, jnp.where(ts.mac_done, chosen, ts.mac)

    # --- learning on Mac-SJERT ------------------------------------------------------------
    def forward(params, inputs: NetInputs, tau, state):
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

        micro = views.micro_view(batch, config.n_step)
        first_rows = lambda tree, k: jax.tree_util.tree_map(lambda x: x[:, :k], tree)  # noqa: E731
        q_tot = mix(first_rows(w, h), gather_q(q[:, :h], micro.mac))
        boot = bootstrap(q_detached, q_tgt, w_tgt, micro.boot_row, micro.boot_avail, micro.boot_free,
                         micro.boot_mac)
        y_micro = jax.lax.stop_gradient(micro.ret + micro.boot_discount * boot)
        micro_loss = _mse(q_tot - y_micro, micro.mask, config.overestimate_weight)

        macro = views.macro_view(batch)  # leaves [B, n, K, ...]
        q_start = take_rows(q, macro.start, batch_ndim=1)  # [B, n, K, n, A]
        w_start = take_rows(w, macro.start, batch_ndim=1)
        q_tot_m = mix(w_start, gather_q(q_start, macro.start_mac))
        boot_m = bootstrap(q_detached, q_tgt, w_tgt, macro.boot_row, macro.boot_avail, macro.boot_free,
                           macro.boot_mac)
        y_macro = jax.lax.stop_gradient(macro.reward + macro.discount * boot_m)
        macro_loss = _mse(q_tot_m - y_macro, macro.mask, config.overestimate_weight)
        total = micro_loss + lam * macro_loss
        return total, {"micro_loss": micro_loss, "macro_loss": macro_loss,
                       "q_tot_mean": jnp.sum(q_tot * micro.mask) / jnp.maximum(micro.mask.sum(), 1)}

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
        loss = _mse(q_tot - y, jv.mask, config.overestimate_weight)
        return loss, {"micro_loss": loss, "macro_loss": jnp.zeros(()),
                      "q_tot_mean": jnp.sum(q_tot * jv.mask) / jnp.maximum(jv.mask.sum(), 1)}

    def loss(params, target_params, batch: EpisodeSlot, key):
        del key
        return (jert_loss if squeezed else sjert_loss)(params, target_params, batch)

    return Algorithm(name="tomacvf", init_params=init_params, init_carry=init_carry, act=act, loss=loss)
