"""What an algorithm plugs into the shared trainer (``jaxmac.trainer``), and the default pieces.

An ``Algorithm`` says what learners differ in; everything else (rollout, episode writer, ring, schedule,
target updates, evaluation, metrics) is the trainer's. The defaults cover the replay-based value learners:
the data source samples episodes from the ring, the update is one gradient step on ``loss`` with the
config's optimiser.

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

from jaxmac.buffer import ring as ring_lib
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
Sample = Callable[[ring_lib.RingState, EpisodeSlot, chex.PRNGKey], Any]
BehaviourAct = Callable[[Any, Any, Any, chex.PRNGKey, chex.Array, chex.Array], tuple[Any, chex.Array]]


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


def on_policy_source(prepare: Callable[[EpisodeSlot], Any]) -> Sample:
    """The on-policy data source: the episodes just collected (leaves ``[E, ...]``), through ``prepare`` (the views
    the learner trains on). The ring is not read; such a learner stores only each episode's length in it."""

    def sample(ring, fresh, key):
        del ring, key
        return prepare(fresh)

    return sample


def store_length(slot: EpisodeSlot):
    """``Algorithm.store`` of an on-policy learner: the ring keeps nothing but the episode's length."""
    return slot.length


def sample_episodes(batch_size: int) -> Sample:
    """The default data source: ``batch_size`` whole episodes, uniformly from the ring."""

    def sample(ring, fresh, key):
        del fresh
        return ring_lib.sample(ring, key, batch_size)[0]

    return sample
