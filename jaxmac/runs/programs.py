"""The jitted programs a run runs (init, chunk, final evaluations; seeds vmapped), built once per setting in a
process (``programs_for``).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable

import jax
import numpy as np

from jaxmac.config import TrainConfig
from jaxmac.seeds import SEED_AXIS

@dataclasses.dataclass(frozen=True)
class Programs:
    """A trainer and the jitted programs the host loop runs, seeds vmapped (state leaves ``[seeds, ...]``)."""
    trainer: Any  # jaxmac.trainer.Trainer
    init: Callable  # keys [seeds] -> TrainState
    chunk: Callable  # TrainState -> (TrainState, metrics [seeds, rounds]); donates the state it is given
    # (params, keys [seeds]) -> (discounted, undiscounted) mean final-evaluation returns [seeds]
    greedy_returns: Callable  # the greedy policy: the value learners' own, the actor-critics' greedy_act
    sampled_returns: Callable  # the policy ``evaluate`` runs (the actor-critics' sampled one)


@functools.lru_cache(maxsize=4)
def programs_for(config: TrainConfig, rounds_per_chunk: int | None) -> Programs:
    """Built once per setting in a process: a resumed, extended or finished run, or a test that trains the same
    configuration several times, reuses the traced and compiled programs instead of tracing them again."""
    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.trainer import make_train

    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env), rounds_per_chunk)

    def final_returns(evaluate):
        run = jax.jit(jax.vmap(lambda p, k: evaluate(p, k, config.eval_episodes), axis_name=SEED_AXIS))

        def returns(params, keys):
            stats = run(params, keys)
            return np.asarray(stats["disc_return"]).mean(-1), np.asarray(stats["return"]).mean(-1)

        return returns

    sampled = final_returns(trainer.evaluate)
    return Programs(trainer, jax.jit(jax.vmap(trainer.init)), jax.jit(trainer.seeds_chunk, donate_argnums=0),
                     final_returns(trainer.evaluate_greedy) if trainer.evaluate_greedy else sampled, sampled)
