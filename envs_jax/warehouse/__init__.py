"""Warehouse Tool Delivery (ToMacVF's WTD-D, -D1, -T, -T1, -Q) as ``warehouse-A`` … ``-E``.

    env = envs_jax.make("warehouse-E")                      # paper config
    env = envs_jax.make("warehouse-A", move_noise_std=0.05, fetch_duration_noise=True)

Overrides are the fields of :class:`WarehouseConfig`. See ``env.py`` for the dynamics,
``variants.py`` for layouts, ``scripted.py`` for a near-optimal hand-written policy.
"""

from __future__ import annotations

from envs_jax.registry import apply_overrides, register
from envs_jax.warehouse.env import InjectedNoiseEnv, Noise, WarehouseCore, WarehouseEnv
from envs_jax.warehouse.variants import DEFAULT_CONFIGS, LAYOUTS, Layout, WarehouseConfig

VALID_NAMES = "warehouse-A, warehouse-B, warehouse-C, warehouse-D, warehouse-E"


def make_warehouse(variant: str, **overrides) -> WarehouseEnv:
    """Build variant ``"A"`` … ``"E"`` with config overrides (validated, ``ValueError`` if bad)."""
    if variant not in LAYOUTS:
        raise ValueError(f"unknown Warehouse variant {variant!r}; valid variants: {sorted(LAYOUTS)}")
    name = f"warehouse-{variant}"
    config = apply_overrides(DEFAULT_CONFIGS[variant], overrides, name)
    return WarehouseEnv(LAYOUTS[variant], config, name)


def _build(match, overrides):
    return make_warehouse(match.group(1), **overrides)


register("warehouse", r"warehouse-([A-E])", VALID_NAMES, _build)

__all__ = [
    "InjectedNoiseEnv",
    "Layout",
    "Noise",
    "WarehouseConfig",
    "WarehouseCore",
    "WarehouseEnv",
    "make_warehouse",
]
