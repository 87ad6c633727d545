"""What an algorithm plugs into the shared trainer (``jaxmac.trainer``), and the default pieces.

An ``Algorithm`` says what learners differ in; everything else (rollout, episode writer, ring, schedule,
target updates, evaluation, metrics) is the trainer's. The defaults cover the replay-based value learners:
the data source samples episodes from the ring (``jaxmac.buffer.sources``), the update is one gradient step on
``loss`` with the config's optimiser. ``Learner`` is how a learner module presents itself to the registry.

``Progress`` carries the counters a schedule may read inside the compiled round (episodes, env steps,
gradient steps so far).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import chex
import jax
import optax
from flax import struct

from jaxmac.buffer.episode import EpisodeSlot
from jaxmac.collect import Act


@struct.dataclass
class Progress:
    """Training counters (i32[] each) before the current round's updates."""

    episodes: chex.Array
    env_steps: chex.Array
    updates: chex.Array


Loss = Callable[[Any, Any, Any, chex.PRNGKey, Progress], tuple[chex.Array, dict[str, chex.Array]]]
Update = Callable[[Any, Any, Any, Any, chex.PRNGKey, Progress], tuple[Any, Any, dict[str, chex.Array]]]
# (ring state, fresh slots, key) -> batch: jaxmac.buffer.sources
Sample = Callable[[Any, EpisodeSlot, chex.PRNGKey], Any]
BehaviourAct = Callable[[Any, Any, Any, chex.PRNGKey, chex.Array, chex.Array], tuple[Any, chex.Array]]


@dataclasses.dataclass(frozen=True)
class Learner:
    """A learner as the registry (``jaxmac.algos.registry``) lists it; each learner module defines its own
    ``LEARNER``.

    settings: its settings block class (a ``jaxmac.config.LearnerSettings`` naming this learner)
    make(config, env) -> Algorithm: the factory
    scenario_values: per scenario, the values its configuration starts from (shared ``TrainConfig`` fields and block
        fields in one flat dict; ``jaxmac.presets.scenario_config``)
    tiny_values: block values for tests and smoke runs (with ``jaxmac.presets.TINY``)
    summary: one line for listings
    paper_values: the publication's own values where ``scenario_values`` differ (``jaxmac train --paper``); None =
        the defaults are the publication's
    """

    name: str
    settings: type
    make: Callable[..., "Algorithm"]
    scenario_values: dict[str, dict[str, Any]]
    tiny_values: dict[str, Any]
    summary: str
    paper_values: dict[str, dict[str, Any]] | None = None

    def __post_init__(self):
        if getattr(self.settings, "algorithm", None) != self.name:
            raise ValueError(f"learner {self.name!r}: its settings class {self.settings.__name__} must name it "
                             f"(class {self.settings.__name__}(..., algorithm={self.name!r}))")


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """A learner on the shared trainer.

    init_params(key) -> params
    init_carry(num_agents) -> per-env policy carry (e.g. GRU states)
    act(params, carry, ts, key, epsilon) -> (carry, actions i32[n]): the greedy/evaluation policy (ε = 0) and,
        unless ``behaviour_act`` is given, the behaviour policy too
    loss(params, target_params, batch, key, progress) -> (scalar, metrics dict of scalars); None when ``update``
        is the algorithm's own (the actor-critics' critic-then-actor steps)
    optimizer: the optax transformation ``update`` applies (``default_optimizer(config)`` unless given)
    update(params, target_params, opt_state, batch, key, progress) -> (params, opt_state, metrics): one
        training step on a batch; default ``gradient_update(loss, optimizer)``
    store(slot) -> item: what the ring keeps of each episode (default: the ``EpisodeSlot`` itself; the Mac-JERT /
        Mac-CERT learners keep their squeezed views, computed once per episode)
    sample(ring, fresh, key) -> batch: the data source; ``fresh`` are the episode slots just collected
        (leaves ``[E, ...]``); default: ``batch_size`` episodes drawn uniformly from the ring
    behaviour_act(params, carry, ts, key, epsilon, episodes) -> (carry, actions): the exploring policy while
        training, given the episodes trained so far (e.g. centralised exploration for a while)
    greedy_act(params, carry, ts, key, epsilon) -> (carry, actions): for a stochastic evaluation policy (the
        actor-critics evaluate by sampling, as their originals), its greedy version, evaluated and logged beside it
    values(params, carry, ts) -> f32[n, A]: the per-agent utilities Q_i the greedy policy maximises at this step
        (carry as ``act`` receives it); value learners with per-agent utilities give it, ``jaxmac eval`` prints it
    """

    name: str
    init_params: Callable[[chex.PRNGKey], Any]
    init_carry: Callable[[int], Any]
    act: Act
    loss: Loss | None
    optimizer: optax.GradientTransformation
    update: Update | None = None
    store: Callable[[EpisodeSlot], Any] | None = None
    sample: Sample | None = None
    behaviour_act: BehaviourAct | None = None
    greedy_act: Act | None = None
    values: Callable[[Any, Any, Any], chex.Array] | None = None

    def __post_init__(self):
        if self.update is None and self.loss is None:
            raise ValueError(f"algorithm {self.name!r} needs a loss (for the default one-step update) or an update")
        if self.update is None:
            object.__setattr__(self, "update", gradient_update(self.loss, self.optimizer))


def default_optimizer(config) -> optax.GradientTransformation:
    """Adam at ``config.lr``, after global-norm clipping at ``config.grad_clip`` (none when it is 0)."""
    return clipped_adam(config.lr, config.grad_clip)


def gradient_update(loss: Loss, optimizer: optax.GradientTransformation) -> Update:
    """One gradient step on ``loss``; metrics gain ``loss`` and ``grad_norm``."""

    def update(params, target_params, opt_state, batch, key, progress):
        (value, metrics), grads = jax.value_and_grad(loss, has_aux=True)(params, target_params, batch, key, progress)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        return params, opt_state, dict(metrics, loss=value, grad_norm=optax.tree.norm(grads))

    return update


def per_part_optimizer(parts: dict[str, optax.GradientTransformation]) -> optax.GradientTransformation:
    """One optimiser per top-level part of the params (e.g. ``{"actor": adam(a_lr), "critic": adam(c_lr)}``), each
    with its own state ``opt_state[part]``, so that an update may step one part before computing the other's
    gradient (the actor-critics' critic-then-actor order). ``update`` on the whole tree steps every part."""

    def init(params):
        return {name: tx.init(params[name]) for name, tx in parts.items()}

    def update(updates, state, params=None):
        out, new_state = {}, {}
        for name, tx in parts.items():
            out[name], new_state[name] = tx.update(updates[name], state[name], None if params is None else params[name])
        return out, new_state

    return optax.GradientTransformation(init, update)


def clipped_adam(lr: float, grad_clip: float) -> optax.GradientTransformation:
    """Adam at ``lr`` after global-norm clipping at ``grad_clip`` (none when it is 0)."""
    if grad_clip == 0:
        return optax.adam(lr)
    return optax.chain(optax.clip_by_global_norm(grad_clip), optax.adam(lr))
