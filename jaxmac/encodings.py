"""Sinusoidal encodings of absolute time ``t`` and macro-action progress ``t_m`` (DECISIONS D3).

The standard transformer sinusoid of an integer position ``p`` with ``d`` (even) features:

    PE(p)[2k]   = sin(p / base^(2k/d))
    PE(p)[2k+1] = cos(p / base^(2k/d))        k = 0 .. d/2 - 1

``time_encoding`` concatenates PE(t) (``dim_t`` features) and PE(t_m) (``dim_tm`` features);
the two are never added. ``use_t=False`` drops the absolute-time part (it leaks the horizon).
"""

from __future__ import annotations

import dataclasses

import chex
import jax.numpy as jnp

from envs_jax.validation import is_integer


@dataclasses.dataclass(frozen=True)
class EncodingConfig:
    """Widths and base of the encodings. ``dim_t``/``dim_tm`` must be even and positive."""

    dim_t: int = 16
    dim_tm: int = 8
    base: float = 10000.0
    use_t: bool = True

    def __post_init__(self):
        for name in ("dim_t", "dim_tm"):
            d = getattr(self, name)
            if not is_integer(d) or d <= 0 or d % 2:
                raise ValueError(f"EncodingConfig.{name}={d!r} must be a positive even integer (e.g. 8, 16)")
        if not self.base > 1.0:
            raise ValueError(f"EncodingConfig.base={self.base!r} must be > 1 (standard: 10000.0)")

    @property
    def dim(self) -> int:
        """Width of ``time_encoding``'s output."""
        return (self.dim_t if self.use_t else 0) + self.dim_tm


def sinusoid(pos: chex.Array, dim: int, base: float = 10000.0) -> chex.Array:
    """Sinusoidal encoding of integer positions.

    Args:
      pos: int[...] positions (any shape; cast to float32).
      dim: even number of features.
      base: wavelength base.
    Returns:
      f32[..., dim], sin/cos interleaved (even index sin, odd index cos).
    """
    if not isinstance(dim, int) or dim <= 0 or dim % 2:
        raise ValueError(f"sinusoid: dim={dim!r} must be a positive even integer")
    freq = base ** (-jnp.arange(0, dim, 2, dtype=jnp.float32) / dim)  # [dim/2]
    angle = jnp.asarray(pos, jnp.float32)[..., None] * freq  # [..., dim/2]
    return jnp.stack([jnp.sin(angle), jnp.cos(angle)], axis=-1).reshape(*angle.shape[:-1], dim)


def time_encoding(t: chex.Array, t_m: chex.Array, config: EncodingConfig = EncodingConfig()) -> chex.Array:
    """``PE(t) ⊕ PE(t_m)``, broadcasting ``t`` against ``t_m``.

    Args:
      t: int[...] absolute primitive time, e.g. int[H] or int[B, H].
      t_m: int[...] progress, broadcastable with ``t`` (e.g. int[H, n] with ``t[:, None]``).
    Returns:
      f32[..., config.dim] where ``...`` is the broadcast shape.
    """
    t, t_m = jnp.broadcast_arrays(jnp.asarray(t), jnp.asarray(t_m))
    parts = [sinusoid(t, config.dim_t, config.base)] if config.use_t else []
    parts.append(sinusoid(t_m, config.dim_tm, config.base))
    return jnp.concatenate(parts, axis=-1)
