"""Mixers: QMIX with ATPG-generated parameters (ToMacVF), vanilla QMIX, VDN and QPLEX (DECISIONS D6, D19).

The hyper-networks run once per row and return ``MixWeights``; ``mix`` then applies them to any
number of candidate joint Q vectors (chosen actions, target actions, a brute-force enumeration)
by broadcasting, so weights are never recomputed per candidate::

    Q_tot = W2ᵀ ELU(Σ_i Q_i W1[i] + b1) + b2          (QMIX kinds; W1, W2 ≥ 0 -> monotone in every Q_i)
    Q_tot = Σ_i Q_i                                     (vdn)

Kinds (``MixerConfig.kind``), all hyper-networks ``Dense(hyper_hidden)–ReLU–Dense`` (2 layers):

* ``'atpg_qmix'`` (ToMacVF): ``W1[i,:] = |f_w1([s_t, ê_t^i])|`` (one row per agent from its own
  ATPG encoding), ``b1 = f_b1([s_t, mean_i ê_t^i])``, ``W2 = |f_w2(s_t)|``, ``b2 = f_v(s_t)``.
* ``'qmix'`` (ToMacVF w/o ATPG): vanilla QMIX hyper-networks on ``s_t`` only,
  ``W1 = |f_w1(s_t)|`` reshaped ``[n, embed]``.
* ``'vdn'``: no parameters, no ATPG (D19).
* ``'qplex'``: QPLEX's duplex dueling mixer on ``s_t`` (Wang et al. 2021): per-agent transformation
  ``Q_i′ = w_i(s) Q_i + b_i(s)``, ``V_i′ = w_i(s) max_a Q_i + b_i(s)`` (``w_i > 0``), and
  ``Q_tot = Σ_i V_i′ + Σ_i λ_i(s, a) (Q_i′ − V_i′)`` with ``λ_i(s, a) = Σ_k |κ_k(s)| |φ_k(s)_i| σ(ψ_k(s, a)_i) > 0``
  over ``qplex_heads`` heads; ψ is a 2-layer MLP on ``[s, onehot(a_1), …, onehot(a_n)]`` whose first layer is split
  into a per-row state part and a per-action table, so the weights are still computed once per row. Because
  ``Q_i′ − V_i′ ≤ 0`` with equality at agent i's greedy action, the per-agent argmaxes maximise Q_tot (IGM).

What a mixer is *conditioned on* is the caller's choice of ``state``: the global state (ToMacVF, QMIX), ATPG's
encodings with it ('atpg_qmix'), or AVF's macro-state (the concatenation of each agent's state at its
decision) — ``state_dim`` is just the width of that vector. Q_tot of a joint action takes the per-agent Q
*table* and the actions (``mix_actions``): QPLEX needs ``max_a Q_i`` and λ(s, a); QMIX and VDN only the chosen
entries (``mix``). QTRAN is future work.

Shapes (``...`` = leading axes, typically ``[B, T]``)::

    mixer = Mixer(config)
    params = init_mixer_params(config, key)                 # {} for 'vdn'
    weights, atpg_out = mixer.apply(params, state, inputs)  # state f32[..., T, S], inputs NetInputs [..., T, ...]
    q_tot = mix(weights, q_joint)                           # q_joint f32[*C, ..., T, n] -> f32[*C, ..., T]

``atpg_out`` is an ``ATPGOutput`` for 'atpg_qmix' and None otherwise; ``inputs`` may be None for
'qmix'/'vdn'. Because the ATPG tokens use the macro-actions in force *before* row t (D4),
``weights`` at row t do not depend on the choices made at t, so ``mix`` is monotone in each Q_i for
fixed weights and the conditional per-agent argmax (``conditional_greedy``) maximises Q_tot (D9).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from jaxmac.networks.agent import _from_spec, _positive_int, dummy_inputs
from jaxmac.networks.atpg import ATPG, ATPGConfig
from jaxmac.networks.inputs import NetInputs

MIXER_KINDS = ("atpg_qmix", "qmix", "vdn", "qplex")


@dataclasses.dataclass(frozen=True)
class MixerConfig:
    """Static configuration of the mixer (hashable).

    Attributes:
      num_agents: n.
      state_dim: S.
      kind: one of ``MIXER_KINDS``: 'atpg_qmix' (ToMacVF), 'qmix' (w/o ATPG), 'vdn'.
      embed: QMIX mixing width (32).
      hyper_hidden: hidden width of every hyper-network (64).
      num_actions: A, padded actions per agent (QPLEX's λ reads the joint action).
      qplex_heads: QPLEX's attention heads K (4, as QPLEX).
      atpg: ``ATPGConfig`` (required for 'atpg_qmix', ignored otherwise); its ``num_agents`` must match.
    """

    num_agents: int
    state_dim: int
    kind: str = "atpg_qmix"
    embed: int = 32
    hyper_hidden: int = 64
    atpg: ATPGConfig | None = None
    num_actions: int = 1
    qplex_heads: int = 4

    def __post_init__(self):
        for name in ("num_agents", "state_dim", "embed", "hyper_hidden", "num_actions", "qplex_heads"):
            _positive_int("MixerConfig", name, getattr(self, name))
        if self.kind not in MIXER_KINDS:
            raise ValueError(f"MixerConfig.kind={self.kind!r}; valid choices: {list(MIXER_KINDS)}")
        if self.kind == "atpg_qmix":
            if not isinstance(self.atpg, ATPGConfig):
                raise ValueError(f"MixerConfig.atpg={self.atpg!r}: kind 'atpg_qmix' needs an ATPGConfig")
            if self.atpg.num_agents != self.num_agents:
                raise ValueError(
                    f"MixerConfig.atpg.num_agents={self.atpg.num_agents} must equal num_agents={self.num_agents}"
                )

    @classmethod
    def from_spec(cls, spec: Any, kind: str = "atpg_qmix", **overrides: Any) -> MixerConfig:
        """Config for an ``envs_jax.EnvSpec``. For 'atpg_qmix' the ATPG config is
        ``ATPGConfig.from_spec(spec, **overrides.pop('atpg_overrides', {}))`` unless ``atpg`` is given."""
        atpg_overrides = overrides.pop("atpg_overrides", {})
        if kind == "atpg_qmix" and "atpg" not in overrides:
            overrides["atpg"] = ATPGConfig.from_spec(spec, **atpg_overrides)
        return _from_spec(cls, dict(num_agents=spec.num_agents, state_dim=spec.state_dim, kind=kind), overrides)


@struct.dataclass
class MixWeights:
    """Mixing parameters per row; leaves None for 'vdn' (and the QMIX leaves None for 'qplex')."""

    w1: chex.Array | None  # f32[..., n, E] ≥ 0
    b1: chex.Array | None  # f32[..., E]
    w2: chex.Array | None  # f32[..., E] ≥ 0
    b2: chex.Array | None  # f32[...]
    kind: str = struct.field(pytree_node=False, default="atpg_qmix")
    qplex: QPLEXWeights | None = None


@struct.dataclass
class QPLEXWeights:
    """QPLEX per row (``K`` heads, ``G`` = hyper_hidden); the action tables are parameters, shared by every row."""

    w: chex.Array  # f32[..., n] > 0 transformation scale w_i(s)
    b: chex.Array  # f32[..., n] transformation shift b_i(s)
    key: chex.Array  # f32[..., K] |κ_k(s)|
    agents: chex.Array  # f32[..., K, n] |φ_k(s)_i|
    psi_state: chex.Array  # f32[..., K, G] first layer of ψ_k on s (bias included)
    psi_action: chex.Array  # f32[K, n, A, G] first layer of ψ_k on agent i's one-hot action
    psi_out_w: chex.Array  # f32[K, G, n]
    psi_out_b: chex.Array  # f32[K, n]


def mix(weights: MixWeights, q: chex.Array) -> chex.Array:
    """Q_tot from per-agent values ``q`` f32[..., n] (the Q_i of one joint action).

    The leading axes of ``q`` broadcast against those of the weights, e.g. weights ``[B, T]`` and
    ``q`` ``[C, B, T, n]`` for C candidate joint actions. Returns f32[broadcast leading axes].
    """
    if weights.kind == "vdn":
        return jnp.sum(q, axis=-1)
    if weights.kind == "qplex":
        raise ValueError("mix: QPLEX needs the per-agent Q table and the actions; use mix_actions")
    hidden = jax.nn.elu(jnp.sum(q[..., :, None] * weights.w1, axis=-2) + weights.b1)  # [..., E]
    return jnp.sum(hidden * weights.w2, axis=-1) + weights.b2


def mix_actions(weights: MixWeights, q_table: chex.Array, actions: chex.Array, avail: chex.Array) -> chex.Array:
    """Q_tot of joint ``actions`` i32[..., n] from the per-agent Q table ``q_table`` f32[..., n, A] (any mixer).

    ``avail`` bool[..., n, A] gives QPLEX's ``V_i = max_{available a} Q_i``. Leading axes broadcast against the
    weights' as in ``mix`` (e.g. candidates ``[C, B, T]``). Returns f32[broadcast leading axes].
    """
    from jaxmac.networks.agent import mask_unavailable
    from jaxmac.targets import gather_q

    lead = jnp.broadcast_shapes(q_table.shape[:-2], actions.shape[:-1])
    q = gather_q(jnp.broadcast_to(q_table, lead + q_table.shape[-2:]), jnp.broadcast_to(actions, lead + actions.shape[-1:]))
    if weights.kind != "qplex":
        return mix(weights, q)
    qp = weights.qplex
    v = jnp.max(mask_unavailable(q_table, avail), axis=-1)
    q_t, v_t = qp.w * q + qp.b, qp.w * v + qp.b
    # ψ_k(s, a): the state part plus, for every agent, the row of its chosen action in the action table
    k, n = qp.psi_action.shape[:2]
    a = jnp.clip(actions, 0, qp.psi_action.shape[2] - 1)
    per_agent = qp.psi_action[:, jnp.arange(n), a]  # [K, ..., n, G] (advanced indexing moves K first)
    act = jnp.moveaxis(jnp.sum(per_agent, axis=-2), 0, -2)  # [..., K, G]
    hidden = jax.nn.relu(qp.psi_state + act)
    psi = jnp.einsum("...kg,kgn->...kn", hidden, qp.psi_out_w) + qp.psi_out_b
    lam = jnp.sum(qp.key[..., None] * qp.agents * jax.nn.sigmoid(psi), axis=-2) + 1e-10  # [..., n] > 0
    return jnp.sum(v_t, axis=-1) + jnp.sum(lam * (q_t - v_t), axis=-1)


class HyperMLP(nn.Module):
    """``Dense(hidden)–ReLU–Dense(out)``: f32[..., F] -> f32[..., out]."""

    hidden: int
    out: int

    @nn.compact
    def __call__(self, x):
        return nn.Dense(self.out, name="out")(nn.relu(nn.Dense(self.hidden, name="hidden")(x)))


class Mixer(nn.Module):
    """Hyper-networks of the configured kind (see the module docstring).

    Call: ``(state f32[..., S], inputs NetInputs [..., T, ...] | None)`` -> ``(MixWeights, ATPGOutput | None)``.
    For 'atpg_qmix' the state's leading axes must be the inputs' ``[..., T]``; for 'qmix' any leading
    axes work (e.g. states gathered at segment starts).
    """

    config: MixerConfig

    @nn.compact
    def __call__(self, state: chex.Array, inputs: NetInputs | None = None):
        cfg = self.config
        n, emb, hid = cfg.num_agents, cfg.embed, cfg.hyper_hidden
        if state.shape[-1] != cfg.state_dim:
            raise ValueError(f"Mixer: state has shape {state.shape}, expected [..., {cfg.state_dim}]")
        if cfg.kind == "vdn":
            return MixWeights(None, None, None, None, kind="vdn"), None
        state = state.astype(jnp.float32)
        if cfg.kind == "qplex":
            return MixWeights(None, None, None, None, kind="qplex", qplex=self._qplex(state)), None
        atpg_out = None
        if cfg.kind == "atpg_qmix":
            if inputs is None:
                raise ValueError("Mixer: kind 'atpg_qmix' needs the NetInputs of the rows (got None)")
            if state.shape[:-1] != inputs.t.shape:
                raise ValueError(
                    f"Mixer: state leading shape {state.shape[:-1]} must equal the inputs' [..., T] = {inputs.t.shape}"
                )
            atpg_out = ATPG(cfg.atpg, name="atpg")(inputs)
            e_hat = atpg_out.e_hat  # [..., n, d]
            s_per_agent = jnp.broadcast_to(state[..., None, :], e_hat.shape[:-1] + (state.shape[-1],))
            w1 = jnp.abs(HyperMLP(hid, emb, name="f_w1")(jnp.concatenate([s_per_agent, e_hat], axis=-1)))
            b1 = HyperMLP(hid, emb, name="f_b1")(jnp.concatenate([state, jnp.mean(e_hat, axis=-2)], axis=-1))
        else:  # 'qmix'
            w1 = jnp.abs(HyperMLP(hid, n * emb, name="f_w1")(state)).reshape(state.shape[:-1] + (n, emb))
            b1 = HyperMLP(hid, emb, name="f_b1")(state)
        w2 = jnp.abs(HyperMLP(hid, emb, name="f_w2")(state))
        b2 = HyperMLP(hid, 1, name="f_v")(state)[..., 0]
        return MixWeights(w1=w1, b1=b1, w2=w2, b2=b2, kind=cfg.kind), atpg_out

    def _qplex(self, state):
        cfg = self.config
        n, k, hid, a = cfg.num_agents, cfg.qplex_heads, cfg.hyper_hidden, cfg.num_actions
        lead = state.shape[:-1]
        w = jnp.abs(HyperMLP(hid, n, name="q_w")(state)) + 1e-10
        b = HyperMLP(hid, n, name="q_b")(state)
        key = jnp.abs(HyperMLP(hid, k, name="lambda_key")(state))
        agents = jnp.abs(HyperMLP(hid, k * n, name="lambda_agents")(state)).reshape(lead + (k, n))
        psi_state = nn.Dense(k * hid, name="psi_state")(state).reshape(lead + (k, hid))
        init = nn.initializers.lecun_normal()
        # the one-hot-action rows of ψ's first layer, initialised as one Dense over [onehot(a_1), …, onehot(a_n)]
        psi_action = self.param(
            "psi_action", lambda key_, shape: jnp.transpose(init(key_, (n * a, k * hid)).reshape(n, a, k, hid),
                                                             (2, 0, 1, 3)), (k, n, a, hid))
        psi_out_w = self.param("psi_out_w", lambda key_, shape: jax.vmap(lambda kk: init(kk, shape[1:]))(
            jax.random.split(key_, shape[0])), (k, hid, n))
        psi_out_b = self.param("psi_out_b", nn.initializers.zeros_init(), (k, n))
        return QPLEXWeights(w=w, b=b, key=key, agents=agents, psi_state=psi_state, psi_action=psi_action,
                            psi_out_w=psi_out_w, psi_out_b=psi_out_b)


@functools.partial(jax.jit, static_argnums=0)
def init_mixer_params(config: MixerConfig, key: chex.PRNGKey):
    """Parameters of ``Mixer(config)`` (jitted init on one dummy row, compiled once per config;
    ``{}`` for 'vdn')."""
    state = jnp.zeros((1, config.state_dim), jnp.float32)
    obs_dim = config.atpg.obs_dim if config.atpg is not None else 1
    inputs = dummy_inputs(config.num_agents, obs_dim) if config.kind == "atpg_qmix" else None
    return Mixer(config).init(key, state, inputs)


def take_rows(tree: Any, rows: chex.Array, batch_ndim: int = 0) -> Any:
    """Gather rows of per-row arrays (MixWeights, Q values, hidden states, …).

    Leaves are ``[*batch, T, *rest]`` with ``batch_ndim`` leading batch axes; ``rows`` is
    i32[*batch, *idx]. Returns leaves ``[*batch, *idx, *rest]``, e.g. weights ``[B, T, ...]`` at
    segment starts ``rows [B, n, K]`` -> ``[B, n, K, ...]`` (``batch_ndim=1``).
    """

    def one(x, r):
        return jnp.take(x, r, axis=0)

    fn = lambda x: _vmap_n(one, batch_ndim)(x, rows)
    return jax.tree_util.tree_map(fn, tree)


def _vmap_n(fn, k):
    for _ in range(k):
        fn = jax.vmap(fn)
    return fn
