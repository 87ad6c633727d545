"""ToMacVF: temporal agent networks + ATPG-parameterised mixer, micro- and macro-TD (DECISIONS D2–D19).

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
* ``L = mean δ_micro² + λ · mean δ_macro²`` (D8), one gradient step; with ``sequential_updates`` the paper's
  literal pseudocode instead: a step on the micro-TD loss, then an additional step on ``λ · macro-TD`` (recomputed
  with the updated parameters) when the batch holds a completed macro-action. Both steps share one Adam state.

Mixers (D19, ``mixer``): QMIX (default), VDN, QPLEX, QTRAN, conditioned on ATPG's encodings with the state (or on the
state alone with ``mixer_params='state'``; see ``networks.mixers``). Every Q_tot is evaluated on the *admissible*
actions of its row (``targets.admissible_actions``: a busy agent's only admissible action is its running one):

* QMIX/VDN: the mixer's weights do not depend on the choices at the row (D4) and are monotone in every Q_i, so the
  conditional target's per-agent argmax is the exact conditional argmax of Q_tot.
* QPLEX: ``V_i`` is the max over the admissible actions, so busy agents' advantages are zero and
  ``Q_tot ≤ Σ_i V_i′`` with equality exactly when every free agent takes its argmax: again the per-agent conditional
  argmax is the exact conditional argmax of Q_tot, although λ(s, a) depends on the joint action.
* QTRAN: the TD losses train the joint ``Q_jt``; the target takes the conditional argmax of the factorised
  ``Q′ = Σ_i Q_i`` (per-agent, exact for a sum) and values it with the target ``Q_jt`` (QTRAN's rule, not an argmax
  of Q_jt). QTRAN's constraint losses tie ``Q′`` to ``Q_jt`` on every micro row (and every Mac-JERT entry):
  ``w_opt · mean opt² + w_nopt · mean nopt²`` (``networks.mixers.qtran_penalties``; ā is the conditional greedy
  joint action of the row, a the executed one). They are part of the micro step with ``sequential_updates``.

``buffer="mac_jert"`` (the w/o-Mac-SJERT ablation, D16) trains the same networks on the
Mac-JERT view instead: the GRU and ATPG run over the squeezed sequence of joint decision
rows with frozen macro-observations, one TD loss with the conditional target.

The update runs on the sampled episodes cut to the shortest of ``length_buckets`` static lengths (halving from H)
that holds the longest of them (``EpisodeSlot.prefix``, ``buckets.length_bucketed``): the networks are causal and
every target row lies within an episode's length, so the losses are those of the full-length slots, at the cost of
the real lengths (1 = always the full horizon, the reference path). With ``packing=True`` (Mac-SJERT) the networks
instead run on the sampled episodes packed back to back (``buffer.packing``: GRU carries reset and ATPG's attention
restarts at every episode's first row) into the fewest of ``packed_row_sizes(B, length_buckets)`` rows, and their
outputs are unpacked to the slots before the (unchanged) losses: the same values at the cost of the *total* length.

Acting (D17) is decentralised: each agent's GRU steps on its own observation stream and a
free agent picks ε-greedily among its available macro-actions (τ = 0); the mixer is never
used. In ``mac_jert`` mode the GRU steps only at joint decision points, as in training.

Everything is a module-level pure function of a ``ToMacVFModel`` (the two networks and the switches, built once by
``build_model``) and arrays: ``forward``, ``q_tot``, ``bootstrap``, ``micro_td``, ``macro_td``, ``sjert_terms``,
``jert_terms``, ``greedy_q_tot``, ``step_values``, ``act``. ``make_tomacvf`` only wires them into the trainer's
``Algorithm`` (with packing and length buckets as wrappers), and diagnostics call the same functions.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.algos.acting import epsilon_greedy
from jaxmac.algos.base import Algorithm, default_optimizer, gradient_update
from jaxmac.algos.targets import admissible_actions, conditional_greedy
from jaxmac.algos.tomacvf.settings import ToMacVFSettings
from jaxmac.buckets import length_bucketed, packed_row_sizes, run_bucketed
from jaxmac.buffer import packing, views
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
    slot_inputs,
    take_rows,
    timestep_inputs,
)
from jaxmac.networks.mixers import mix_actions, qtran_penalties
from jaxmac.schedules import linear_schedule


def network_configs(config: TrainConfig, env: MacroEnv) -> tuple[AgentNetConfig, MixerConfig]:
    spec, config = env.spec, config.algo
    enc = EncodingConfig(dim_t=config.time_pe_dim, dim_tm=config.progress_pe_dim, use_t=config.use_time_pe)
    agent = AgentNetConfig.from_spec(spec, hidden=config.rnn_size, fc=config.fc_size, encoding=enc)
    kind = config.mixer if config.mixer == "vdn" or config.mixer_params == "state" else f"atpg_{config.mixer}"
    atpg = ATPGConfig.from_spec(spec, embed=config.attn_dim, delta=config.attn_delta,
                                attn_window=config.attn_window or None, encoding=enc)
    mixer = MixerConfig.from_spec(spec, kind=kind, embed=config.mixer_embed, hyper_hidden=config.hyper_hidden,
                                  atpg=atpg)
    return agent, mixer


@dataclasses.dataclass(frozen=True)
class ToMacVFModel:
    """The static part of a ToMacVF learner: its agent network, its mixer (with ATPG) and its settings."""

    agent_cfg: AgentNetConfig
    mixer_cfg: MixerConfig
    settings: ToMacVFSettings

    @property
    def net(self) -> TemporalAgentNet:
        return TemporalAgentNet(self.agent_cfg)

    @property
    def mixer(self) -> Mixer:
        return Mixer(self.mixer_cfg)

    @property
    def obs_mode(self) -> str:  # "macro" whenever buffer="mac_jert" (the settings refuse anything else)
        return self.settings.obs_mode

    @property
    def squeezed(self) -> bool:  # trains on the Mac-JERT view (the w/o-Mac-SJERT ablation)
        return self.settings.buffer == "mac_jert"

    @property
    def qtran(self) -> bool:
        return self.mixer_cfg.family == "qtran"


def build_model(config: TrainConfig, env: MacroEnv) -> ToMacVFModel:
    return ToMacVFModel(*network_configs(config, env), config.algo)


def init_params(model: ToMacVFModel, key) -> dict:
    """``{"agent": …, "mixer": …}`` (the mixer holds ATPG)."""
    k_agent, k_mixer = jax.random.split(key)
    return {"agent": init_agent_params(model.agent_cfg, k_agent), "mixer": init_mixer_params(model.mixer_cfg, k_mixer)}


def free_at_rows(mac_done: jax.Array) -> jax.Array:
    """bool[..., H, n]: the agent chooses at row t (t = 0, or its macro-action ended at step t − 1)."""
    first = jnp.ones_like(mac_done[..., :1, :])
    return jnp.concatenate([first, mac_done[..., :-1, :]], axis=-2)


# --- acting ------------------------------------------------------------------------------------------------------

def step_values(model: ToMacVFModel, params, carry, ts):
    """(Q_i f32[n, A] of every macro-action at this timestep, valued at τ = 0, and the stepped GRU carry)."""
    inputs = timestep_inputs(ts)
    if model.obs_mode == "macro":
        inputs = inputs.replace(obs=jnp.asarray(ts.obs_macro, jnp.float32))
    tau = jnp.zeros_like(ts.t_m)  # free agents value their choice at τ = 0
    return model.net.apply(params["agent"], inputs, carry, tau, method="step")


def act(model: ToMacVFModel, params, carry, ts, key, epsilon):
    """Decentralised ε-greedy acting (D17): (new carry, actions i32[n]); busy agents re-send their action."""
    q, new_carry = step_values(model, params, carry, ts)
    if model.squeezed:  # the GRU only sees joint decision points
        new_carry = jnp.where(jnp.any(ts.mac_done), new_carry, carry)
    return new_carry, epsilon_greedy(key, q, ts.avail_actions, ts.mac_done, ts.mac, epsilon)


# --- the forward pass and the values the losses read -------------------------------------------------------------

def forward(model: ToMacVFModel, params, inputs, tau, state):
    """The agent GRUs and the mixer's weights over every row: (q f32[B, T, n, A], MixWeights [B, T])."""
    b = inputs.t.shape[:-1]
    q, _, _ = model.net.apply(params["agent"], inputs, initial_carry(model.agent_cfg, b), tau)
    weights, _ = model.mixer.apply(params["mixer"], state, inputs)
    return q, weights


def packed_forward(model: ToMacVFModel, params, inputs, tau, state, plan, rows):
    """``forward`` on the episodes packed into ``rows`` rows (``buffer.packing``), unpacked to their slots."""
    layout = packing.packed_layout(plan, rows, inputs.t.shape[-1])
    pk = lambda x: packing.pack(x, layout)  # noqa: E731
    packed = jax.tree_util.tree_map(pk, inputs).replace(reset=layout.reset)
    q, weights = forward(model, params, packed, pk(tau), pk(state))
    return packing.unpack(q, plan), weights.map_rows(lambda x: packing.unpack(x, plan))


def q_tot(weights, q, actions, avail, free):
    """Q_tot of the executed joint ``actions`` at rows whose choosing agents are ``free``."""
    return mix_actions(weights, q, actions, admissible_actions(avail, free, actions))


def conditional_target(q_online, q_target, w_target, avail, free, pinned):
    """The bootstrap value of a row under To-Mac-IGM (D9), double-Q: the joint action is chosen with the online
    values — free agents take their available argmax, busy agents keep ``pinned`` — and valued by the target mixer
    ``w_target`` on the target values over the same admissible sets. For QMIX, VDN and QPLEX that joint action is the
    argmax of the online Q_tot over the admissible joint actions (see the module docstring); for QTRAN it is the
    argmax of ``Σ_i Q_i`` and the value is the target ``Q_jt`` there.

    Args: ``q_online``, ``q_target`` f32[..., n, A]; ``w_target`` MixWeights [...]; ``avail`` bool[..., n, A];
    ``free`` bool[..., n]; ``pinned`` i32[..., n]. Returns (value f32[...], joint action i32[..., n]).
    """
    joint = conditional_greedy(q_online, avail, free, pinned)
    return mix_actions(w_target, q_target, joint, admissible_actions(avail, free, pinned)), joint


def bootstrap(q_online, q_target, w_target, rows, avail, free, pinned):
    """Q̄_tot at bootstrap ``rows`` [B, ...] with the conditional double-Q joint action."""
    qo, qt, wt = (take_rows(x, rows, batch_ndim=1) for x in (q_online, q_target, w_target))
    return conditional_target(qo, qt, wt, avail, free, pinned)[0]


def greedy_q_tot(model: ToMacVFModel, params, batch: EpisodeSlot) -> jax.Array:
    """f32[B, H + 1]: Q_tot of the conditional greedy joint action (D9: busy agents keep their macro-action) at every
    row of the slots, row H being the time-limit bootstrap row of a truncated episode (a target, never a prediction)."""
    inputs, tau = slot_inputs(batch, model.obs_mode)
    q, weights = forward(model, params, inputs, tau, batch.decode_state())
    free = jnp.concatenate([free_at_rows(batch.mac_done), batch.mac_done[:, -1:]], 1)  # rows 0 … H
    pinned = jnp.concatenate([batch.mac, batch.mac[:, -1:]], 1)
    greedy = conditional_greedy(q, batch.avail, free, pinned)
    return mix_actions(weights, q, greedy, admissible_actions(batch.avail, free, pinned))


# --- the losses ----------------------------------------------------------------------------------------------------

def overestimate_weight(settings: ToMacVFSettings, progress):
    """The TD weight where Q_tot is above its target: a python float when constant (bit-identical to a plain
    constant), else the scheduled f32[]."""
    if settings.overestimate_anneal_episodes == 0:
        return settings.overestimate_weight
    return linear_schedule(progress.episodes, settings.overestimate_anneal_start,
                           settings.overestimate_anneal_episodes, settings.overestimate_weight,
                           settings.overestimate_weight_end)


def qtran_terms(model: ToMacVFModel, weights, q, actions, avail, free, mask) -> dict:
    """QTRAN's constraint losses on the rows of ``mask`` (none for the other mixers)."""
    if not model.qtran:
        return {}
    greedy = conditional_greedy(jax.lax.stop_gradient(q), avail, free, actions)
    opt, nopt = qtran_penalties(weights, q, actions, greedy)
    return {"qtran_opt_loss": masked_mean(opt**2, mask), "qtran_nopt_loss": masked_mean(nopt**2, mask)}


def micro_td(micro: views.MicroView, q_tot_now, q_detached, q_tgt, w_tgt, weight):
    """Micro-TD (D11) on every valid step: ``Q_tot(t)`` against ``Σ_{k<m} γ^k r_{t+k} + γ^m Q̄_tot(t+m)``."""
    boot = bootstrap(q_detached, q_tgt, w_tgt, micro.boot_row, micro.boot_avail, micro.boot_free, micro.boot_mac)
    y = jax.lax.stop_gradient(micro.ret + micro.boot_discount * boot)
    return td_mse(q_tot_now - y, micro.mask, weight)


def macro_td(macro: views.MacroView, q, w, avail, free, q_detached, q_tgt, w_tgt, weight):
    """Macro-TD (D10) on every complete Mac-SJERT segment: ``Q_tot`` at its start row with the joint action in force
    there against ``R_m + γ^τ Q̄_tot(end + 1)``. ``q``, ``w``, ``avail``, ``free`` are the slots' rows."""
    at_start = lambda x: take_rows(x, macro.start, batch_ndim=1)  # noqa: E731  [B, n, K, ...]
    q_tot_macro = q_tot(at_start(w), at_start(q), macro.start_mac, at_start(avail), at_start(free))
    boot = bootstrap(q_detached, q_tgt, w_tgt, macro.boot_row, macro.boot_avail, macro.boot_free, macro.boot_mac)
    y = jax.lax.stop_gradient(macro.reward + macro.discount * boot)
    return td_mse(q_tot_macro - y, macro.mask, weight)


def _with_time_limit(settings: ToMacVFSettings, batch: EpisodeSlot) -> EpisodeSlot:
    return batch if settings.bootstrap_time_limit else views.time_limit_as_termination(batch)


def sjert_terms(model: ToMacVFModel, params, target_params, batch: EpisodeSlot, progress, packed=None):
    """Loss terms on Mac-SJERT {micro_loss, macro_loss, QTRAN's (``qtran`` only)}, unweighted, and metrics;
    ``packed`` = (plan, rows) runs the networks on the episodes packed into that many rows (same values)."""
    settings = model.settings
    weight = overestimate_weight(settings, progress)
    batch = _with_time_limit(settings, batch)
    inputs, tau = slot_inputs(batch, model.obs_mode)
    state = batch.decode_state()
    if packed is None:
        q, w = forward(model, params, inputs, tau, state)
        q_tgt, w_tgt = forward(model, target_params, inputs, tau, state)
    else:
        q, w = packed_forward(model, params, inputs, tau, state, *packed)
        q_tgt, w_tgt = packed_forward(model, target_params, inputs, tau, state, *packed)
    q_detached = jax.lax.stop_gradient(q)
    h = batch.mac.shape[-2]
    free, avail = free_at_rows(batch.mac_done), batch.avail[:, :h]

    micro = views.micro_view(batch, settings.n_step)
    w_now, q_now = w.map_rows(lambda x: x[:, :h]), q[:, :h]
    q_tot_micro = q_tot(w_now, q_now, micro.mac, avail, free)
    terms = {"micro_loss": micro_td(micro, q_tot_micro, q_detached, q_tgt, w_tgt, weight)}
    terms |= qtran_terms(model, w_now, q_now, micro.mac, avail, free, micro.mask)
    terms["macro_loss"] = macro_td(views.macro_view(batch), q, w, avail, free, q_detached, q_tgt, w_tgt, weight)
    return terms, {"q_tot_mean": masked_mean(q_tot_micro, micro.mask)} | weight_metric(weight)


def jert_terms(model: ToMacVFModel, params, target_params, batch: EpisodeSlot, progress):
    """The one TD loss on the Mac-JERT view (the w/o-Mac-SJERT ablation, D16) with the conditional target."""
    weight = overestimate_weight(model.settings, progress)
    jv, inputs, tau, state = jert_sequence(_with_time_limit(model.settings, batch))
    q, w = forward(model, params, inputs, tau, state)
    q_tgt, w_tgt = forward(model, target_params, inputs, tau, state)
    kk = jv.mask.shape[-1]
    w_now, q_now = w.map_rows(lambda x: x[:, :kk]), q[:, :kk]
    free = free_at_rows(jv.free_next)  # the agents choosing at an entry ended their action at the one before
    q_tot_now = q_tot(w_now, q_now, jv.mac, jv.avail, free)
    nxt = jnp.broadcast_to(jnp.arange(1, kk + 1), jv.mask.shape)
    boot = bootstrap(jax.lax.stop_gradient(q), q_tgt, w_tgt, nxt, jv.avail_next, jv.free_next, jv.next_mac)
    y = jax.lax.stop_gradient(jv.reward + jv.discount * boot)
    terms = {"micro_loss": td_mse(q_tot_now - y, jv.mask, weight), "macro_loss": jnp.zeros(())}
    terms |= qtran_terms(model, w_now, q_now, jv.mac, jv.avail, free, jv.mask)
    return terms, {"q_tot_mean": masked_mean(q_tot_now, jv.mask)} | weight_metric(weight)


def term_weights(settings: ToMacVFSettings) -> dict[str, float]:
    return {"micro_loss": 1.0, "macro_loss": settings.macro_loss_weight, "qtran_opt_loss": settings.qtran_opt_weight,
            "qtran_nopt_loss": settings.qtran_nopt_weight}


# --- the wiring ----------------------------------------------------------------------------------------------------

def make_tomacvf(config: TrainConfig, env: MacroEnv) -> Algorithm:
    model = build_model(config, env)
    settings = config.algo
    terms_of = functools.partial(jert_terms if model.squeezed else sjert_terms, model)
    weights = term_weights(settings)

    def loss_of(terms_fn):
        def loss(params, target_params, batch: EpisodeSlot, key, progress):
            del key
            terms, metrics = terms_fn(params, target_params, batch, progress)
            return weighted_sum(terms, weights), metrics | terms

        return loss

    optimizer = default_optimizer(config)

    def make_update(terms_fn):
        if settings.sequential_updates:
            return sequential_update(terms_fn, weights, optimizer)
        return gradient_update(loss_of(terms_fn), optimizer)

    if settings.packing:
        # the networks run on the sampled episodes packed into the fewest of packed_row_sizes(B, length_buckets) rows
        def update(params, target_params, opt_state, batch, key, progress):
            plan = packing.pack_plan(batch.length, batch.config.horizon + 1)

            def with_rows(rows):
                # as many rows as episodes: nothing to gain from packing, the networks run on the slots themselves
                packed = None if rows == batch.length.shape[0] else (plan, rows)
                terms_fn = lambda p, t, b, pr: sjert_terms(model, p, t, b, pr, packed=packed)  # noqa: E731
                return make_update(terms_fn)(params, target_params, opt_state, batch, key, progress)

            sizes = packed_row_sizes(batch.length.shape[0], config.length_buckets)
            return run_bucketed(with_rows, sizes, plan.rows_used)
    else:
        # on the batch's shortest prefix that holds its longest episode (the full horizon when length_buckets = 1)
        update = length_bucketed(make_update(terms_of), config.length_buckets, lambda batch: batch.config.horizon,
                                 lambda batch: jnp.max(batch.length))
    return Algorithm(name="tomacvf", init_params=functools.partial(init_params, model),
                     init_carry=lambda num_agents: initial_carry(model.agent_cfg),
                     act=functools.partial(act, model), loss=loss_of(terms_of), optimizer=optimizer, update=update,
                     values=lambda p, c, ts: step_values(model, p, c, ts)[0])


def weight_metric(weight) -> dict:
    """``{"overestimate_weight": w}`` when the weight is scheduled (a metric worth a column), else nothing."""
    return {} if isinstance(weight, (int, float)) else {"overestimate_weight": weight}


def weighted_sum(terms: dict, weights: dict) -> jax.Array:
    """Σ_k weights[k] · terms[k] (a weight of 1 is not multiplied, so the plain micro loss is bit-exact)."""
    return sum(value if weights[name] == 1.0 else weights[name] * value for name, value in terms.items())


def sequential_update(terms_of, term_weights, optimizer):
    """D8's literal two-step update: a gradient step on every term but the macro-TD loss, then one on
    ``λ · macro-TD`` recomputed with the updated parameters — skipped when the batch has no completed
    macro-action (an Adam step on a zero gradient would still move the parameters). Metrics: the first step's terms
    and ``grad_norm``, the second's ``macro_loss`` (unweighted) and ``grad_norm_macro``; ``loss`` is the first step's
    loss plus λ · macro_loss."""
    lam = term_weights["macro_loss"]

    def micro_part(params, target_params, batch, key, progress):
        terms, metrics = terms_of(params, target_params, batch, progress)
        terms.pop("macro_loss")
        return weighted_sum(terms, term_weights), metrics | terms

    def macro_part(params, target_params, batch, key, progress):
        terms, _ = terms_of(params, target_params, batch, progress)
        return lam * terms["macro_loss"], {"macro_loss": terms["macro_loss"]}

    micro_step = gradient_update(micro_part, optimizer)
    macro_step = gradient_update(macro_part, optimizer)

    def update(params, target_params, opt_state, batch, key, progress):
        params, opt_state, metrics = micro_step(params, target_params, opt_state, batch, key, progress)
        has_macro = jnp.any(views.macro_view(batch).mask)

        def step(args):
            p, o = args
            p, o, m = macro_step(p, target_params, o, batch, key, progress)
            return p, o, m["macro_loss"], m["grad_norm"]

        def skip(args):
            return args[0], args[1], jnp.zeros(()), jnp.zeros(())

        params, opt_state, macro_loss, macro_norm = jax.lax.cond(has_macro, step, skip, (params, opt_state))
        metrics = metrics | {"macro_loss": macro_loss, "grad_norm_macro": macro_norm,
                             "loss": metrics["loss"] + lam * macro_loss}
        return params, opt_state, metrics

    return update
