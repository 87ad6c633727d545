"""The temporal agent network of ToMacVF (DECISIONS D2, D3).

For agent ``i`` at row ``t`` (what it saw before step ``t``, see ``jaxmac.networks.inputs``)::

    x_t  = [ ô_t ⊕ PE(t),  onehot(m_{t-1}) ⊕ PE(t-1) ⊕ PE(t_m(t-1)),  onehot(i) ]
    h_t  = GRU(ReLU(Dense_fc(x_t)), h_{t-1})        h_{-1} = 0, and h_{t-1} := 0 where reset[t]
    Q_i(ĥ_t, ·, τ) = MLP([h_t, PE(τ)]) ∈ R^A

PE(t) has ``encoding.dim_t`` features, PE(t_m) and PE(τ) ``encoding.dim_tm`` (``jaxmac.encodings``);
``encoding.use_t=False`` drops PE(t) and PE(t-1) (D3). Where ``m_{t-1} = -1`` (no previous action)
the whole previous-action block is zero. The GRU runs over **every primitive step**; τ is the
progress of the macro-action being valued (``t_m`` for the executing action, 0 at decision points).

Every agent has its own parameters: the GRU torso and the Q head are ``flax.linen.vmap``-ed over
the agent axis (stacked params, leading axis ``n``); observations and actions are padded to
``O``/``A`` and unavailable actions are masked with ``mask_unavailable``.

Shapes (``...`` = any leading batch axes, e.g. ``[B]``; ``T`` rows; ``n`` agents; ``h`` GRU size)::

    net = TemporalAgentNet(config)
    params = init_agent_params(config, key)
    q, hs, carry_T = net.apply(params, inputs, carry, tau)           # f32[..., T, n, A], [..., T, n, h], [..., n, h]
    hs, carry_T = net.apply(params, inputs, carry, method="unroll")    # recurrent part only
    q = net.apply(params, hs, tau, method="q_values")                 # head at any τ[..., T, n]
    q_t, carry = net.apply(params, inputs_t, carry, tau_t, method="step")  # acting: no T axis

``carry = initial_carry(config, batch_shape)`` (zeros). ``step`` is ``__call__`` on a length-1
sequence, so stepping a sequence row by row reproduces the sequence apply.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp

from envs_jax.validation import is_integer
from jaxmac.encodings import EncodingConfig, sinusoid
from jaxmac.networks.inputs import NetInputs, validate_inputs


def _positive_int(owner: str, name: str, v: Any) -> None:
    if not is_integer(v) or v < 1:
        raise ValueError(f"{owner}.{name}={v!r} must be a positive integer")


@dataclasses.dataclass(frozen=True)
class AgentNetConfig:
    """Static configuration of the temporal agent network (hashable).

    Attributes:
      num_agents: n.
      obs_dim: O, padded observation width.
      num_actions: A, padded macro-action count.
      hidden: GRU size h (D2: 32 BP-6/8, 48 BP-10, 64 BP-12/14, 32 Overcooked, 64 Warehouse).
      fc: width of the Dense-ReLU layer before the GRU (64).
      head_hidden: hidden widths of the Q head MLP on ``[h_t, PE(τ)]`` (ReLU).
      encoding: PE widths/base; ``use_t=False`` drops the absolute-time PE (D3).
    """

    num_agents: int
    obs_dim: int
    num_actions: int
    hidden: int = 64
    fc: int = 64
    head_hidden: tuple[int, ...] = (64,)
    encoding: EncodingConfig = EncodingConfig()

    def __post_init__(self):
        for name in ("num_agents", "obs_dim", "num_actions", "hidden", "fc"):
            _positive_int("AgentNetConfig", name, getattr(self, name))
        if not isinstance(self.head_hidden, tuple) or not all(
            is_integer(w) and w >= 1 for w in self.head_hidden
        ):
            raise ValueError(
                f"AgentNetConfig.head_hidden={self.head_hidden!r} must be a tuple of positive integers, e.g. (64,) or ()"
            )
        if not isinstance(self.encoding, EncodingConfig):
            raise ValueError(f"AgentNetConfig.encoding must be an EncodingConfig, got {self.encoding!r}")

    @classmethod
    def from_spec(cls, spec: Any, **overrides: Any) -> AgentNetConfig:
        """Config for an ``envs_jax.EnvSpec`` (n, padded O and A); ``overrides`` set other fields."""
        return _from_spec(cls, dict(num_agents=spec.num_agents, obs_dim=spec.obs_dim,
                                    num_actions=spec.max_actions), overrides)

    @property
    def feature_dim(self) -> int:
        """Width of ``x_t``."""
        enc = self.encoding
        dt = enc.dim_t if enc.use_t else 0
        return self.obs_dim + dt + self.num_actions + dt + enc.dim_tm + self.num_agents


def _from_spec(cls, fields: dict, overrides: dict):
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = set(overrides) - set(names)
    if unknown:
        raise ValueError(f"{cls.__name__}.from_spec: unknown override(s) {sorted(unknown)}; valid: {names}")
    return cls(**{**fields, **overrides})


def agent_features(config: AgentNetConfig, inputs: NetInputs) -> chex.Array:
    """``x_t`` for every row and agent: f32[..., T, n, config.feature_dim] (parameter-free)."""
    enc, n = config.encoding, config.num_agents
    per_agent = lambda x: jnp.broadcast_to(x[..., None, :], x.shape[:-1] + (n, x.shape[-1]))
    obs_part = [inputs.obs.astype(jnp.float32)]
    act_part = [jax.nn.one_hot(inputs.prev_mac, config.num_actions, dtype=jnp.float32)]
    if enc.use_t:
        obs_part.append(per_agent(sinusoid(inputs.t, enc.dim_t, enc.base)))
        act_part.append(per_agent(sinusoid(inputs.prev_t, enc.dim_t, enc.base)))
    act_part.append(sinusoid(inputs.prev_t_m, enc.dim_tm, enc.base))
    has_prev = (inputs.prev_mac >= 0)[..., None].astype(jnp.float32)
    act = jnp.concatenate(act_part, axis=-1) * has_prev
    agent_id = jnp.broadcast_to(jnp.eye(n, dtype=jnp.float32), act.shape[:-1] + (n,))
    return jnp.concatenate(obs_part + [act, agent_id], axis=-1)


def _gate_orthogonal(key, shape, dtype=jnp.float32):
    """[h, 3h] recurrent kernel: one orthogonal [h, h] block per gate (r, z, n)."""
    h = shape[0]
    keys = jax.random.split(key, 3)
    return jnp.concatenate([nn.initializers.orthogonal()(k, (h, h), dtype) for k in keys], axis=1)


class GRUTorso(nn.Module):
    """One agent: ``Dense(fc)–ReLU–GRU(hidden)`` over a sequence with reset flags.

    GRU (r, z, n gates): r = σ(W_r x + U_r h), z = σ(W_z x + U_z h),
    n = tanh(W_n x + r ⊙ (U_n h + b_hn)), h' = (1 - z) ⊙ n + z ⊙ h (input biases in W·x).
    The input projections of all rows are computed before the time scan.

    Call: ``(x f32[..., T, D], reset bool[..., T, 1], carry f32[..., h])``
    -> ``(hs f32[..., T, h], carry_T f32[..., h])``; the carry is zeroed before every row with
    ``reset`` set, ``hs[..., t, :]`` is the state after row ``t``.
    """

    fc: int
    hidden: int

    @nn.compact
    def __call__(self, x, reset, carry):
        h = self.hidden
        z = nn.relu(nn.Dense(self.fc, name="fc")(x))
        gx = nn.Dense(3 * h, name="gru_in")(z)  # [..., T, 3h]
        u = self.param("gru_hh_kernel", _gate_orthogonal, (h, 3 * h))
        b_hn = self.param("gru_hh_bias", nn.initializers.zeros_init(), (h,))
        return gru_scan(gx, reset[..., 0], carry, u, b_hn)


def gru_scan(gx: chex.Array, reset: chex.Array, carry: chex.Array, u: chex.Array, b_hn: chex.Array):
    """The GRU recurrence over precomputed input projections (the only sequential part of a recurrent net).

    r = σ(gx_r + h U_r), z = σ(gx_z + h U_z), n = tanh(gx_n + r ⊙ (h U_n + b_hn)), h' = (1 − z) ⊙ n + z ⊙ h;
    the carry is zeroed before every row with ``reset`` set.

    Args:
      gx: f32[..., T, 3h] input projections W·x + b of every row (gates r, z, n).
      reset: bool[..., T].
      carry: f32[..., h] state before row 0.
      u: f32[h, 3h] recurrent kernel; b_hn: f32[h].
    Returns:
      (hs f32[..., T, h] the state after each row, carry_T f32[..., h]).
    """
    h = u.shape[0]

    def cell(c, row):
        g, r_flag = row
        c = jnp.where(r_flag[..., None], jnp.zeros_like(c), c)
        gh = c @ u
        r = jax.nn.sigmoid(g[..., :h] + gh[..., :h])
        zz = jax.nn.sigmoid(g[..., h:2 * h] + gh[..., h:2 * h])
        nn_ = jnp.tanh(g[..., 2 * h:] + r * (gh[..., 2 * h:] + b_hn))
        c = (1.0 - zz) * nn_ + zz * c
        return c, c

    carry_t, hs = jax.lax.scan(cell, carry, (jnp.moveaxis(gx, -2, 0), jnp.moveaxis(reset, -1, 0)))
    return jnp.moveaxis(hs, 0, -2), carry_t


class QHead(nn.Module):
    """One agent: ``MLP([h_t, PE(τ)]) -> A``. Call: ``(hs f32[..., h], tau_enc f32[..., E]) -> f32[..., A]``."""

    hidden: Sequence[int]
    num_actions: int

    @nn.compact
    def __call__(self, hs, tau_enc):
        y = jnp.concatenate([hs, tau_enc], axis=-1)
        for k, w in enumerate(self.hidden):
            y = nn.relu(nn.Dense(w, name=f"hidden_{k}")(y))
        return nn.Dense(self.num_actions, name="out")(y)


def _per_agent(module_cls):
    """Separate parameters per agent: params stacked on axis 0, agents on axis -2 of every input."""
    return nn.vmap(
        module_cls, variable_axes={"params": 0}, split_rngs={"params": True}, in_axes=-2, out_axes=-2
    )


class TemporalAgentNet(nn.Module):
    """All agents' temporal agent networks (see the module docstring for the API and shapes)."""

    config: AgentNetConfig

    def setup(self):
        cfg = self.config
        self.torso = _per_agent(GRUTorso)(fc=cfg.fc, hidden=cfg.hidden)
        self.head = _per_agent(QHead)(hidden=tuple(cfg.head_hidden), num_actions=cfg.num_actions)

    def unroll(self, inputs: NetInputs, carry: chex.Array) -> tuple[chex.Array, chex.Array]:
        """``inputs`` [..., T, ...], ``carry`` f32[..., n, h] -> (hs f32[..., T, n, h], carry_T f32[..., n, h])."""
        cfg = self.config
        validate_inputs(inputs, cfg.num_agents, cfg.obs_dim, "TemporalAgentNet")
        x = agent_features(cfg, inputs)
        # [..., T, n, 1]: agents on axis -2 like every other per-agent input
        reset = jnp.broadcast_to(inputs.reset[..., None, None], inputs.prev_mac.shape + (1,))
        return self.torso(x, reset, carry)

    def q_values(self, hs: chex.Array, tau: chex.Array) -> chex.Array:
        """``hs`` f32[..., n, h], ``tau`` i32[..., n] -> Q f32[..., n, A] (unmasked)."""
        enc = self.config.encoding
        return self.head(hs, sinusoid(tau, enc.dim_tm, enc.base))

    def __call__(self, inputs: NetInputs, carry: chex.Array, tau: chex.Array):
        """-> (q f32[..., T, n, A], hs f32[..., T, n, h], carry_T f32[..., n, h]); ``tau`` i32[..., T, n]."""
        hs, carry_t = self.unroll(inputs, carry)
        return self.q_values(hs, tau), hs, carry_t

    def step(self, inputs: NetInputs, carry: chex.Array, tau: chex.Array):
        """One row, no T axis: ``inputs`` leaves [..., n, ...], ``carry`` f32[..., n, h], ``tau`` i32[..., n]
        -> (q f32[..., n, A], carry' f32[..., n, h])."""
        q, _, carry_t = self(inputs.add_time_axis(), carry, tau[..., None, :])
        return q[..., 0, :, :], carry_t


def initial_carry(config: AgentNetConfig, batch_shape: tuple[int, ...] = ()) -> chex.Array:
    """Zero GRU state f32[*batch_shape, n, h]."""
    return jnp.zeros(tuple(batch_shape) + (config.num_agents, config.hidden), jnp.float32)


def dummy_inputs(num_agents: int, obs_dim: int, length: int = 1) -> NetInputs:
    """A zero input sequence ``[length, ...]`` (for ``init``)."""
    t = jnp.zeros((length,), jnp.int32)
    return NetInputs(
        obs=jnp.zeros((length, num_agents, obs_dim), jnp.float32), t=t, prev_t=t - 1,
        prev_mac=jnp.full((length, num_agents), -1, jnp.int32),
        prev_t_m=jnp.zeros((length, num_agents), jnp.int32), reset=t == 0,
    )


@functools.partial(jax.jit, static_argnums=0)
def init_agent_params(config: AgentNetConfig, key: chex.PRNGKey):
    """Parameters of ``TemporalAgentNet(config)`` (jitted init, compiled once per config; every leaf
    has leading axis n)."""
    inputs = dummy_inputs(config.num_agents, config.obs_dim)
    tau = jnp.zeros((1, config.num_agents), jnp.int32)
    return TemporalAgentNet(config).init(key, inputs, initial_carry(config), tau)
