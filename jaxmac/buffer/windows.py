"""Fixed-length windows of stored episodes: the originals' ``trace_len`` sampling (docs/baselines.md §1.1).

MacroMARL's value learners on Box Pushing store, per episode of ``T`` primitive steps, every window of
``L = trace_len`` consecutive step records, front-padded with ``L − 1`` empty records (so ``T + L − 1``
windows, each holding at least one real step; none crosses an episode), and sample windows uniformly.
Inside a window the records are squeezed (Mac-JERT: steps where any macro-action ended; Mac-CERT: steps where
agent i's ended) and the GRU starts from a zero state at the window's first kept step. Because the
original stores *running* accumulators per step, a kept step inside a window carries its whole macro
transition even when the macro-action began before the window.

The ring of such a learner stores, per episode, the squeezed views it trains on (``StoredViews``: the
Mac-JERT and/or Mac-CERT view of the whole episode, computed once when the episode is written, so every
transition is exact). A window is an episode plus its first step ``w0 ∈ [−(L−1), T−1]`` (steps
``w0 … w0+L−1``; those outside ``[0, T)`` are padding). ``sample_windows`` draws (episode, w0) uniformly over
all windows of the ring and gathers only the view entries whose kept step lies in the window (``crop``),
so a gradient step reads ``L`` entries per sample, not the whole episode. ``trace_len = 0`` samples whole
episodes (``w0 = 0``, ``L`` = all entries).
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.validation import is_integer
from jaxmac.buffer import ring as ring_lib
from jaxmac.buffer import views
from jaxmac.buffer.episode import EpisodeSlot


@struct.dataclass
class StoredViews:
    """What the ring of a Mac-JERT/Mac-CERT learner keeps per episode (leaves ``[...]`` per episode)."""

    length: chex.Array  # i32[] primitive steps of the episode
    jert: views.JertView | None  # leaves [H, ...], or None if the learner does not read it
    cert: views.CertView | None  # leaves [n, K, ...]


def store_views(jert: bool, cert: bool):
    """``slot -> StoredViews`` holding the requested views (the learner's ``Algorithm.store``)."""

    def store(slot: EpisodeSlot) -> StoredViews:
        return StoredViews(length=slot.length, jert=views.jert_view(slot) if jert else None,
                           cert=views.cert_view(slot) if cert else None)

    return store


@struct.dataclass
class WindowBatch:
    """``B`` windows: the view entries inside each (a prefix of real entries per row, ``mask`` set)."""

    jert: views.JertView | None  # leaves [B, L, ...]
    cert: views.CertView | None  # leaves [B, n, L, ...]


def sample_windows(ring: ring_lib.RingState, key: chex.PRNGKey, batch_size: int, length: int) -> WindowBatch:
    """``batch_size`` windows of ``length`` steps from a ring of ``StoredViews``, uniform over every window of every
    stored episode (an episode of ``T`` steps has ``T + length − 1``), with replacement; ``length = 0``: whole
    episodes, uniformly."""
    idx, first = draw_windows(ring, key, batch_size, length)
    return window_views(ring.slots, idx, first, length)


def draw_windows(ring: ring_lib.RingState, key: chex.PRNGKey, batch_size: int, length: int):
    """Which windows ``sample_windows`` takes: ring positions ``idx`` i32[B] and first steps i32[B]."""
    if not is_integer(length) or length < 0:
        raise ValueError(f"sample_windows: length={length!r} must be a non-negative integer (0 = whole episodes)")
    if length == 0:
        idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(ring.count, 1), dtype=jnp.int32)
        return idx, jnp.zeros((batch_size,), jnp.int32)
    filled = jnp.arange(ring.capacity) < ring.count
    windows = jnp.where(filled, ring.slots.length + length - 1, 0).astype(jnp.int32)  # [N]
    ends = jnp.cumsum(windows)  # window w (0-based, over the whole ring) lives in the episode whose range holds it
    w = jax.random.randint(key, (batch_size,), 0, jnp.maximum(ends[-1], 1), dtype=jnp.int32)
    idx = jnp.searchsorted(ends, w, side="right").astype(jnp.int32)
    return idx, w - (ends[idx] - windows[idx]) - (length - 1)


def window_views(stored: StoredViews, idx: chex.Array, first_step: chex.Array, length: int) -> WindowBatch:
    """The entries of episodes ``stored[idx]`` (leaves ``[N, ...]``) inside windows starting at ``first_step`` i32[B]
    of ``length`` steps (0 = the whole episode), gathering only those entries."""
    jert = cert = None
    if stored.jert is not None:
        jv = stored.jert
        size = length or jv.step.shape[-1]
        index, valid = crop(jv.step[idx], jv.mask[idx], first_step, size)  # [B, L]
        jert = jax.tree_util.tree_map(lambda x: x[idx[:, None], index], jv).replace(mask=valid)
    if stored.cert is not None:
        cv = stored.cert
        size = length or cv.step.shape[-1]
        index, valid = crop(cv.step[idx], cv.mask[idx], first_step[:, None], size)  # [B, n, L]
        agent = jnp.arange(cv.step.shape[-2])[None, :, None]
        cert = jax.tree_util.tree_map(lambda x: x[idx[:, None, None], agent, index], cv).replace(mask=valid)
    return WindowBatch(jert=jert, cert=cert)


def crop(step: chex.Array, mask: chex.Array, first_step: chex.Array, length: int) -> tuple[chex.Array, chex.Array]:
    """Entries of a left-packed view whose kept step lies in the window ``first_step … first_step+length−1``.

    Args:
      step: i32[..., K] kept step of each entry (increasing over the real entries).
      mask: bool[..., K] real entries (a prefix).
      first_step: i32[...] the window's first step (the leading axes).
      length: L (static).
    Returns:
      index: i32[..., L] entry positions ``k0 … k0+L−1`` (``k0`` = real entries before the window), clipped to K−1.
      valid: bool[..., L] the entry is real and inside the window (a prefix).
    """
    first_step = jnp.asarray(first_step)[..., None]
    k0 = jnp.sum(jnp.logical_and(mask, step < first_step), axis=-1, keepdims=True)
    index = k0 + jnp.arange(length)
    inside = index < step.shape[-1]
    index = jnp.minimum(index, step.shape[-1] - 1)
    valid = jnp.take_along_axis(mask, index, -1) & (jnp.take_along_axis(step, index, -1) < first_step + length)
    return index.astype(jnp.int32), valid & inside


def append_bootstrap(x: chex.Array, boot: chex.Array, count: chex.Array, axis: int) -> chex.Array:
    """``x`` with one more entry along ``axis`` where entry ``count`` is ``boot`` (the row after the last real entry,
    from which the last transition bootstraps); later entries stay zero padding.

    Args:
      x: [*lead, L, *rest] entries (``axis`` = len(lead)).
      boot: [*lead, L, *rest] per-entry "next" values; the one of entry ``count − 1`` is used.
      count: i32[*lead] real entries.
    Returns:
      [*lead, L + 1, *rest].
    """
    last = jnp.maximum(count - 1, 0)
    expand = lambda i: i.reshape(i.shape + (1,) * (x.ndim - i.ndim))  # noqa: E731
    boot_row = jnp.take_along_axis(boot, expand(last[..., None]), axis)
    padded = jnp.concatenate([x, jnp.zeros_like(jnp.take(x, jnp.arange(1), axis=axis))], axis=axis)
    where = expand(jnp.arange(x.shape[axis] + 1) == count[..., None])
    return jnp.where(where, boot_row.astype(x.dtype), padded)


def jert_window(batch: WindowBatch):
    """Mac-JERT entries of each window and the observation sequence a recurrent net runs over.

    Returns:
      view: the ``views.JertView`` entries, leaves ``[B, L, ...]``.
      obs: f32[B, L + 1, n, O] frozen joint observations at the entries' decision rows, then the one after the last
        entry (``Q(h′)`` of entry k is the net's output at k + 1, as the originals' ``[o_0, o′_0, o′_1, …]``).
    """
    view = batch.jert
    return view, append_bootstrap(view.obs, view.obs_next, view.mask.sum(-1), axis=1)


def cert_window(batch: WindowBatch):
    """Per agent, its Mac-CERT entries of each window and its observation sequence.

    Returns:
      view: the ``views.CertView`` entries, leaves ``[B, n, L, ...]``.
      obs: f32[B, n, L + 1, O].
    """
    view = batch.cert
    return view, append_bootstrap(view.obs, view.obs_next, view.mask.sum(-1), axis=2)


def window_source(batch_size: int, trace_len: int):
    """A trainer data source (``Algorithm.sample``) over a ring of ``StoredViews``: ``batch_size`` windows of
    ``trace_len`` steps, or whole episodes when ``trace_len`` is 0."""

    def sample(ring, fresh, key):
        del fresh
        return sample_windows(ring, key, batch_size, trace_len)

    return sample
