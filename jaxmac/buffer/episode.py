"""The episode slot of the Mac-SJERT ring (DECISIONS D0) and the writer that fills it.

One slot holds one episode of at most ``H`` primitive steps of ``n`` agents, in fixed
shapes (padded obs width ``O``, action count ``A``, state width ``S``, segment table
length ``K``). Steps are indexed ``t = 0 .. H-1``; *rows* ``r = 0 .. H`` are what the agents
saw before step ``r`` (row 0: the reset, row ``t+1``: the outcome of step ``t``)::

    rows   [H+1]  state[S]  obs_real[n,O]  obs_macro[n,O]  avail[n,A]
    steps  [H]    mac[n]  mac_done[n]  t_m[n]  reward  terminated  truncated  valid
    segments      per agent, K rows ordered by termination (the paper's D^i):
                  start  end  duration  mac  R_m  valid        [n, K]; count [n]

Step ``t`` is valid iff no step before it terminated or truncated. Invalid steps and rows
are zeroed (``mac = -1``) so that padding never leaks into sums; masks must still be used.

A segment of agent ``i`` is one executed macro-action: steps ``start .. end`` with
``start = end - t_m[end, i]``, ``duration = t_m[end, i] + 1`` and
``R_m = Σ_{k<duration} γ^k reward[start + k]`` (DECISIONS D10). A segment is *complete* (a
valid macro transition) when it ends with ``mac_done`` or, by default, with the episode's
termination (``close_on_terminal``: the macro-action's value then has no future term).
A segment cut by truncation or by the end of the slot is not complete and not stored.

Observations are stored compactly by an ``ObsCodec`` (see ``SlotConfig.from_spec`` for the
per-domain defaults); ``decode_obs`` turns them back into float32.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import chex
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax.validation import is_integer
from jaxmac.buffer import segments as seg

_DTYPES = {
    "float32": jnp.float32,
    "float16": jnp.float16,
    "bfloat16": jnp.bfloat16,
    "uint8": jnp.uint8,
    "bool": jnp.bool_,
}

# Per-domain observation storage, keyed by the env-name prefix (``spec.name.split("-")[0]``).
#   boxpushing: 5 binary features               -> uint8, exact
#   warehouse:  one-hots and small counts (<256) -> uint8, exact
#   overcooked: x/7, y/7 positions and chop/3     -> uint8 holding round(21·x) (21 = lcm(7, 3)),
#               decoded as q·(1/21) in float32: within 1 ulp (≤ 6e-8) of the env's values, which
#               are themselves k·(1/7) as XLA compiles them, not the correctly rounded k/7
# The global state stays float32 everywhere (Box Pushing and Warehouse states hold
# fractions such as 1.5/14 and negative flags).
DEFAULT_OBS_STORAGE: dict[str, tuple[str, float]] = {
    "boxpushing": ("uint8", 1.0),
    "warehouse": ("uint8", 1.0),
    "overcooked": ("uint8", 21.0),
}


@dataclasses.dataclass(frozen=True)
class ObsCodec:
    """How float observations are stored.

    ``dtype`` is one of float32, float16, bfloat16, uint8, bool. ``uint8`` stores
    ``round(x * scale)`` (values must be multiples of ``1/scale`` in ``[0, 255/scale]``; they
    come back within float32 rounding, exactly when ``scale`` is 1); ``bool`` stores
    ``x != 0`` (binary features only). ``roundtrip_error`` measures the loss on real data.
    """

    dtype: str = "float32"
    scale: float = 1.0

    def __post_init__(self):
        if self.dtype not in _DTYPES:
            raise ValueError(f"ObsCodec.dtype={self.dtype!r}; valid choices: {sorted(_DTYPES)}")
        if not (isinstance(self.scale, (int, float)) and self.scale > 0):
            raise ValueError(f"ObsCodec.scale={self.scale!r} must be a positive number")
        if self.scale != 1.0 and self.dtype != "uint8":
            raise ValueError(f"ObsCodec.scale={self.scale!r} is only meaningful with dtype 'uint8', got {self.dtype!r}")

    def encode(self, x: chex.Array) -> chex.Array:
        if self.dtype == "uint8":
            return jnp.clip(jnp.round(x * self.scale), 0, 255).astype(jnp.uint8)
        if self.dtype == "bool":
            return x != 0
        return x.astype(_DTYPES[self.dtype])

    def decode(self, x: chex.Array) -> chex.Array:
        x = x.astype(jnp.float32)
        # an explicit reciprocal multiply: what XLA would turn a division into anyway
        return x * jnp.float32(1.0 / self.scale) if self.scale != 1.0 else x

    def roundtrip_error(self, x: Any) -> float:
        """Host-side: max |decode(encode(x)) - x| over concrete values ``x`` (0.0 = lossless)."""
        x = jnp.asarray(np.asarray(x, np.float32))
        return float(jnp.max(jnp.abs(self.decode(self.encode(x)) - x), initial=0.0))


@dataclasses.dataclass(frozen=True)
class SlotConfig:
    """Static shapes and storage of an episode slot (hashable; closed over by ``jit``).

    Attributes:
      horizon: H, primitive steps per slot (the rollout length).
      num_agents: n.
      obs_dim: O, padded observation width.
      num_actions: A, padded macro-action count (width of ``avail``).
      state_dim: S, global state width.
      discount: γ used for ``R_m`` and by the views.
      k_max: K, segment-table rows per agent (``None`` → H, always enough).
      obs: observation storage codec.
      state_dtype: storage dtype of the global state (a float dtype).
      close_on_terminal: termination completes every running segment (see module doc).
    """

    horizon: int
    num_agents: int
    obs_dim: int
    num_actions: int
    state_dim: int
    discount: float
    k_max: int | None = None
    obs: ObsCodec = ObsCodec()
    state_dtype: str = "float32"
    close_on_terminal: bool = True

    def __post_init__(self):
        for name in ("horizon", "num_agents", "obs_dim", "num_actions", "state_dim"):
            v = getattr(self, name)
            if not is_integer(v) or v < 1:
                raise ValueError(f"SlotConfig.{name}={v!r} must be a positive integer")
        if self.k_max is None:
            object.__setattr__(self, "k_max", int(self.horizon))
        if not isinstance(self.k_max, (int, np.integer)) or not 1 <= self.k_max <= self.horizon:
            raise ValueError(f"SlotConfig.k_max={self.k_max!r} must be an integer in [1, horizon={self.horizon}]")
        if not 0.0 < self.discount <= 1.0:
            raise ValueError(f"SlotConfig.discount={self.discount!r} must be in (0, 1]")
        if self.state_dtype not in ("float32", "float16", "bfloat16"):
            raise ValueError(
                f"SlotConfig.state_dtype={self.state_dtype!r}; valid choices: ['bfloat16', 'float16', 'float32']"
            )
        if not isinstance(self.obs, ObsCodec):
            raise ValueError(f"SlotConfig.obs must be an ObsCodec, got {self.obs!r}")

    @classmethod
    def from_spec(cls, spec: Any, **overrides: Any) -> SlotConfig:
        """Config for an ``envs_jax.EnvSpec``: its shapes, horizon and discount, and the
        domain's default observation storage (``DEFAULT_OBS_STORAGE``); ``overrides``
        replace any field (e.g. ``horizon=50``, ``obs=ObsCodec("float32")``)."""
        dtype, scale = DEFAULT_OBS_STORAGE.get(spec.name.split("-")[0], ("float32", 1.0))
        fields = dict(
            horizon=spec.horizon,
            num_agents=spec.num_agents,
            obs_dim=spec.obs_dim,
            num_actions=spec.max_actions,
            state_dim=spec.state_dim,
            discount=spec.discount,
            obs=ObsCodec(dtype, scale),
        )
        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(
                f"SlotConfig.from_spec: unknown override(s) {sorted(unknown)}; "
                f"valid: {[f.name for f in dataclasses.fields(cls)]}"
            )
        fields.update(overrides)
        return cls(**fields)


@struct.dataclass
class SegmentTable:
    """Per-agent completed segments, ordered by termination (row i = the paper's D^i).

    Invalid rows (``valid`` False) are zero with ``mac = -1``. Agents with more than K
    complete segments keep their first K (``count`` still says how many there were).
    """

    start: chex.Array  # i32[n, K] first step of the segment
    end: chex.Array  # i32[n, K] last step (its mac_done step)
    duration: chex.Array  # i32[n, K] end - start + 1 (τ)
    mac: chex.Array  # i32[n, K] the macro-action
    R_m: chex.Array  # f32[n, K] Σ_k γ^k reward[start + k]
    valid: chex.Array  # bool[n, K]
    count: chex.Array  # i32[n] complete segments in the episode (may exceed K)


@struct.dataclass
class EpisodeSlot:
    """One episode in fixed shapes; see the module docstring for the layout."""

    state: chex.Array  # [H+1, S] state_dtype
    obs_real: chex.Array  # [H+1, n, O] obs codec dtype
    obs_macro: chex.Array  # [H+1, n, O] obs codec dtype (frozen while a macro-action runs)
    avail: chex.Array  # bool[H+1, n, A] actions available to a free agent at that row
    mac: chex.Array  # i32[H, n] macro-action executed during step t (-1 if invalid)
    mac_done: chex.Array  # bool[H, n] it terminated at the end of step t
    t_m: chex.Array  # i32[H, n] its progress during step t (0 on its first step)
    reward: chex.Array  # f32[H]
    terminated: chex.Array  # bool[H]
    truncated: chex.Array  # bool[H]
    valid: chex.Array  # bool[H] a prefix: steps of the episode
    length: chex.Array  # i32[] number of valid steps
    segments: SegmentTable
    config: SlotConfig = struct.field(pytree_node=False)

    def decode_obs(self, which: str = "real") -> chex.Array:
        """float32 observations ``[..., H+1, n, O]``; ``which`` is 'real' or 'macro'."""
        if which not in ("real", "macro"):
            raise ValueError(f"decode_obs: which={which!r}; valid choices: ['macro', 'real']")
        return self.config.obs.decode(self.obs_real if which == "real" else self.obs_macro)

    def decode_state(self) -> chex.Array:
        """float32 global states ``[..., H+1, S]``."""
        return self.state.astype(jnp.float32)

    def prefix(self, rows: int) -> EpisodeSlot:
        """The slots (any leading batch axes) cut to their first ``rows`` steps (``rows + 1`` state rows) and
        ``min(K, rows)`` segments per agent, with ``config.horizon = rows``. Exact for every episode of length
        ≤ ``rows``: its valid steps, its bootstrap row and its completed segments (at most one per step, in order)
        all lie in the prefix, and what is cut is padding."""
        cfg = self.config
        if not isinstance(rows, int) or not 1 <= rows <= cfg.horizon:
            raise ValueError(f"EpisodeSlot.prefix: rows={rows!r} must be an integer in [1, horizon={cfg.horizon}]")
        lead = self.length.ndim  # batch axes
        k = min(cfg.k_max, rows)
        cut = lambda size, axis: lambda x: jax.lax.slice_in_dim(x, 0, size, axis=axis)  # noqa: E731
        steps, per_row, per_segment = cut(rows, lead), cut(rows + 1, lead), cut(k, lead + 1)
        return self.replace(
            state=per_row(self.state), obs_real=per_row(self.obs_real), obs_macro=per_row(self.obs_macro),
            avail=per_row(self.avail), mac=steps(self.mac), mac_done=steps(self.mac_done), t_m=steps(self.t_m),
            reward=steps(self.reward), terminated=steps(self.terminated), truncated=steps(self.truncated),
            valid=steps(self.valid),
            segments=self.segments.replace(**{name: per_segment(getattr(self.segments, name))
                                               for name in ("start", "end", "duration", "mac", "R_m", "valid")}),
            config=dataclasses.replace(cfg, horizon=rows, k_max=k))


def slot_nbytes(slot_or_config: EpisodeSlot | SlotConfig) -> int:
    """Bytes of one (unbatched) slot."""
    slot = slot_or_config if isinstance(slot_or_config, EpisodeSlot) else empty_slot(slot_or_config)
    return int(sum(x.size * x.dtype.itemsize for x in jax.tree_util.tree_leaves(slot)))


def empty_slot(config: SlotConfig) -> EpisodeSlot:
    """An all-invalid slot with the config's shapes (used to initialise a ring)."""
    h, n, o, a, s, k = (config.horizon, config.num_agents, config.obs_dim, config.num_actions,
                        config.state_dim, config.k_max)
    obs_dtype = _DTYPES[config.obs.dtype]
    zi = lambda *shape: jnp.zeros(shape, jnp.int32)
    zb = lambda *shape: jnp.zeros(shape, bool)
    return EpisodeSlot(
        state=jnp.zeros((h + 1, s), _DTYPES[config.state_dtype]),
        obs_real=jnp.zeros((h + 1, n, o), obs_dtype),
        obs_macro=jnp.zeros((h + 1, n, o), obs_dtype),
        avail=zb(h + 1, n, a),
        mac=jnp.full((h, n), -1, jnp.int32),
        mac_done=zb(h, n),
        t_m=zi(h, n),
        reward=jnp.zeros((h,), jnp.float32),
        terminated=zb(h),
        truncated=zb(h),
        valid=zb(h),
        length=jnp.zeros((), jnp.int32),
        segments=SegmentTable(
            start=zi(n, k), end=zi(n, k), duration=zi(n, k), mac=jnp.full((n, k), -1, jnp.int32),
            R_m=jnp.zeros((n, k), jnp.float32), valid=zb(n, k), count=zi(n),
        ),
        config=config,
    )


def _check_shapes(config: SlotConfig, reset_ts: Any, traj: Any) -> None:
    h, n, o, a, s = config.horizon, config.num_agents, config.obs_dim, config.num_actions, config.state_dim
    want_reset = {"obs_real": (n, o), "obs_macro": (n, o), "avail_actions": (n, a), "state": (s,)}
    want_traj = {
        "obs_real": (h, n, o), "obs_macro": (h, n, o), "avail_actions": (h, n, a), "state": (h, s),
        "mac": (h, n), "mac_done": (h, n), "t_m": (h, n), "reward": (h,), "terminated": (h,),
        "truncated": (h,),
    }
    for label, ts, want in (("reset timestep", reset_ts, want_reset), ("trajectory", traj, want_traj)):
        for name, shape in want.items():
            got = tuple(np.shape(getattr(ts, name)))
            if got != shape:
                raise ValueError(
                    f"write_episode: {label}.{name} has shape {got}, expected {shape} for "
                    f"SlotConfig(horizon={h}, num_agents={n}, obs_dim={o}, num_actions={a}, state_dim={s}); "
                    "pass one unbatched reset TimeStep and the H stacked TimeSteps of lax.scan "
                    "(vmap write_episode over a batch of envs)"
                )


def write_episode(config: SlotConfig, reset_ts: Any, traj: Any) -> EpisodeSlot:
    """Build a slot from a rollout, on device.

    Args:
      config: the slot's static configuration.
      reset_ts: the ``envs_jax.TimeStep`` returned by ``env.reset`` (unbatched leaves).
      traj: the ``H`` TimeSteps stacked by ``lax.scan`` over ``env.step`` without auto-reset
        (leaves ``[H, ...]``). Steps after the first terminated/truncated one are masked.
    Returns:
      The filled ``EpisodeSlot``. Vmap over a batch of rollouts to fill E slots at once.
    """
    _check_shapes(config, reset_ts, traj)
    done = jnp.logical_or(traj.terminated, traj.truncated)
    valid = (jnp.cumsum(done) - done) == 0  # no done strictly before t
    row_valid = jnp.concatenate([jnp.ones((1,), bool), valid])

    def rows(first, rest, fill=0):
        x = jnp.concatenate([first[None], rest], axis=0)
        m = row_valid.reshape((-1,) + (1,) * (x.ndim - 1))
        return jnp.where(m, x, jnp.asarray(fill, x.dtype))

    step_mask = valid[:, None]
    mac = jnp.where(step_mask, traj.mac, -1).astype(jnp.int32)
    mac_done = jnp.logical_and(traj.mac_done, step_mask)
    t_m = jnp.where(step_mask, traj.t_m, 0).astype(jnp.int32)
    reward = jnp.where(valid, traj.reward, 0.0).astype(jnp.float32)
    terminated = jnp.logical_and(traj.terminated, valid)
    truncated = jnp.logical_and(traj.truncated, valid)

    segments = _segment_table(config, mac, mac_done, t_m, reward, terminated, valid)
    return EpisodeSlot(
        state=rows(reset_ts.state, traj.state).astype(_DTYPES[config.state_dtype]),
        obs_real=config.obs.encode(rows(reset_ts.obs_real, traj.obs_real)),
        obs_macro=config.obs.encode(rows(reset_ts.obs_macro, traj.obs_macro)),
        avail=rows(reset_ts.avail_actions, traj.avail_actions, False).astype(bool),
        mac=mac,
        mac_done=mac_done,
        t_m=t_m,
        reward=reward,
        terminated=terminated,
        truncated=truncated,
        valid=valid,
        length=jnp.sum(valid, dtype=jnp.int32),
        segments=segments,
        config=config,
    )


def agent_accumulator(gamma: float, reward: chex.Array, t_m: chex.Array) -> chex.Array:
    """Per-agent running discounted reward of the current macro-action after each step.

    ``acc[t, i] = Σ_{k=0}^{t_m[t,i]} γ^k reward[t - t_m[t,i] + k]`` — MacroMARL's per-agent
    accumulator (reset when a new macro-action starts, ``+= γ^{t_m} r`` otherwise).

    Args: reward f32[H], t_m i32[H, n]. Returns f32[H, n].
    """
    x = seg.discount_powers(gamma, t_m) * reward[:, None]
    return seg.running_sum(x, t_m == 0)


def _segment_table(config, mac, mac_done, t_m, reward, terminated, valid) -> SegmentTable:
    ends = jnp.logical_and(valid[:, None], mac_done)  # [H, n]
    if config.close_on_terminal:
        ends = jnp.logical_or(ends, terminated[:, None])
    acc = agent_accumulator(config.discount, reward, t_m)  # [H, n]

    def per_agent(ends_i, t_m_i, mac_i, acc_i):
        end, ok = seg.pack(ends_i, config.k_max)
        duration = t_m_i[end] + 1
        zero = lambda x: jnp.where(ok, x, 0)
        return (zero(end - duration + 1), zero(end), zero(duration), jnp.where(ok, mac_i[end], -1),
                jnp.where(ok, acc_i[end], 0.0), ok, jnp.sum(ends_i, dtype=jnp.int32))

    start, end, duration, seg_mac, r_m, ok, count = jax.vmap(per_agent, in_axes=1)(ends, t_m, mac, acc)
    return SegmentTable(start=start, end=end, duration=duration, mac=seg_mac, R_m=r_m, valid=ok, count=count)
