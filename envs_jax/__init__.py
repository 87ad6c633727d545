"""Pure-functional, jittable JAX ports of the macro-action MARL benchmarks.

    import envs_jax, jax
    env = envs_jax.make("boxpushing-6x6")
    state, ts = env.reset(jax.random.key(0))
    state, ts = env.step(jax.random.key(1), state, actions)   # int32[n_agents]

See ``envs_jax.core`` for the API and ``envs_jax.wrappers.AutoReset`` for rollouts.
"""

from envs_jax.core import CoreStep, EnvSpec, EnvState, MacroEnv, TimeStep
from envs_jax.registry import make, registered_names
from envs_jax.wrappers import AutoReset, AutoResetState

# Importing a domain registers its names with ``make``.
from envs_jax import boxpushing as _boxpushing  # noqa: E402,F401
from envs_jax import overcooked as _overcooked  # noqa: E402,F401
from envs_jax import warehouse as _warehouse  # noqa: E402,F401

__all__ = [
    "AutoReset",
    "AutoResetState",
    "CoreStep",
    "EnvSpec",
    "EnvState",
    "MacroEnv",
    "TimeStep",
    "make",
    "registered_names",
]
