"""Mixers: QMIX with ATPG-generated parameters (ToMacVF), vanilla QMIX, VDN, QPLEX and QTRAN (DECISIONS D6, D19).

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
  ``V_i`` is the maximum over the actions the caller declares *admissible* for agent i (``mix_actions``' ``avail``):
  passing ``targets.admissible_actions`` (a busy agent's only admissible action is its running one) makes the
  per-agent conditional argmax the exact conditional argmax of Q_tot (To-Mac-IGM, D9).
* ``'qtran'``: QTRAN's joint networks (Son et al. 2019) in the joint-action-input form (pymarl's "coma_critic"
  architecture): ``Q_jt(s, a) = MLP([s, onehot(a_1), …, onehot(a_n)])`` (two hidden layers of ``hyper_hidden``) and
  ``V_jt(s) = MLP(s)``. ``mix_actions`` returns Q_jt (it does not read the per-agent Q table); the factorised
  ``Q′ = Σ_i Q_i`` is tied to it only through QTRAN's constraint losses (``qtran_penalties``). As in QPLEX, the
  first layer on the actions is a per-action table, so any number of candidate joint actions reuse the row's weights.
* ``'atpg_qplex'``, ``'atpg_qtran'`` (ToMacVF_QPLEX, ToMacVF_Qtran, D19): the same mixers conditioned on
  ``c_t = [s_t, ê_t^1, …, ê_t^n]``, the state with every agent's ATPG encoding, instead of ``s_t`` alone.

What a mixer is *conditioned on* is the caller's choice of ``state``: the global state (ToMacVF, QMIX), ATPG's
encodings with it ('atpg_qmix'), or AVF's macro-state (the concatenation of each agent's state at its
decision) — ``state_dim`` is just the width of that vector. Q_tot of a joint action takes the per-agent Q
*table* and the actions (``mix_actions``): QPLEX needs ``max_a Q_i`` and λ(s, a), QTRAN the joint action; QMIX and
VDN only the chosen entries (``mix``).

Shapes (``...`` = leading axes, typically ``[B, T]``)::

    mixer = Mixer(config)
    params = init_mixer_params(config, key)                 # {} for 'vdn'
    weights, atpg_out = mixer.apply(params, state, inputs)  # state f32[..., T, S], inputs NetInputs [..., T, ...]
    q_tot = mix(weights, q_joint)                           # q_joint f32[*C, ..., T, n] -> f32[*C, ..., T]

``atpg_out`` is an ``ATPGOutput`` for the 'atpg_*' kinds and None otherwise; ``inputs`` may be None for the
others. Because the ATPG tokens use the macro-actions in force *before* row t (D4),
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
from jaxmac.ops import gather_q, mask_unavailable

MIXER_KINDS = ("atpg_qmix", "qmix", "vdn", "qplex", "atpg_qplex", "qtran", "atpg_qtran")
ATPG_KINDS = ("atpg_qmix", "atpg_qplex", "atpg_qtran")


@dataclasses.dataclass(frozen=True)
class MixerConfig:
    """Static configuration of the mixer (hashable).

    Attributes:
      num_agents: n.
      state_dim: S.
      kind: one of ``MIXER_KINDS``: 'atpg_qmix' (ToMacVF), 'qmix' (w/o ATPG), 'vdn', 'qplex', 'qtran' and their
        ATPG-conditioned forms.
      embed: QMIX mixing width (32).
      hyper_hidden: hidden width of every hyper-network (64).
      num_actions: A, padded actions per agent (QPLEX's λ reads the joint action).
      qplex_heads: QPLEX's attention heads K (4, as QPLEX).
      atpg: ``ATPGConfig`` (required for the ATPG kinds, ignored otherwise); its ``num_agents`` must match.
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
        if self.kind in ATPG_KINDS:
            if not isinstance(self.atpg, ATPGConfig):
                raise ValueError(f"MixerConfig.atpg={self.atpg!r}: kind {self.kind!r} needs an ATPGConfig")
            if self.atpg.num_agents != self.num_agents:
                raise ValueError(
                    f"MixerConfig.atpg.num_agents={self.atpg.num_agents} must equal num_agents={self.num_agents}"
                )

    @classmethod
    def from_spec(cls, spec: Any, kind: str = "atpg_qmix", **overrides: Any) -> MixerConfig:
        """Config for an ``envs_jax.EnvSpec``. For the ATPG kinds the ATPG config is
        ``ATPGConfig.from_spec(spec, **overrides.pop('atpg_overrides', {}))`` unless ``atpg`` is given."""
        atpg_overrides = overrides.pop("atpg_overrides", {})
        if kind in ATPG_KINDS and "atpg" not in overrides:
            overrides["atpg"] = ATPGConfig.from_spec(spec, **atpg_overrides)
        return _from_spec(cls, dict(num_agents=spec.num_agents, state_dim=spec.state_dim, kind=kind,
                                    num_actions=spec.max_actions), overrides)

    @property
    def family(self) -> str:
        """The mixing function: 'qmix', 'vdn', 'qplex' or 'qtran' (the kind without its conditioning)."""
        return self.kind.removeprefix("atpg_")


@struct.dataclass
class MixWeights:
    """Mixing parameters per row; leaves None for 'vdn' (and the QMIX leaves None for QPLEX and QTRAN).

    ``kind`` is the mixing function ('qmix', 'vdn', 'qplex', 'qtran'), whatever the conditioning."""

    w1: chex.Array | None  # f32[..., n, E] ≥ 0
    b1: chex.Array | None  # f32[..., E]
    w2: chex.Array | None  # f32[..., E] ≥ 0
    b2: chex.Array | None  # f32[...]
    kind: str = struct.field(pytree_node=False, default="qmix")
    qplex: QPLEXWeights | None = None
    qtran: QTRANWeights | None = None

    def map_rows(self, fn) -> MixWeights:
        """``fn`` applied to every per-row leaf (leading axes ``[..., T]``), not to the parameters that every row
        shares (QPLEX's and QTRAN's action tables and upper layers): how rows are sliced or gathered."""
        opt = lambda x: None if x is None else fn(x)  # noqa: E731
        return self.replace(w1=opt(self.w1), b1=opt(self.b1), w2=opt(self.w2), b2=opt(self.b2),
                            qplex=None if self.qplex is None else self.qplex.map_rows(fn),
                            qtran=None if self.qtran is None else self.qtran.map_rows(fn))


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

    def map_rows(self, fn) -> QPLEXWeights:
        return self.replace(w=fn(self.w), b=fn(self.b), key=fn(self.key), agents=fn(self.agents),
                            psi_state=fn(self.psi_state))


@struct.dataclass
class QTRANWeights:
    """QTRAN per row (``G`` = hyper_hidden); the action table and the upper layers are parameters shared by every row."""

    hidden_state: chex.Array  # f32[..., G] Q_jt's first layer on the conditioning (bias included)
    action_table: chex.Array  # f32[n, A, G] Q_jt's first layer on agent i's one-hot action
    w2: chex.Array  # f32[G, G]
    b2: chex.Array  # f32[G]
    w3: chex.Array  # f32[G]
    b3: chex.Array  # f32[]
    v: chex.Array  # f32[...] V_jt(s)

    def map_rows(self, fn) -> QTRANWeights:
        return self.replace(hidden_state=fn(self.hidden_state), v=fn(self.v))


def mix(weights: MixWeights, q: chex.Array) -> chex.Array:
    """Q_tot from per-agent values ``q`` f32[..., n] (the Q_i of one joint action).

    The leading axes of ``q`` broadcast against those of the weights, e.g. weights ``[B, T]`` and
    ``q`` ``[C, B, T, n]`` for C candidate joint actions. Returns f32[broadcast leading axes].
    """
    if weights.kind == "vdn":
        return jnp.sum(q, axis=-1)
    if weights.kind in ("qplex", "qtran"):
        raise ValueError(f"mix: {weights.kind.upper()} needs the per-agent Q table and the actions; use mix_actions")
    hidden = jax.nn.elu(jnp.sum(q[..., :, None] * weights.w1, axis=-2) + weights.b1)  # [..., E]
    return jnp.sum(hidden * weights.w2, axis=-1) + weights.b2


def mix_actions(weights: MixWeights, q_table: chex.Array, actions: chex.Array, avail: chex.Array) -> chex.Array:
    """Q_tot of joint ``actions`` i32[..., n] from the per-agent Q table ``q_table`` f32[..., n, A] (any mixer).

    ``avail`` bool[..., n, A] gives QPLEX's ``V_i = max_{admissible a} Q_i`` (see the module docstring). QTRAN
    returns Q_jt(s, a), which does not read ``q_table``. Leading axes broadcast against the weights' as in ``mix``
    (e.g. candidates ``[C, B, T]``). Returns f32[broadcast leading axes].
    """
    if weights.kind == "qtran":
        return _qtran_joint_q(weights.qtran, actions)
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


def _action_rows(table: chex.Array, actions: chex.Array) -> chex.Array:
    """Σ_i table[i, a_i]: the first layer on the joint one-hot action. ``table`` f32[n, A, G], ``actions``
    i32[..., n] (negative = padding, read as action 0) -> f32[..., G]."""
    a = jnp.clip(actions, 0, table.shape[1] - 1)
    return jnp.sum(table[jnp.arange(table.shape[0]), a], axis=-2)


def _qtran_joint_q(qt: QTRANWeights, actions: chex.Array) -> chex.Array:
    hidden = jax.nn.relu(qt.hidden_state + _action_rows(qt.action_table, actions))
    return jax.nn.relu(hidden @ qt.w2 + qt.b2) @ qt.w3 + qt.b3


def qtran_value(weights: MixWeights) -> chex.Array:
    """QTRAN's V_jt(s) per row: f32[...]."""
    if weights.kind != "qtran":
        raise ValueError(f"qtran_value: the weights are of kind {weights.kind!r}, not 'qtran'")
    return weights.qtran.v


def qtran_penalties(weights: MixWeights, q_table: chex.Array, taken: chex.Array, greedy: chex.Array):
    """QTRAN's constraint errors per row (Son et al. 2019, QTRAN-base), with ``Q′ = Σ_i Q_i``:

        opt  = Q′(ā) − Q_jt(ā) + V_jt        at the greedy joint action ā     (loss: opt²)
        nopt = min(Q′(a) − Q_jt(a) + V_jt, 0) at the taken joint action a     (loss: nopt²)

    Q_jt is held fixed (stop-gradient), as in QTRAN: these terms train the per-agent Q_i and V_jt, the TD loss
    trains Q_jt. Args: ``q_table`` f32[..., n, A], ``taken``/``greedy`` i32[..., n]. Returns (opt, nopt) f32[...].
    """
    v = qtran_value(weights)
    q_jt = lambda a: jax.lax.stop_gradient(mix_actions(weights, q_table, a, None))  # noqa: E731
    opt = jnp.sum(gather_q(q_table, greedy), axis=-1) - q_jt(greedy) + v
    nopt = jnp.minimum(jnp.sum(gather_q(q_table, taken), axis=-1) - q_jt(taken) + v, 0.0)
    return opt, nopt


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
        if cfg.kind in ATPG_KINDS:
            if inputs is None:
                raise ValueError(f"Mixer: kind {cfg.kind!r} needs the NetInputs of the rows (got None)")
            if state.shape[:-1] != inputs.t.shape:
                raise ValueError(
                    f"Mixer: state leading shape {state.shape[:-1]} must equal the inputs' [..., T] = {inputs.t.shape}"
                )
            atpg_out = ATPG(cfg.atpg, name="atpg")(inputs)
        if cfg.family in ("qplex", "qtran"):
            cond = state
            if atpg_out is not None:  # c_t = [s_t, ê_t^1, …, ê_t^n]
                e_hat = atpg_out.e_hat
                cond = jnp.concatenate([state, e_hat.reshape(e_hat.shape[:-2] + (-1,))], axis=-1)
            if cfg.family == "qplex":
                return MixWeights(None, None, None, None, kind="qplex", qplex=self._qplex(cond)), atpg_out
            return MixWeights(None, None, None, None, kind="qtran", qtran=self._qtran(cond)), atpg_out
        if cfg.kind == "atpg_qmix":
            e_hat = atpg_out.e_hat  # [..., n, d]
            s_per_agent = jnp.broadcast_to(state[..., None, :], e_hat.shape[:-1] + (state.shape[-1],))
            w1 = jnp.abs(HyperMLP(hid, emb, name="f_w1")(jnp.concatenate([s_per_agent, e_hat], axis=-1)))
            b1 = HyperMLP(hid, emb, name="f_b1")(jnp.concatenate([state, jnp.mean(e_hat, axis=-2)], axis=-1))
        else:  # 'qmix'
            w1 = jnp.abs(HyperMLP(hid, n * emb, name="f_w1")(state)).reshape(state.shape[:-1] + (n, emb))
            b1 = HyperMLP(hid, emb, name="f_b1")(state)
        w2 = jnp.abs(HyperMLP(hid, emb, name="f_w2")(state))
        b2 = HyperMLP(hid, 1, name="f_v")(state)[..., 0]
        return MixWeights(w1=w1, b1=b1, w2=w2, b2=b2, kind="qmix"), atpg_out

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


    def _qtran(self, cond):
        cfg = self.config
        n, hid, a = cfg.num_agents, cfg.hyper_hidden, cfg.num_actions
        init = nn.initializers.lecun_normal()
        hidden_state = nn.Dense(hid, name="q_state")(cond)
        # the one-hot-action rows of Q_jt's first layer, initialised as one Dense over [onehot(a_1), …, onehot(a_n)]
        action_table = self.param("q_actions", lambda key_, shape: init(key_, (n * a, hid)).reshape(shape), (n, a, hid))
        w2 = self.param("q_hidden_w", init, (hid, hid))
        b2 = self.param("q_hidden_b", nn.initializers.zeros_init(), (hid,))
        w3 = self.param("q_out_w", lambda key_, shape: init(key_, (hid, 1))[:, 0], (hid,))
        b3 = self.param("q_out_b", nn.initializers.zeros_init(), ())
        v = HyperMLP(hid, 1, name="v")(cond)[..., 0]
        return QTRANWeights(hidden_state=hidden_state, action_table=action_table, w2=w2, b2=b2, w3=w3, b3=b3, v=v)


@functools.partial(jax.jit, static_argnums=0)
def init_mixer_params(config: MixerConfig, key: chex.PRNGKey):
    """Parameters of ``Mixer(config)`` (jitted init on one dummy row, compiled once per config;
    ``{}`` for 'vdn')."""
    state = jnp.zeros((1, config.state_dim), jnp.float32)
    obs_dim = config.atpg.obs_dim if config.atpg is not None else 1
    inputs = dummy_inputs(config.num_agents, obs_dim) if config.kind in ATPG_KINDS else None
    return Mixer(config).init(key, state, inputs)


def take_rows(tree: Any, rows: chex.Array, batch_ndim: int = 0) -> Any:
    """Gather rows of per-row arrays (MixWeights, Q values, hidden states, …).

    Leaves are ``[*batch, T, *rest]`` with ``batch_ndim`` leading batch axes; ``rows`` is
    i32[*batch, *idx]. Returns leaves ``[*batch, *idx, *rest]``, e.g. weights ``[B, T, ...]`` at
    segment starts ``rows [B, n, K]`` -> ``[B, n, K, ...]`` (``batch_ndim=1``). ``MixWeights`` gather their per-row
    leaves only (``MixWeights.map_rows``).
    """

    def one(x, r):
        return jnp.take(x, r, axis=0)

    fn = lambda x: _vmap_n(one, batch_ndim)(x, rows)
    if isinstance(tree, MixWeights):  # gather the per-row leaves only
        return tree.map_rows(fn)
    return jax.tree_util.tree_map(fn, tree)


def _vmap_n(fn, k):
    for _ in range(k):
        fn = jax.vmap(fn)
    return fn
