"""The Python API: train a run, load a run folder, act with a trained policy, evaluate it.

    import jaxmac
    run = jaxmac.train("quickstart")             # or jaxmac.load("runs/boxpushing-6x6-tomacvf-TIME")
    policy = run.policy(seed=0)                  # jittable: policy.act(timestep, carry, key) -> (actions, carry)
    print(run.evaluate(seed=0, episodes=10))     # discounted / undiscounted return of each episode

A policy acts in one env: ``timestep`` is the ``envs_jax.TimeStep`` the env's ``reset``/``step`` returned (leaves
unbatched, ``[n, ...]`` per agent), ``carry`` the policy's recurrent state (``policy.init_carry()`` at the start of an
episode), ``key`` a PRNG key; ``actions`` is ``i32[n]``, one macro-action per agent for ``env.step`` (free agents,
``timestep.mac_done``, choose; busy agents re-send their running macro-action, ``timestep.mac``). ``jax.vmap`` it for
a batch of envs. This module imports JAX; ``import jaxmac`` alone does not (``jaxmac.train`` and friends load it
on first use).
"""

from __future__ import annotations

import csv
import dataclasses
import os
from typing import Any

import jax
import numpy as np

from envs_jax.validation import is_integer
from jaxmac.config import TrainConfig


@jax.tree_util.register_pytree_node_class
class Policy:
    """One seed's trained policy: ``act(timestep, carry, key) -> (actions, carry)``, pure and jittable
    (``jax.jit(policy.act)``; a ``Policy`` is also a pytree, so it can be passed into a jitted function).

    ``greedy`` (the default): the actor-critics' ``greedy_act`` (the argmax of their actors); a learner without one
    acts with ``Algorithm.act`` at ε = 0 — for the value learners their greedy policy (as ``programs_for`` in
    ``jaxmac.runs.programs`` picks the final evaluation's policy).
    ``greedy=False``: the learner's evaluation policy ``Algorithm.act`` at ε = 0 — the actor-critics sample from
    their actors (what their training curves report); for the value learners it is the same greedy policy.
    """

    def __init__(self, algorithm, params, num_agents: int, greedy: bool = True):
        self.algorithm = algorithm  # jaxmac.algos.base.Algorithm
        self.params = params
        self.num_agents = num_agents
        self.greedy = greedy

    @property
    def _act(self):
        return self.algorithm.greedy_act if self.greedy and self.algorithm.greedy_act else self.algorithm.act

    @property
    def sampled(self) -> bool:
        """Whether ``act`` samples its actions (reads ``key``): an actor-critic's policy with ``greedy=False``."""
        return self.algorithm.greedy_act is not None and not self.greedy

    def init_carry(self):
        """The recurrent state at the start of an episode (before the reset timestep is acted on)."""
        return self.algorithm.init_carry(self.num_agents)

    def act(self, timestep, carry, key):
        """``(actions i32[n], carry)`` for one env's ``timestep`` (see the module docstring)."""
        carry, actions = self._act(self.params, carry, timestep, key, 0.0)
        return actions, carry

    def tree_flatten(self):
        return (self.params,), (self.algorithm, self.num_agents, self.greedy)

    @classmethod
    def tree_unflatten(cls, aux, children):
        algorithm, num_agents, greedy = aux
        return cls(algorithm, children[0], num_agents, greedy)

    def __repr__(self) -> str:
        return f"Policy({self.algorithm.name}, {'sampled' if self.sampled else 'greedy'}, {self.num_agents} agents)"


def evaluate_policy(env, policy: Policy, episodes: int = 10, key: int | jax.Array = 0) -> dict[str, np.ndarray]:
    """``episodes`` independent episodes of ``policy`` in ``env`` (one jitted, vmapped program): per episode its
    ``discounted`` return (Σ_t γ^t r_t over the primitive steps t until the episode ends, the metric of the curves),
    ``undiscounted`` return and ``length``, numpy arrays ``[episodes]``.

    Episode ``i`` runs from ``k = jax.random.split(key, episodes)[i]`` (``key`` an int is ``jax.random.key(key)``) as
    ``jaxmac.collect.run_episode`` does: ``k_reset, k_steps = split(k)``, ``env.reset(k_reset)``, and step ``t`` splits
    ``split(k_steps, horizon)[t]`` into the policy's key and the env's."""
    if not is_integer(episodes) or episodes < 1:
        raise ValueError(f"episodes={episodes!r} must be a positive integer")
    keys = jax.random.split(jax.random.key(key) if isinstance(key, int) else key, episodes)
    stats = _evaluator(env)(policy, keys)
    return {"discounted": np.asarray(stats["disc_return"]), "undiscounted": np.asarray(stats["return"]),
            "length": np.asarray(stats["length"])}


_EVALUATORS: dict[int, tuple[Any, Any]] = {}


def _evaluator(env):
    """The jitted ``(policy, keys [E]) -> episode_returns`` of ``env`` (one per env object)."""
    from jaxmac.collect import episode_returns, run_episode

    held = _EVALUATORS.get(id(env))
    if held is not None and held[0] is env:
        return held[1]

    def one(policy, key):
        def act(params, carry, ts, k, epsilon):
            actions, carry = policy.act(ts, carry, k)
            return carry, actions

        _, traj, _ = run_episode(env, act, lambda n: policy.init_carry(), None, key, 0.0)
        return episode_returns(traj, env.spec.discount)

    fn = jax.jit(jax.vmap(one, in_axes=(None, 0)))
    _EVALUATORS[id(env)] = (env, fn)
    return fn


@dataclasses.dataclass(eq=False)
class Run:
    """A run folder as loaded by ``load``: its settings, env, learner, the trained parameters of every seed (at its
    newest checkpoint) and its records.

    ``seeds``: the run's seed numbers (as in metrics.csv; ``0 … S-1`` unless it was trained with an offset);
    ``params``: seed → parameters, empty when the folder holds no checkpoint (a committed run keeps only its
    records); ``episodes``: episodes trained per seed at that checkpoint; ``summary``: summary.json (None until the
    run finished); ``metrics``: metrics.csv as columns (``metrics["eval_disc_return"]`` …, one entry per seed and
    round, NaN where a round did not evaluate)."""

    path: str
    config: TrainConfig
    meta: dict
    env: Any  # envs_jax MacroEnv
    algorithm: Any  # jaxmac.algos.base.Algorithm
    seeds: list[int]
    params: dict[int, Any]
    episodes: int
    summary: dict | None

    @property
    def metrics(self) -> dict[str, np.ndarray]:
        return read_metrics(os.path.join(self.path, "metrics.csv"))

    def policy(self, seed: int | None = None, greedy: bool = True) -> Policy:
        """Seed ``seed``'s policy (default: the run's first seed); see ``Policy`` for ``greedy``."""
        seed = self.seeds[0] if seed is None else seed
        if seed not in self.seeds:
            raise ValueError(f"seed={seed!r} is not a seed of {self.path}; its seeds are {self.seeds}")
        if seed not in self.params:
            raise ValueError(f"{self.path} has no checkpoint (none saved, or none that restores): there is no trained "
                             f"policy to load; train it further (jaxmac train --resume {self.path})")
        return Policy(self.algorithm, self.params[seed], self.env.spec.num_agents, greedy)

    def evaluate(self, seed: int | None = None, episodes: int = 10, key: int | jax.Array = 0,
                 greedy: bool = True) -> dict[str, np.ndarray]:
        """``evaluate_policy(run.env, run.policy(seed, greedy), episodes, key)``: the ``discounted`` and
        ``undiscounted`` return and ``length`` of each of ``episodes`` independent episodes."""
        return evaluate_policy(self.env, self.policy(seed, greedy), episodes, key)

    def __repr__(self) -> str:
        final = "" if not self.summary else f", final greedy return {self.summary['final_greedy_return_mean']:.1f}"
        return (f"Run({self.path!r}: {self.config.algorithm} on {self.config.scenario}, seeds {self.seeds}, "
                f"{self.episodes} episodes per seed{final})")


def read_metrics(path: str) -> dict[str, np.ndarray]:
    """metrics.csv as ``{column: array}`` (float; ``seed``, ``round`` and ``episodes`` int); empty if it is absent."""
    if not os.path.exists(path):
        return {}
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return {}
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    out = {}
    for i, name in enumerate(header):
        values = np.array([float(r[i]) if r[i] != "" else np.nan for r in body], dtype=np.float64)
        out[name] = values.astype(np.int64) if name in ("seed", "round", "episodes") else values
    return out


def load(run_dir: str) -> Run:
    """The run in ``run_dir`` (a folder of ``jaxmac train`` or ``train``, a ``--workers`` run included) at its newest
    checkpoint that restores. Reads only (and turns on JAX's persistent compilation cache, as the CLI does)."""
    import json

    from jaxmac.runs import enable_compilation_cache, load_run, read_meta

    enable_compilation_cache()
    meta = read_meta(run_dir)
    config = TrainConfig.from_dict(meta["config"])
    folders = ([os.path.join(run_dir, f"worker{k}") for k in range(meta["workers"])] if "workers" in meta
               else [run_dir])
    seeds = list(range(meta["seed_offset"], meta["seed_offset"] + meta["seeds"]))
    params: dict[int, Any] = {}
    env = algorithm = None
    episodes = 0
    for folder in folders:
        if not os.path.isdir(os.path.join(folder, "checkpoints")):
            continue
        trainer, state, chunks, part = load_run(folder)
        env, algorithm = trainer.env, trainer.algorithm
        if chunks:
            episodes = int(np.asarray(state.episodes)[0])
            for i, seed in enumerate(range(part["seed_offset"], part["seed_offset"] + part["seeds"])):
                params[seed] = jax.tree_util.tree_map(lambda x, i=i: x[i], state.params)
    if env is None:  # no checkpoint anywhere: the settings and records only
        from jaxmac.algos.registry import make_algorithm
        from jaxmac.config import make_env

        env = make_env(config)
        algorithm = make_algorithm(config, env)
    summary = None
    summary_path = os.path.join(run_dir, "summary.json")
    if os.path.exists(summary_path):
        with open(summary_path) as f:
            summary = json.load(f)
    return Run(run_dir, config, meta, env, algorithm, seeds, params, episodes, summary)


def train(preset: str | TrainConfig | None = None, *, scenario: str | None = None, algorithm: str | None = None,
          seeds: int | None = None, out_dir: str | None = None, tiny: bool = False, paper: bool = False,
          seed_offset: int = 0, progress: bool = True, log: str | None = None, **overrides) -> Run:
    """Train a run (``jaxmac.runs.train_run``, as ``jaxmac train`` does) and return it loaded (``load``).

    What to train: a preset name (``"quickstart"``; ``jaxmac train --help`` lists them), or ``scenario`` and
    ``algorithm`` (defaults ``boxpushing-6x6`` and ``tomacvf``; ``tiny``: test sizes, ``paper``: the publication's
    values), or a ``TrainConfig``; ``overrides`` are settings on top (``episodes=500``, ``lr=5e-4``). ``seeds``:
    the preset's count, else 1. ``out_dir``: default ``runs/SCENARIO-ALGORITHM-TIME``. ``log``: ``"tensorboard"``,
    ``"wandb"`` or ``"wandb:online"`` also logs the metrics there (``jaxmac train --log``)."""
    from jaxmac.presets import preset_config, scenario_config
    from jaxmac.runs import default_out_dir, enable_compilation_cache, train_run

    fixed = [name for name, given in (("scenario", scenario is not None), ("algorithm", algorithm is not None),
                                      ("tiny", tiny), ("paper", paper)) if given]
    if isinstance(preset, TrainConfig):
        if fixed:
            raise ValueError(f"a TrainConfig fixes the scenario and learner; {', '.join(fixed)} cannot be combined "
                             "with it (overrides can)")
        config = preset.override(**overrides)
        seeds = 1 if seeds is None else seeds
    elif preset is not None:
        if fixed:
            raise ValueError(f"preset {preset!r} fixes the scenario, learner and sizes; {', '.join(fixed)} cannot be "
                             "combined with it (seeds and overrides can)")
        config, found = preset_config(preset)
        config = config.override(**overrides)
        seeds = found.seeds if seeds is None else seeds
    else:
        config = scenario_config(scenario or "boxpushing-6x6", algorithm or "tomacvf", tiny=tiny, paper=paper,
                                 overrides=overrides)
        seeds = 1 if seeds is None else seeds
    out_dir = out_dir or default_out_dir(config)
    enable_compilation_cache()
    train_run(config, seeds, out_dir, seed_offset=seed_offset, progress=progress, log=log)
    return load(out_dir)
