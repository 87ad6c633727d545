"""What the ToMacVF networks read at one primitive step, and builders from slots and timesteps.

Both the temporal agent network (D2) and ATPG (D4) read, for every agent at row ``t`` (what the
agents saw before step ``t``; row 0 is the reset), the observation at ``t`` and the macro-action
*in force before the decision at t* (the one executed during step ``t-1``) with its progress::

    obs       f32[..., T, n, O]   ô_t (padded to O; obs_real by default, D1)
    t         i32[..., T]         absolute time of the row (PE(t))
    prev_t    i32[..., T]         time of the previous action's step (PE(t-1)); t-1 on a full episode
    prev_mac  i32[..., T, n]      m_{t-1}; -1 where there is none (t = 0): its whole block is zeroed
    prev_t_m  i32[..., T, n]      t_m(t-1), the progress of m_{t-1} during step t-1
    reset     bool[..., T]        episode start: the GRU carry is zeroed before this row

For the single-step apply used by the rollout the same struct is used without the ``T`` axis.
``prev_t`` is separate from ``t`` so that squeezed sequences (Mac-JERT, D16) can pass the true times
of their kept steps.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

from jaxmac.buffer import views
from jaxmac.buffer.episode import EpisodeSlot


@struct.dataclass
class NetInputs:
    """Per-row network inputs (see the module docstring for shapes)."""

    obs: chex.Array  # f32[..., T, n, O]
    t: chex.Array  # i32[..., T]
    prev_t: chex.Array  # i32[..., T]
    prev_mac: chex.Array  # i32[..., T, n]
    prev_t_m: chex.Array  # i32[..., T, n]
    reset: chex.Array  # bool[..., T]

    def add_time_axis(self) -> NetInputs:
        """Step inputs (no T axis) -> a length-1 sequence."""
        return NetInputs(
            obs=self.obs[..., None, :, :], t=self.t[..., None], prev_t=self.prev_t[..., None],
            prev_mac=self.prev_mac[..., None, :], prev_t_m=self.prev_t_m[..., None, :],
            reset=self.reset[..., None],
        )


def slot_inputs(slot: EpisodeSlot, which: str = "real") -> tuple[NetInputs, chex.Array]:
    """Inputs for every row ``0..H`` of an episode slot, and the progress τ to value at each row.

    Args:
      slot: an ``EpisodeSlot`` with any number of leading batch axes (leaves ``[..., H, ...]``).
      which: 'real' (``obs_real``, ToMacVF, D1) or 'macro' (frozen ``obs_macro``).
    Returns:
      inputs: ``NetInputs`` with ``T = H + 1`` rows (``reset`` only at row 0).
      tau: i32[..., H+1, n], progress of the macro-action each agent executes from row r on:
        0 where the agent is free at r (r = 0 or ``mac_done[r-1]``), else ``t_m[r-1] + 1``.
        Equals ``slot.t_m[r]`` on valid steps, and ``MicroView.boot_t_m`` / ``MacroView.boot_t_m``
        at bootstrap rows (row ``H`` included), so one head evaluation per row serves the chosen
        action, the double-Q argmax of free agents (τ = 0) and the pinned busy agents (D9, D10).
    """
    if which not in ("real", "macro"):
        raise ValueError(f"slot_inputs: which={which!r}; valid choices: ['macro', 'real']")
    obs = slot.decode_obs(which)  # [..., H+1, n, O]
    batch = slot.reward.shape[:-1]
    h, n = slot.mac.shape[-2:]
    t = jnp.broadcast_to(jnp.arange(h + 1, dtype=jnp.int32), batch + (h + 1,))
    first = lambda fill: jnp.full(batch + (1, n), fill, jnp.int32)
    prev_mac = jnp.concatenate([first(-1), slot.mac], axis=-2)
    prev_t_m = jnp.concatenate([first(0), slot.t_m], axis=-2)
    tau = jnp.concatenate([first(0), jnp.where(slot.mac_done, 0, slot.t_m + 1)], axis=-2)
    inputs = NetInputs(obs=obs, t=t, prev_t=t - 1, prev_mac=prev_mac, prev_t_m=prev_t_m, reset=t == 0)
    return inputs, tau.astype(jnp.int32)


def jert_inputs(slot: EpisodeSlot, jert) -> tuple[NetInputs, chex.Array]:
    """Inputs of the squeezed Mac-JERT sequence (D16): one entry per kept step of a ``JertView``.

    Entry ``k`` is the decision row ``jert.start[k]`` (frozen ``obs_macro``, true time ``jert.t``);
    its previous macro-action is the one executed during step ``start[k] - 1`` (= the previous kept
    step), with that step's true time and progress. ``reset`` only at entry 0; padded entries
    (``jert.mask`` False) come after the real ones and carry no previous action.

    Args:
      slot: the ``EpisodeSlot`` the view was computed from (any leading batch axes).
      jert: ``views.jert_view(slot)`` (leaves ``[..., H, ...]``).
    Returns:
      inputs: ``NetInputs`` with ``T = H`` entries.
      tau: i32[..., H, n] progress at each decision row (``jert.t_m``; 0 for free agents).
    """

    def one(mac, t_m, start, mask):
        has_prev = jnp.logical_and(start >= 1, mask)
        idx = jnp.maximum(start - 1, 0)
        prev_mac = jnp.where(has_prev[:, None], mac[idx], -1)
        prev_t_m = jnp.where(has_prev[:, None], t_m[idx], 0)
        return prev_mac, prev_t_m

    fn = one
    for _ in range(slot.reward.ndim - 1):
        fn = jax.vmap(fn)
    prev_mac, prev_t_m = fn(slot.mac, slot.t_m, jert.start, jert.mask)
    h = jert.t.shape[-1]
    reset = jnp.broadcast_to(jnp.arange(h) == 0, jert.t.shape)
    inputs = NetInputs(obs=jert.obs.astype(jnp.float32), t=jert.t.astype(jnp.int32), prev_t=jert.t - 1,
                       prev_mac=prev_mac.astype(jnp.int32), prev_t_m=prev_t_m.astype(jnp.int32), reset=reset)
    return inputs, jert.t_m.astype(jnp.int32)


def jert_sequence(batch: EpisodeSlot):
    """The squeezed Mac-JERT sequence (D16) plus its bootstrap row, for a batch of slots.

    Entries ``0..c-1`` are the ``c`` real joint decision rows (``jert_inputs``); entry ``c``
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


def timestep_inputs(ts) -> NetInputs:
    """Step inputs (no T axis) from an ``envs_jax.TimeStep`` (any leading batch axes, e.g. ``[E]``).

    ``ts.mac``/``ts.t_m`` are the macro-action executed during the step that produced ``ts`` and its
    progress, i.e. ``m_{t-1}``/``t_m(t-1)`` for the row ``t = ts.t``; at a reset ``ts.t == 0`` (the
    GRU carry is zeroed) and ``ts.mac == -1``. Uses ``obs_real`` (D1). When acting, value the
    free agents' choices with τ = 0 (D17).
    """
    t = jnp.asarray(ts.t, jnp.int32)
    return NetInputs(
        obs=jnp.asarray(ts.obs_real, jnp.float32), t=t, prev_t=t - 1,
        prev_mac=jnp.asarray(ts.mac, jnp.int32), prev_t_m=jnp.asarray(ts.t_m, jnp.int32), reset=t == 0,
    )


def validate_inputs(inputs: NetInputs, num_agents: int, obs_dim: int, where: str) -> None:
    """Shape check of sequence inputs (``T`` axis present), raising ValueError naming the field."""
    lead = inputs.t.shape  # [..., T]
    want = {
        "obs": lead + (num_agents, obs_dim), "t": lead, "prev_t": lead, "prev_mac": lead + (num_agents,),
        "prev_t_m": lead + (num_agents,), "reset": lead,
    }
    if len(lead) < 1:
        raise ValueError(f"{where}: inputs.t has shape {lead}; expected [..., T] (use step() for one step)")
    for name, shape in want.items():
        got = tuple(getattr(inputs, name).shape)
        if got != shape:
            raise ValueError(
                f"{where}: inputs.{name} has shape {got}, expected {shape} "
                f"(leading [..., T] = {lead}, n = {num_agents}, O = {obs_dim})"
            )
