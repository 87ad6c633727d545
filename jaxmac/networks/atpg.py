"""Agent-oriented Temporal Parameter Generation, the attention part (DECISIONS D4, D5).

1. Tokens, per agent and row ``t`` (weights shared across agents, agent one-hot appended)::

       tok_t^i = MLP([ô_t^i ⊕ PE(t),  onehot(m_{t-1}^i) ⊕ PE(t) ⊕ PE(t_m^i(t-1)),  onehot(i)]) ∈ R^d

   The action is the macro-action *in force before the decision at t* (D4), so nothing computed
   at row t depends on the free agents' choices at t; where ``m_{t-1} = -1`` its block is zero.
2. Temporal self-attention, per agent, single head, causal over the rows of one episode
   (``s ≤ t``, the current row included; with ``attn_window = w`` only ``t - w < s ≤ t``)::

       e_t^i = Σ_s softmax_s(q_t^i · k_s^i / √d) v_s^i        q, k, v = W_{Q,K,V} tok

3. Agent-oriented attention across agents at each row (D5)::

       α_t^{ij} = softmax_{j≠i}(q_i · k_j / √d),  α_t^{ii} = 0,  α_t^{ij} := 0 where α_t^{ij} < δ
       ê_t^i = Σ_j α_t^{ij} v_j                   q, k, v = W_{Q,K,V} e_t   (no renormalisation)

   With a single agent there is no other agent: ``ê = 0`` and ``α = 0``.

A sequence is one episode from its reset, or several episodes back to back (packed rows): the temporal attention
of a row only reads the rows since the last ``inputs.reset`` (rows after an episode's end only influence later
rows). Shapes, ``...`` = leading batch axes::

    out = ATPG(config).apply(params, inputs)        # inputs: NetInputs [..., T, ...]
    out.e_hat  f32[..., T, n, d]    out.alpha  f32[..., T, n, n]    out.e  f32[..., T, n, d]
"""

from __future__ import annotations

import dataclasses
from typing import Any

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxmac.encodings import EncodingConfig, sinusoid
from jaxmac.networks.agent import _from_spec, _positive_int
from jaxmac.networks.inputs import NetInputs, validate_inputs


@dataclasses.dataclass(frozen=True)
class ATPGConfig:
    """Static configuration of ATPG's attention (hashable).

    Attributes:
      num_agents, obs_dim, num_actions: n, padded O and A.
      embed: d, width of tokens, temporal and agent encodings (32).
      token_hidden: hidden width of the token MLP (Dense(token_hidden)–ReLU–Dense(d)).
      attn_window: None (whole episode so far) or w ≥ 1 (the last w rows, current one included).
      delta: δ ∈ [0, 1), agent-attention weights below it are zeroed (0.05).
      encoding: PE widths/base; ``use_t=False`` drops PE(t) (D3).
    """

    num_agents: int
    obs_dim: int
    num_actions: int
    embed: int = 32
    token_hidden: int = 64
    attn_window: int | None = None
    delta: float = 0.05
    encoding: EncodingConfig = EncodingConfig()

    def __post_init__(self):
        for name in ("num_agents", "obs_dim", "num_actions", "embed", "token_hidden"):
            _positive_int("ATPGConfig", name, getattr(self, name))
        if self.attn_window is not None:
            _positive_int("ATPGConfig", "attn_window", self.attn_window)
        if isinstance(self.delta, bool) or not isinstance(self.delta, (int, float)) or not 0.0 <= self.delta < 1.0:
            raise ValueError(f"ATPGConfig.delta={self.delta!r} must be a number in [0, 1) (default 0.05)")
        if not isinstance(self.encoding, EncodingConfig):
            raise ValueError(f"ATPGConfig.encoding must be an EncodingConfig, got {self.encoding!r}")

    @classmethod
    def from_spec(cls, spec: Any, **overrides: Any) -> ATPGConfig:
        """Config for an ``envs_jax.EnvSpec`` (n, padded O and A); ``overrides`` set other fields."""
        return _from_spec(cls, dict(num_agents=spec.num_agents, obs_dim=spec.obs_dim,
                                    num_actions=spec.max_actions), overrides)


@struct.dataclass
class ATPGOutput:
    e_hat: chex.Array  # f32[..., T, n, d] agent-oriented encodings ê_t^i (what the mixer reads)
    alpha: chex.Array  # f32[..., T, n, n] α_t^{ij} after the diagonal and δ masks
    e: chex.Array  # f32[..., T, n, d] temporal encodings e_t^i


def token_features(config: ATPGConfig, inputs: NetInputs) -> chex.Array:
    """Token MLP input for every row and agent: f32[..., T, n, F] (parameter-free)."""
    enc, n = config.encoding, config.num_agents
    per_agent = lambda x: jnp.broadcast_to(x[..., None, :], x.shape[:-1] + (n, x.shape[-1]))
    pe_t = [per_agent(sinusoid(inputs.t, enc.dim_t, enc.base))] if enc.use_t else []
    obs_part = [inputs.obs.astype(jnp.float32)] + pe_t
    act_part = [jax.nn.one_hot(inputs.prev_mac, config.num_actions, dtype=jnp.float32)] + pe_t
    act_part.append(sinusoid(inputs.prev_t_m, enc.dim_tm, enc.base))
    act = jnp.concatenate(act_part, axis=-1) * (inputs.prev_mac >= 0)[..., None].astype(jnp.float32)
    agent_id = jnp.broadcast_to(jnp.eye(n, dtype=jnp.float32), act.shape[:-1] + (n,))
    return jnp.concatenate(obs_part + [act, agent_id], axis=-1)


def temporal_mask(length: int, window: int | None) -> np.ndarray:
    """bool[T, T]: row t may attend to row s (s ≤ t, and t - s < window if a window is set)."""
    t = np.arange(length)
    lag = t[:, None] - t[None, :]
    ok = lag >= 0
    return ok if window is None else ok & (lag < window)


def query_blocks(length: int, blocks: int = 2) -> list[tuple[int, int]]:
    """[(first query row, end query row)]: the rows ``[0, length)`` cut into ``blocks`` query blocks; each attends to
    the keys up to its own end (the causal mask is zero beyond), so the masked-out upper triangle is never computed."""
    edges = sorted({round(length * j / blocks) for j in range(blocks + 1)})
    return list(zip(edges[:-1], edges[1:]))


def _attention_block(q, k, v, allowed):
    """softmax(q kᵀ / √d | allowed) v and the probabilities: q f32[..., Tq, d], k, v f32[..., Tk, d], allowed
    bool[..., Tq, Tk] (every query row allows at least one key) -> (out f32[..., Tq, d], p f32[..., Tq, Tk])."""
    logits = (q @ jnp.swapaxes(k, -1, -2)) * (1.0 / np.sqrt(q.shape[-1]))
    p = jax.nn.softmax(jnp.where(allowed, logits, -jnp.inf), axis=-1)
    return p @ v, p


@jax.custom_vjp
def causal_attention(q, k, v, segment, window):
    """Causal single-head attention within segments, by query blocks (``query_blocks``).

    Row t attends to rows s ≤ t of its own segment (and t − s < window when ``window`` is an i32[] > 0).
    Args: q, k, v f32[..., T, d]; segment i32[..., T] (its leading axes broadcast against q's); window i32[]
    (0 = none).
    Returns f32[..., T, d]. The backward pass is the textbook one (dV = Pᵀ dO, dS = P ⊙ (dP − rowsum(dO ⊙ O)))
    on the stored probabilities of each block, which XLA runs faster on CPU than the autodiff of the masked softmax.
    """
    return _causal_attention_fwd(q, k, v, segment, window)[0]


def _block_masks(segment, window):
    """(first query row, end query row, allowed bool[..., Tq, Tk] over keys 0 … end) per query block."""
    t = np.arange(segment.shape[-1])
    for a, b in query_blocks(segment.shape[-1]):
        lag = t[a:b, None] - t[None, :b]
        allowed = (lag >= 0) & ((window <= 0) | (lag < window))
        yield a, b, allowed & (segment[..., a:b, None] == segment[..., None, :b])


def _causal_attention_fwd(q, k, v, segment, window):
    outs, probs = [], []
    for a, b, allowed in _block_masks(segment, window):
        out, p = _attention_block(q[..., a:b, :], k[..., :b, :], v[..., :b, :], allowed)
        outs.append(out)
        probs.append(p)
    out = jnp.concatenate(outs, axis=-2)
    return out, (q, k, v, segment, window, out, probs)


def _causal_attention_bwd(res, d_out):
    q, k, v, segment, window, out, probs = res
    scale = 1.0 / np.sqrt(q.shape[-1])
    dq, dk, dv = [], jnp.zeros_like(k), jnp.zeros_like(v)
    row_dot = jnp.sum(d_out * out, axis=-1, keepdims=True)  # rowsum(dO ⊙ O) [..., T, 1]
    for (a, b), p in zip(query_blocks(q.shape[-2]), probs):
        do = d_out[..., a:b, :]
        dv = dv.at[..., :b, :].add(jnp.swapaxes(p, -1, -2) @ do)
        ds = p * (do @ jnp.swapaxes(v[..., :b, :], -1, -2) - row_dot[..., a:b, :]) * scale
        dq.append(ds @ k[..., :b, :])
        dk = dk.at[..., :b, :].add(jnp.swapaxes(ds, -1, -2) @ q[..., a:b, :])
    return jnp.concatenate(dq, axis=-2), dk, dv, None, None


causal_attention.defvjp(_causal_attention_fwd, _causal_attention_bwd)


class TemporalSelfAttention(nn.Module):
    """Single-head causal self-attention over time, independently per agent (shared weights).

    Call: ``(tok f32[..., T, n, d], segment i32[..., T] | None) -> e f32[..., T, n, d]``; with ``segment`` a row
    attends only to rows of its own segment (the episode it belongs to in a packed row).
    """

    embed: int
    window: int | None = None

    @nn.compact
    def __call__(self, tok, segment=None):
        d = self.embed
        x = jnp.swapaxes(tok, -2, -3)  # [..., n, T, d]: plain batched matmuls (faster on CPU than einsum)
        q, k, v = (nn.Dense(d, use_bias=False, name=name)(x) for name in ("query", "key", "value"))
        if segment is None:
            segment = jnp.zeros(tok.shape[:-2], jnp.int32)
        window = jnp.asarray(self.window or 0, jnp.int32)
        return jnp.swapaxes(causal_attention(q, k, v, segment[..., None, :], window), -2, -3)  # same for all agents


class AgentAttention(nn.Module):
    """Attention across agents at each row with α_ii = 0 and α < δ zeroed (D5).

    Call: ``e f32[..., n, d] -> (e_hat f32[..., n, d], alpha f32[..., n, n])``.
    """

    embed: int
    delta: float

    @nn.compact
    def __call__(self, e):
        d, n = self.embed, e.shape[-2]
        q, k, v = (nn.Dense(d, use_bias=False, name=name)(e) for name in ("query", "key", "value"))
        if n == 1:  # no other agent to attend to
            return jnp.zeros_like(v), jnp.zeros(e.shape[:-1] + (1,), e.dtype)
        logits = jnp.einsum("...id,...jd->...ij", q, k) / np.sqrt(d)
        eye = np.eye(n, dtype=bool)
        alpha = jax.nn.softmax(jnp.where(eye, -jnp.inf, logits), axis=-1)
        alpha = jnp.where(eye | (alpha < self.delta), 0.0, alpha)
        return jnp.einsum("...ij,...jd->...id", alpha, v), alpha


class ATPG(nn.Module):
    """Tokens -> temporal self-attention -> agent-oriented attention (see the module docstring)."""

    config: ATPGConfig

    @nn.compact
    def __call__(self, inputs: NetInputs) -> ATPGOutput:
        cfg = self.config
        validate_inputs(inputs, cfg.num_agents, cfg.obs_dim, "ATPG")
        x = token_features(cfg, inputs)
        tok = nn.Dense(cfg.embed, name="token_out")(nn.relu(nn.Dense(cfg.token_hidden, name="token_hidden")(x)))
        segment = jnp.cumsum(inputs.reset.astype(jnp.int32), axis=-1)  # episode index within the sequence
        e = TemporalSelfAttention(cfg.embed, cfg.attn_window, name="temporal")(tok, segment)
        e_hat, alpha = AgentAttention(cfg.embed, cfg.delta, name="agents")(e)
        return ATPGOutput(e_hat=e_hat, alpha=alpha, e=e)
