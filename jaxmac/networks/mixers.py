"""Mixers of ToMacVF: QMIX with ATPG-generated parameters, vanilla QMIX, VDN (DECISIONS D6, D19).

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

QTRAN and QPLEX mixers (D19, the paper's Fig. 7) are future work.

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

MIXER_KINDS = ("atpg_qmix", "qmix", "vdn")


@dataclasses.dataclass(frozen=True)
class MixerConfig:
    """Static configuration of the mixer (hashable).

    Attributes:
      num_agents: n.
      state_dim: S.
      kind: one of ``MIXER_KINDS``: 'atpg_qmix' (ToMacVF), 'qmix' (w/o ATPG), 'vdn'.
      embed: QMIX mixing width (32).
      hyper_hidden: hidden width of every hyper-network (64).
      atpg: ``ATPGConfig`` (required for 'atpg_qmix', ignored otherwise); its ``num_agents`` must match.
    """

    num_agents: int
    state_dim: int
    kind: str = "atpg_qmix"
    embed: int = 32
    hyper_hidden: int = 64
    atpg: ATPGConfig | None = None

    def __post_init__(self):
        for name in ("num_agents", "state_dim", "embed", "hyper_hidden"):
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
    """Mixing parameters per row; leaves None for 'vdn'."""

    w1: chex.Array | None  # f32[..., n, E] ≥ 0
    b1: chex.Array | None  # f32[..., E]
    w2: chex.Array | None  # f32[..., E] ≥ 0
    b2: chex.Array | None  # f32[...]
    kind: str = struct.field(pytree_node=False, default="atpg_qmix")


def mix(weights: MixWeights, q: chex.Array) -> chex.Array:
    """Q_tot from per-agent values ``q`` f32[..., n] (the Q_i of one joint action).

    The leading axes of ``q`` broadcast against those of the weights, e.g. weights ``[B, T]`` and
    ``q`` ``[C, B, T, n]`` for C candidate joint actions. Returns f32[broadcast leading axes].
    """
    if weights.kind == "vdn":
        return jnp.sum(q, axis=-1)
    hidden = jax.nn.elu(jnp.sum(q[..., :, None] * weights.w1, axis=-2) + weights.b1)  # [..., E]
    return jnp.sum(hidden * weights.w2, axis=-1) + weights.b2


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
