"""Macro-action Overcooked (WeihaoTan/gym-macro-overcooked, as used by MacroMARL) in JAX.

    env = envs_jax.make("overcooked-A")          # or -B, -C; overrides: see OvercookedConfig

3 agents on a 7×7 kitchen must chop a tomato, a lettuce and an onion, put them on one plate and
deliver it (task 6, lettuce-onion-tomato salad). Behaviour follows
``docs/envs/overcooked.md`` exactly, quirks included; modules:

* ``layouts``     maps, canonical object order, macro-action lists (static, numpy)
* ``world``       state dataclass, true grid, beliefs, belief maps, observations
* ``planner``     the controllers' A* planner with the original's heap tie-breaking
* ``physics``     one primitive step of the world (sequential agents, swaps, interactions)
* ``controllers`` macro-action controllers and post-step termination checks
* ``env``         the ``MacroEnv`` and its config
* ``render``      text picture of a state
* ``scripted``    a jittable scripted policy that delivers the salad
"""

from envs_jax.overcooked.env import Overcooked, OvercookedConfig
from envs_jax.overcooked.layouts import MAP_NAMES
from envs_jax.overcooked.world import OvercookedState
from envs_jax.registry import apply_overrides, register

_VALID = ", ".join(f"overcooked-{m}" for m in MAP_NAMES)


def _build(match, overrides) -> Overcooked:
    map_name = match.group(1)
    name = f"overcooked-{map_name}"
    if map_name not in MAP_NAMES:
        raise ValueError(f"unknown env name {name!r}; valid Overcooked names: {_VALID}")
    return Overcooked(map_name, apply_overrides(OvercookedConfig(), overrides, name))


register("overcooked", r"overcooked-(.*)", _VALID, _build)

__all__ = ["MAP_NAMES", "Overcooked", "OvercookedConfig", "OvercookedState"]
