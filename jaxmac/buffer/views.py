"""Training views of episode slots: Mac-SJERT micro/macro transitions, Mac-JERT and Mac-CERT.

Every view is computed on device from one ``EpisodeSlot`` (leaves ``[H, ...]``) or from a
batch of them (leaves ``[B, H, ...]``, any number of leading batch axes: the view is
vmapped automatically). Outputs are plain fixed-shape arrays with a ``mask``; a loss takes
``sum(mask * δ²) / max(1, sum(mask))`` without any Python-side bookkeeping. Shapes below are
per episode; batched calls prepend ``[B]``. ``n`` agents, ``H`` steps, ``K`` = ``k_max``,
``O``/``A``/``S`` padded obs/action/state widths.

Row indices (``boot_row``, ``start``, …) index the slot's ``[H+1]`` row arrays
(``slot.decode_obs()``, ``slot.decode_state()``, ``slot.avail``, or the outputs of a network
run over all rows); step indices index its ``[H]`` step arrays. All discounts already include
the termination mask: ``target = reward + discount · bootstrap_value``.

* ``micro_view(slot, n_step)``: every valid primitive step, n-step returns (DECISIONS D11),
  bootstrapping at truncation and at the slot end but not after termination
  (``time_limit_as_termination(slot)``: not after truncation either).
* ``macro_view(slot)``: one row per complete segment of the segment table (D7, D10).
* ``jert_view(slot)``: Mac-JERT, the steps where any agent's macro-action ended, left-packed.
* ``cert_view(slot)``: Mac-CERT, per agent the steps where its macro-action ended.

Mac-JERT/CERT reproduce MacroMARL's per-step running accumulators (docs/baselines.md §1.0, §2):
a kept step's reward is ``Σ_{k<τ} γ^k r`` since the previous kept step, ``τ`` is the number of
primitive steps since then, and the observations are the frozen ``obs_macro`` rows. As in the
original, a step is kept only where ``mac_done`` is set (a terminal step where no
macro-action reports termination is not kept; incomplete segments at truncation are dropped).
"""

from __future__ import annotations

import functools

import chex
import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.validation import is_integer
from jaxmac.buffer import segments as seg
from jaxmac.buffer.episode import EpisodeSlot, agent_accumulator


def _auto_batch(view):
    """Vmap ``view`` over every leading axis of the slot beyond the single-episode rank."""

    @functools.wraps(view)
    def wrapper(slot: EpisodeSlot, *args, **kwargs):
        if not isinstance(slot, EpisodeSlot):
            raise ValueError(f"{view.__name__}: expected an EpisodeSlot, got {type(slot).__name__}")
        fn = lambda s: view(s, *args, **kwargs)
        for _ in range(slot.reward.ndim - 1):
            fn = jax.vmap(fn)
        return fn(slot)

    return wrapper


def _pinned_next(slot: EpisodeSlot, last: chex.Array):
    """Who is free after step(s) ``last`` and what busy agents keep doing (DECISIONS D9).

    Returns ``free`` bool[..., n], ``mac`` i32[..., n] (the running macro-action, the pinned
    choice of a busy agent) and ``t_m`` i32[..., n] (its progress at the next step; 0 if free).
    """
    free = slot.mac_done[last]
    return free, slot.mac[last], jnp.where(free, 0, slot.t_m[last] + 1)


# ----------------------------------------------------------------------------------------
# Mac-SJERT: micro transitions


@struct.dataclass
class MicroView:
    """Per primitive step t (shapes per episode)."""

    mask: chex.Array  # bool[H] valid step
    mac: chex.Array  # i32[H, n] executing macro-action (the Q_i(ĥ_t, m_t, t_m) being trained)
    t_m: chex.Array  # i32[H, n] its progress
    reward: chex.Array  # f32[H] r_t
    free_next: chex.Array  # bool[H, n] agents choosing at row t+1 (mac_done[t])
    ret: chex.Array  # f32[H] Σ_{k<m} γ^k r_{t+k}, m = n_steps[t]
    n_steps: chex.Array  # i32[H] m = min(n, length - t)
    boot_row: chex.Array  # i32[H] t + m
    boot_discount: chex.Array  # f32[H] γ^m, 0 if the episode terminated within the m steps
    boot_free: chex.Array  # bool[H, n] free agents at boot_row (argmax over their actions)
    boot_mac: chex.Array  # i32[H, n] pinned macro-action of busy agents at boot_row
    boot_t_m: chex.Array  # i32[H, n] progress at boot_row (0 where free)
    boot_avail: chex.Array  # bool[H, n, A] available actions at boot_row


@_auto_batch
def micro_view(slot: EpisodeSlot, n_step: int = 1) -> MicroView:
    """Every valid primitive step with its n-step target ingredients (DECISIONS D11)."""
    if not is_integer(n_step) or n_step < 1:
        raise ValueError(f"micro_view: n_step={n_step!r} must be a positive integer (1 = one-step TD)")
    cfg = slot.config
    h = cfg.horizon
    t = jnp.arange(h)
    mask = slot.valid
    m = jnp.clip(jnp.minimum(n_step, slot.length - t), 1, n_step)  # steps summed, ≥ 1
    k = jnp.arange(n_step)
    window = t[:, None] + k[None, :]  # [H, n_step]
    r_pad = jnp.concatenate([slot.reward, jnp.zeros((n_step,), jnp.float32)])
    weights = jnp.where(k[None, :] < m[:, None], seg.discount_powers(cfg.discount, k)[None, :], 0.0)
    ret = jnp.sum(weights * r_pad[window], axis=1)
    last = t + m - 1  # last summed step (≤ length - 1 on valid steps)
    boot_row = t + m
    discount = jnp.where(slot.terminated[last], 0.0, seg.discount_powers(cfg.discount, m))
    free, pinned, t_m_next = _pinned_next(slot, last)
    z = lambda x: jnp.where(mask.reshape((-1,) + (1,) * (x.ndim - 1)), x, jnp.zeros((), x.dtype))
    return MicroView(
        mask=mask, mac=slot.mac, t_m=slot.t_m, reward=slot.reward, free_next=slot.mac_done,
        ret=z(ret), n_steps=z(m), boot_row=z(boot_row), boot_discount=z(discount),
        boot_free=z(free), boot_mac=z(pinned), boot_t_m=z(t_m_next), boot_avail=z(slot.avail[boot_row]),
    )


def time_limit_as_termination(slot: EpisodeSlot) -> EpisodeSlot:
    """``slot`` (any batch shape) with a time-limit truncation flagged as termination, so that every view's target
    at the last step of a truncated episode is its reward alone (no bootstrap). Right for a learner that sees the
    absolute time step (the limit is then part of its MDP); the views' default bootstraps there (DECISIONS D10).
    The segment table is kept: a macro-action cut by the time limit still gives no macro transition, one that ends
    on the last step gives a terminal one."""
    return slot.replace(terminated=jnp.logical_or(slot.terminated, slot.truncated))


# ----------------------------------------------------------------------------------------
# Mac-SJERT: macro transitions (one per complete segment)


@struct.dataclass
class MacroView:
    """Per agent i and segment-table row k (shapes per episode)."""

    mask: chex.Array  # bool[n, K] complete segment
    agent: chex.Array  # i32[n, K] i
    mac: chex.Array  # i32[n, K] the segment's macro-action
    start: chex.Array  # i32[n, K] first step = row of s, ô at which Q_tot is evaluated
    end: chex.Array  # i32[n, K] last step
    duration: chex.Array  # i32[n, K] τ
    reward: chex.Array  # f32[n, K] R_m
    boot_row: chex.Array  # i32[n, K] end + 1
    discount: chex.Array  # f32[n, K] γ^τ, 0 if the segment ended with termination
    start_mac: chex.Array  # i32[n, K, n] joint macro-action executed at the start step
    start_t_m: chex.Array  # i32[n, K, n] joint progress at the start step (0 for agent i)
    boot_free: chex.Array  # bool[n, K, n] free agents at boot_row
    boot_mac: chex.Array  # i32[n, K, n] pinned macro-actions of busy agents at boot_row
    boot_t_m: chex.Array  # i32[n, K, n] progress at boot_row (0 where free)
    boot_avail: chex.Array  # bool[n, K, n, A] available actions at boot_row


@_auto_batch
def macro_view(slot: EpisodeSlot) -> MacroView:
    """The segment table as macro transitions (DECISIONS D10)."""
    cfg = slot.config
    s = slot.segments
    mask = s.valid
    terminal = slot.terminated[s.end]
    discount = jnp.where(terminal, 0.0, seg.discount_powers(cfg.discount, s.duration))
    free, pinned, t_m_next = _pinned_next(slot, s.end)
    z = lambda x: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 2)), x, jnp.zeros((), x.dtype))
    agent = jnp.broadcast_to(jnp.arange(cfg.num_agents, dtype=jnp.int32)[:, None], mask.shape)
    return MacroView(
        mask=mask, agent=agent, mac=s.mac, start=s.start, end=s.end, duration=s.duration,
        reward=s.R_m, boot_row=z(s.end + 1), discount=z(discount),
        start_mac=z(slot.mac[s.start]), start_t_m=z(slot.t_m[s.start]),
        boot_free=z(free), boot_mac=z(pinned), boot_t_m=z(t_m_next), boot_avail=z(slot.avail[s.end + 1]),
    )


# ----------------------------------------------------------------------------------------
# Mac-JERT (joint, squeezed by any termination)


@struct.dataclass
class JertView:
    """Joint macro transitions at the kept steps, left-packed to H entries (shapes per episode)."""

    mask: chex.Array  # bool[H] real entry (a prefix)
    step: chex.Array  # i32[H] kept step (some agent's macro-action ended there)
    start: chex.Array  # i32[H] first step since the previous kept step = decision row
    tau: chex.Array  # i32[H] τ^J = step - start + 1
    reward: chex.Array  # f32[H] R^J = Σ_{k<τ} γ^k r_{start+k}
    discount: chex.Array  # f32[H] γ^τ, 0 at termination
    terminal: chex.Array  # bool[H]
    mac: chex.Array  # i32[H, n] joint macro-action m^J
    free_next: chex.Array  # bool[H, n] agents whose macro-action ended ("valid" of the original)
    next_mac: chex.Array  # i32[H, n] pinned macro-actions of the busy agents at the next decision
    t: chex.Array  # i32[H] true time of the decision row (for PE(t))
    t_m: chex.Array  # i32[H, n] true progress at the decision row (for PE(t_m))
    next_t_m: chex.Array  # i32[H, n] progress at the next decision row (0 where free)
    obs: chex.Array  # f32[H, n, O] frozen joint macro-observation at the decision row
    obs_next: chex.Array  # f32[H, n, O] the one after the kept step
    state: chex.Array  # f32[H, S] global state at the decision row
    state_next: chex.Array  # f32[H, S]
    macro_state: chex.Array  # f32[H, n, S] per agent, the state at the row where it chose its running action
    macro_state_next: chex.Array  # f32[H, n, S] the same at the next decision row
    avail: chex.Array  # bool[H, n, A]
    avail_next: chex.Array  # bool[H, n, A]


@_auto_batch
def jert_view(slot: EpisodeSlot) -> JertView:
    """Mac-JERT: MacroMARL's ``any(mac_done)`` squeeze with its joint running accumulator."""
    cfg = slot.config
    t_j = jnp.min(slot.t_m, axis=1)  # steps since the last joint decision = min_i t_m
    kept = jnp.logical_and(slot.valid, jnp.any(slot.mac_done, axis=1))
    step, mask = seg.pack(kept, cfg.horizon)
    acc = seg.running_sum(seg.discount_powers(cfg.discount, t_j) * slot.reward, t_j == 0)
    start = step - t_j[step]
    tau = t_j[step] + 1
    terminal = slot.terminated[step]
    free, pinned, t_m_next = _pinned_next(slot, step)
    obs = slot.decode_obs("macro")
    state = slot.decode_state()
    z = lambda x: jnp.where(mask.reshape((-1,) + (1,) * (x.ndim - 1)), x, jnp.zeros((), x.dtype))
    return JertView(
        mask=mask, step=z(step), start=z(start), tau=z(tau), reward=z(acc[step]),
        discount=z(jnp.where(terminal, 0.0, seg.discount_powers(cfg.discount, tau))), terminal=z(terminal),
        mac=z(slot.mac[step]), free_next=z(free), next_mac=z(pinned), t=z(start),
        t_m=z(slot.t_m[start]), next_t_m=z(t_m_next), obs=z(obs[start]), obs_next=z(obs[step + 1]),
        state=z(state[start]), state_next=z(state[step + 1]),
        macro_state=z(state[start[:, None] - slot.t_m[start]]),  # agent i chose at row start − t_m[start, i]
        macro_state_next=z(state[step[:, None] + 1 - t_m_next]), avail=z(slot.avail[start]),
        avail_next=z(slot.avail[step + 1]),
    )


# ----------------------------------------------------------------------------------------
# Mac-CERT (per agent, squeezed by the agent's own terminations)


@struct.dataclass
class CertView:
    """Per agent i, its macro transitions left-packed to K entries (shapes per episode)."""

    mask: chex.Array  # bool[n, K]
    step: chex.Array  # i32[n, K] step where agent i's macro-action ended
    start: chex.Array  # i32[n, K] its first step
    tau: chex.Array  # i32[n, K] τ_i
    reward: chex.Array  # f32[n, K] R_i = Σ_{k<τ_i} γ^k r_{start+k}
    discount: chex.Array  # f32[n, K] γ^τ_i, 0 at termination
    terminal: chex.Array  # bool[n, K]
    mac: chex.Array  # i32[n, K]
    t: chex.Array  # i32[n, K] true time of the decision row (= start)
    obs: chex.Array  # f32[n, K, O] agent i's frozen macro-observation at its decision row
    obs_next: chex.Array  # f32[n, K, O] the one after its macro-action ended
    avail_next: chex.Array  # bool[n, K, A] its available actions then


@_auto_batch
def cert_view(slot: EpisodeSlot) -> CertView:
    """Mac-CERT: per-agent ``mac_done`` squeeze with the per-agent running accumulator."""
    cfg = slot.config
    acc = agent_accumulator(cfg.discount, slot.reward, slot.t_m)  # [H, n]
    kept = jnp.logical_and(slot.valid[:, None], slot.mac_done)  # [H, n]
    obs = slot.decode_obs("macro")

    def per_agent(i, kept_i, t_m_i, acc_i, mac_i):
        step, mask = seg.pack(kept_i, cfg.k_max)
        tau = t_m_i[step] + 1
        start = step - tau + 1
        terminal = slot.terminated[step]
        z = lambda x: jnp.where(mask.reshape((-1,) + (1,) * (x.ndim - 1)), x, jnp.zeros((), x.dtype))
        return CertView(
            mask=mask, step=z(step), start=z(start), tau=z(tau), reward=z(acc_i[step]),
            discount=z(jnp.where(terminal, 0.0, seg.discount_powers(cfg.discount, tau))),
            terminal=z(terminal), mac=jnp.where(mask, mac_i[step], -1), t=z(start),
            obs=z(obs[start, i]), obs_next=z(obs[step + 1, i]), avail_next=z(slot.avail[step + 1, i]),
        )

    return jax.vmap(per_agent, in_axes=(0, 1, 1, 1, 1))(
        jnp.arange(cfg.num_agents), kept, slot.t_m, acc, slot.mac
    )


def cert_to_jert_index(cert_step: chex.Array, cert_mask: chex.Array, jert_step: chex.Array,
                       jert_mask: chex.Array) -> chex.Array:
    """For every Mac-CERT entry, the position of the Mac-JERT entry at the same step (an agent's termination is
    always a joint decision point), in views cropped to the same windows (Mac-Dec-MADDRQN's ``id_v`` alignment).

    Args:
      cert_step, cert_mask: [B, n, L] agent entries; jert_step, jert_mask: [B, Lj] joint entries.
    Returns:
      i32[B, n, L] joint entry index (0 where ``cert_mask`` is False).
    """
    before = jert_mask[:, None, None, :] & (jert_step[:, None, None, :] < cert_step[..., None])
    return jnp.where(cert_mask, before.sum(-1), 0).astype(jnp.int32)
