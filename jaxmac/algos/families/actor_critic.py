"""Pieces of the macro-action actor-critics (Mac-IAICC, Mac-NIACC, Mac-CAC; docs/baselines.md §1.0, §1.4–1.6).

They learn on-policy from the ``num_envs`` episodes just collected (no replay), each update being a critic step
followed by an actor step whose advantages come from the *updated* critic (``critic_then_actor_update``).

* **Policy.** An actor outputs logits over an agent's macro-actions (or the joint ones, Mac-CAC). Exploration
  mixes the softmax with a uniform distribution, ``π_ε = (1 − ε) π + ε / |M_i|`` over the agent's own
  macro-actions (``epsilon_mixed_log_probs``); actions are sampled from ``π_ε`` restricted to the available ones
  and renormalised, and the policy gradient uses ``log π_ε`` of the unrestricted mixture, as the originals do.
  Their evaluation samples from the un-mixed ``π`` (ε = 0); greedy evaluation takes its available argmax.
* **Critic targets.** n-step returns over macro transitions (``macro_returns``): an entry k of a squeezed
  sequence (Mac-CERT of one agent, or Mac-JERT) with reward ``R_k`` (accumulated with γ over its τ_k primitive
  steps) and ``d_k = γ^{τ_k}`` (0 at termination) gets ``G_k = Σ_{j<m} (Π_{i<j} d_{k+i}) R_{k+j} +
  (Π_{i<m} d_{k+i}) V⁻_{k+m−1}`` with ``m = min(n, entries left)``, where ``V⁻_k`` is the target critic after
  entry k; the last entries of a sequence are Monte-Carlo to its end, bootstrapped there after a truncation.
* **Actor loss.** ``−Σ_k γ^{t_k} log π_ε(m_k | h_k) A_k / Σ_k 1`` over an actor's entries, with ``t_k`` the
  absolute primitive step at which macro-action k ended (the originals' weighting), ``A_k = G_k − V(·)``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any, Callable

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from envs_jax.validation import is_integer
from jaxmac.algos.acting import epsilon_schedule
from jaxmac.algos.families.centralised import joint_obs
from jaxmac.algos.families.decentralised import init_agent_drqn
from jaxmac.algos.families.decentralised import sequence_q as decentralised_sequence
from jaxmac.algos.targets import joint_mask, unravel_joint
from jaxmac.buckets import length_bucketed
from jaxmac.buffer import views, windows
from jaxmac.buffer.episode import EpisodeSlot
from jaxmac.losses import masked_mean, td_mse
from jaxmac.networks.drqn import DRQN, AgentDRQN, AgentStateCritic, StateCritic
from jaxmac.ops import MASK_VALUE, gather_q, masked_argmax


def real_action_mask(action_counts: Sequence[int], width: int) -> np.ndarray:
    """bool[n, width]: agent i's own macro-actions (its first ``action_counts[i]`` entries; the rest is padding)."""
    return np.arange(width)[None, :] < np.asarray(action_counts)[:, None]


def epsilon_mixed_log_probs(logits: chex.Array, real: chex.Array, epsilon: chex.Array) -> chex.Array:
    """``log π_ε`` with ``π_ε = (1 − ε) softmax(logits) + ε / |M|`` over the real actions.

    Args:
      logits: f32[..., A]; real: bool[..., A] (broadcastable) the actions the softmax is over; epsilon: f32[].
    Returns:
      f32[..., A], ``MASK_VALUE`` on the padding entries.
    """
    real = jnp.broadcast_to(real, logits.shape)
    log_pi = jax.nn.log_softmax(jnp.where(real, logits, MASK_VALUE), axis=-1)
    count = real.sum(-1, keepdims=True).astype(logits.dtype)
    epsilon = jnp.asarray(epsilon, logits.dtype)
    mixed = jnp.logaddexp(log_pi + jnp.log1p(-epsilon), jnp.log(epsilon) - jnp.log(count))
    return jnp.where(real, mixed, MASK_VALUE)


def choose(key: chex.PRNGKey, log_probs: chex.Array, allowed: chex.Array, greedy: bool) -> chex.Array:
    """A sample from ``exp(log_probs)`` restricted to ``allowed`` and renormalised (or its argmax): i32[...].

    Sampling inverts the cumulative distribution with one uniform draw per row (a Gumbel draw per action costs
    |M_1|·…·|M_n| random numbers per joint decision, which dominates Mac-CAC's rollouts on Overcooked)."""
    if greedy:
        return masked_argmax(log_probs, allowed)
    probs = jnp.where(allowed, jnp.exp(log_probs - jnp.max(jnp.where(allowed, log_probs, MASK_VALUE), -1,
                                                            keepdims=True)), 0.0)
    cdf = jnp.cumsum(probs, -1)
    u = jax.random.uniform(key, cdf.shape[:-1] + (1,)) * cdf[..., -1:]
    index = jnp.sum(cdf <= u, -1)  # first action whose cumulative mass exceeds u
    last = probs.shape[-1] - 1 - jnp.argmax(jnp.flip(allowed, -1), -1)  # the last allowed action (u at the top)
    return jnp.minimum(index, last).astype(jnp.int32)


def actors_step(net, params, carry, ts, key, epsilon, real: np.ndarray, greedy: bool = False):
    """Decentralised actors at one primitive step: each free agent samples from its ``π_ε`` over its available
    actions (or takes the argmax); busy agents re-send their running macro-action. An agent's GRU steps only at
    its own decisions (Mac-CERT history, as the originals' runner). ``carry`` f32[n, h].
    Returns ``(carry, actions i32[n])``."""
    carry = jnp.where(ts.t == 0, jnp.zeros_like(carry), carry)
    x = jnp.asarray(ts.obs_macro, jnp.float32)[None]  # [1, n, O]
    logits, new_carry = net.apply(params, x, jnp.zeros((1,), bool), carry)
    log_probs = epsilon_mixed_log_probs(logits[0], real, epsilon)
    chosen = choose(key, log_probs, ts.avail_actions & real, greedy)
    actions = jnp.where(ts.mac_done, chosen, ts.mac)
    return jnp.where(ts.mac_done[:, None], new_carry, carry), actions


def joint_actor_step(net, params, carry, ts, key, epsilon, action_counts: Sequence[int], greedy: bool = False):
    """A centralised joint actor at one primitive step (Mac-CAC): at a joint decision point it samples a joint
    macro-action from ``π_ε`` restricted to the joint actions whose busy agents keep their running macro-action and
    whose free agents pick available ones; only the free agents' components are executed. The GRU steps at joint
    decision points only. ``carry`` f32[h]. Returns ``(carry, actions i32[n])``."""
    carry = jnp.where(ts.t == 0, jnp.zeros_like(carry), carry)
    logits, new_carry = net.apply(params, joint_obs(ts.obs_macro)[None], jnp.zeros((1,), bool), carry)
    log_probs = epsilon_mixed_log_probs(logits[0], jnp.ones(logits.shape[-1:], bool), epsilon)
    allowed = joint_mask(ts.avail_actions, ts.mac_done, ts.mac, action_counts)
    actions = unravel_joint(choose(key, log_probs, allowed, greedy), action_counts)
    actions = jnp.where(ts.mac_done, actions, ts.mac)
    return jnp.where(jnp.any(ts.mac_done), new_carry, carry), actions


def macro_returns(reward: chex.Array, discount: chex.Array, bootstrap: chex.Array, mask: chex.Array,
                  n_step: int) -> chex.Array:
    """n-step returns over the macro transitions of squeezed sequences (see the module docstring).

    Args:
      reward, discount, bootstrap: f32[..., L] per entry ``R_k``, ``γ^{τ_k}`` (0 at termination) and the target
        critic's value after entry k.
      mask: bool[..., L] real entries (a prefix).
      n_step: n ≥ 1 (static; 1 = one-step TD).
    Returns:
      f32[..., L] ``G_k`` (0 on padding).
    """
    if not is_integer(n_step) or n_step < 1:
        raise ValueError(f"macro_returns: n_step={n_step!r} must be a positive integer (1 = one-step TD)")
    length = reward.shape[-1]
    k = jnp.arange(length)
    left = mask.sum(-1, keepdims=True) - k  # entries from k to the end of the sequence
    m = jnp.clip(left, 1, n_step)
    ret = jnp.zeros_like(reward)
    weight = jnp.ones_like(reward)
    for j in range(n_step):  # static n (≤ 5 in every script); each term is one gather along the sequence
        idx = jnp.broadcast_to(jnp.minimum(k + j, length - 1), reward.shape)
        r_j, d_j, v_j = (jnp.take_along_axis(x, idx, -1) for x in (reward, discount, bootstrap))
        ret = ret + jnp.where(j < m, weight * r_j, 0.0) + jnp.where(j == m - 1, weight * d_j * v_j, 0.0)
        weight = weight * d_j
    return jnp.where(mask, ret, 0.0)


def policy_gradient_loss(log_pi_taken: chex.Array, advantage: chex.Array, step: chex.Array, gamma: float,
                         mask: chex.Array) -> chex.Array:
    """``−Σ γ^{step} log π_ε · A / Σ mask`` over one actor's entries (all arrays of one shape)."""
    weight = jnp.where(mask, jnp.power(gamma, step.astype(jnp.float32)), 0.0)
    return -jnp.sum(weight * log_pi_taken * jax.lax.stop_gradient(advantage)) / jnp.maximum(mask.sum(), 1)


def per_agent_policy_gradient_loss(log_pi_taken, advantage, step, gamma, mask):
    """``policy_gradient_loss`` of each agent's actor (agents on axis 1 of ``[B, n, L]`` arrays), summed: each
    agent normalises by its own entries, as separately optimised actors."""
    per_agent = jax.vmap(lambda lp, adv, st, m: policy_gradient_loss(lp, adv, st, gamma, m), in_axes=1)(
        log_pi_taken, advantage, step, mask)
    return per_agent.sum()


# --- the update ----------------------------------------------------------------------------------------

CriticTargets = Callable[[Any, Any], tuple[chex.Array, chex.Array]]  # (target critic, batch) -> (G, mask)
CriticValues = Callable[[Any, Any], chex.Array]  # (critic, batch) -> V
ActorLoss = Callable[[Any, Any, chex.Array, chex.Array], tuple[chex.Array, dict[str, chex.Array]]]


def critic_then_actor_update(critic_targets: CriticTargets, critic_values: CriticValues, actor_loss: ActorLoss,
                             optimizers: dict[str, optax.GradientTransformation], config):
    """An ``Algorithm.update`` over params ``{"actor", "critic"}``: one critic step on the mean squared error
    ``(G − V)²`` (each critic group — an agent's individual critic, or the one joint critic — averaged over its own
    entries, groups summed), then one actor step with ``A = G − V`` from the updated critic.

    ``critic_targets`` and ``critic_values`` return arrays ``[B, g, L]`` (g critic groups, L entries);
    ``actor_loss(actor_params, batch, advantage, epsilon)`` maps the advantages to its own entries. ε is the
    exploration rate the episodes were collected with (the schedule at ``progress.episodes``). The step runs on the
    batch cut to its real entries, in ``config.length_buckets`` static sizes (``on_policy_bucketed``).
    """

    def update(params, target_params, opt_state, batch, key, progress):
        del key
        epsilon = epsilon_schedule(config, progress.episodes)
        targets, mask = critic_targets(target_params["critic"], batch)
        targets = jax.lax.stop_gradient(targets)

        def critic_loss(critic):
            values = critic_values(critic, batch)
            return jax.vmap(td_mse, in_axes=1)(values - targets, mask).sum(), values

        (c_loss, values), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(params["critic"])
        c_updates, c_state = optimizers["critic"].update(c_grads, opt_state["critic"], params["critic"])
        critic = optax.apply_updates(params["critic"], c_updates)
        advantage = jnp.where(mask, targets - critic_values(critic, batch), 0.0)
        (a_loss, a_metrics), a_grads = jax.value_and_grad(actor_loss, has_aux=True)(
            params["actor"], batch, advantage, epsilon)
        a_updates, a_state = optimizers["actor"].update(a_grads, opt_state["actor"], params["actor"])
        actor = optax.apply_updates(params["actor"], a_updates)
        metrics = {
            "critic_loss": c_loss, "actor_loss": a_loss, "loss": c_loss + a_loss,
            "value_mean": masked_mean(values, mask), "return_mean": masked_mean(targets, mask),
            "advantage_mean": masked_mean(advantage, mask), "advantage_abs": masked_mean(jnp.abs(advantage), mask),
            "critic_grad_norm": optax.tree.norm(c_grads), "actor_grad_norm": optax.tree.norm(a_grads),
            "grad_norm": optax.tree.norm((c_grads, a_grads)), **a_metrics,
        }
        return {"actor": actor, "critic": critic}, {"actor": a_state, "critic": c_state}, metrics

    return on_policy_bucketed(update, config.length_buckets)


# --- the episodes an update reads, and the decentralised actors ------------------------------------------


@struct.dataclass
class OnPolicyBatch:
    """Views of the round's episodes (leaves ``[E, ...]``); a learner fills only what it reads.

    cert: Mac-CERT, leaves ``[E, n, K, ...]``; jert: Mac-JERT, leaves ``[E, H, ...]``.
    cert_state / cert_state_next: f32[E, n, K, S] the state where agent i's macro-action k was chosen / after it
      ended (state critics of individual agents).
    start_joint / end_joint: i32[E, n, K] the Mac-JERT entry at which agent i's macro-action k started / ended
      (the joint decision point whose history scores it, and the one after which its bootstrap is read).
    """

    cert: views.CertView | None = None
    jert: views.JertView | None = None
    cert_state: chex.Array | None = None
    cert_state_next: chex.Array | None = None
    start_joint: chex.Array | None = None
    end_joint: chex.Array | None = None

    def entries(self) -> chex.Array:
        """i32[]: the most real entries of any sequence in the batch (Mac-CERT per agent, Mac-JERT)."""
        counts = [v.mask.sum(-1).max() for v in (self.cert, self.jert) if v is not None]
        return functools.reduce(jnp.maximum, counts).astype(jnp.int32)

    def prefix(self, size: int) -> "OnPolicyBatch":
        """The batch cut to its first ``size`` entries per sequence (exact when ``size >= entries()``: masks are
        prefixes, and joint indices point at real entries)."""
        cut = lambda axis: lambda x: jax.lax.slice_in_dim(x, 0, size, axis=axis)  # noqa: E731
        cert_axis = 2  # [E, n, K, ...]
        tree = jax.tree_util.tree_map
        return OnPolicyBatch(
            cert=None if self.cert is None else tree(cut(cert_axis), self.cert),
            jert=None if self.jert is None else tree(cut(1), self.jert),
            **{name: None if getattr(self, name) is None else cut(cert_axis)(getattr(self, name))
               for name in ("cert_state", "cert_state_next", "start_joint", "end_joint")})


def on_policy_bucketed(update, buckets: int):
    """``update`` on the batch's shortest prefix that holds every real Mac-CERT / Mac-JERT entry
    (``buckets.length_bucketed``)."""
    full = lambda batch: (batch.cert if batch.cert is not None else batch.jert).mask.shape[-1]  # noqa: E731
    return length_bucketed(update, buckets, full, OnPolicyBatch.entries)


def prepare_on_policy(cert: bool = True, jert: bool = True, cert_states: bool = False, alignment: bool = False):
    """``slots -> OnPolicyBatch`` holding the requested views (an ``on_policy_source``'s ``prepare``)."""

    def prepare(slots: EpisodeSlot) -> OnPolicyBatch:
        c = views.cert_view(slots) if cert else None
        j = views.jert_view(slots) if jert or alignment else None
        out = OnPolicyBatch(cert=c, jert=j if jert else None)
        if cert_states:
            rows = slots.decode_state()  # [E, H + 1, S]
            gather = jax.vmap(lambda r, i: r[i])
            out = out.replace(cert_state=gather(rows, c.start), cert_state_next=gather(rows, c.step + 1))
        if alignment:
            out = out.replace(start_joint=views.cert_to_jert_index(c.start, c.mask, j.step, j.mask),
                              end_joint=views.cert_to_jert_index(c.step, c.mask, j.step, j.mask))
        return out

    return prepare


def joint_history(jert: views.JertView) -> chex.Array:
    """f32[E, H + 1, n·O]: the joint macro-observations of the Mac-JERT entries, then the one after the last entry
    (a recurrent critic's output at k + 1 is its value after entry k)."""
    return joint_obs(windows.append_bootstrap(jert.obs, jert.obs_next, jert.mask.sum(-1), axis=1))


def centralised_critic(settings, spec, per_agent: bool):
    """The critic of the independent-actor learners: ``(net, init(key) -> params)``.

    ``settings.critic == 'history'``: a DRQN with one output over the joint macro-observations (input n·O);
    'state': ``StateCritic`` over the global state. ``per_agent``: one such critic per agent with its own parameters
    (Mac-IAICC; inputs with agents on axis -2), else one joint critic (Mac-NIACC)."""
    n = spec.num_agents
    lead = (1, n) if per_agent else (1,)
    if settings.critic == "history":
        net = (AgentDRQN if per_agent else DRQN)(mlp=settings.critic_mlp_sizes, hidden=settings.critic_rnn_size, out=1)
        carry = jnp.zeros(lead[1:] + (settings.critic_rnn_size,))
        return net, lambda key: net.init(key, jnp.zeros(lead + (n * spec.obs_dim,)), jnp.zeros((1,), bool), carry)
    net = (AgentStateCritic if per_agent else StateCritic)(mlp=settings.critic_mlp_sizes, mid=settings.critic_mid_size)
    return net, lambda key: net.init(key, jnp.zeros(lead + (spec.state_dim,)))


@dataclasses.dataclass(frozen=True)
class AgentActors:
    """Per-agent recurrent actors on their own frozen macro-observations (Mac-IAICC, Mac-NIACC): a DRQN-shaped
    net per agent whose outputs are logits, stepping at the agent's own decisions."""

    net: AgentDRQN
    real: np.ndarray  # bool[n, A] each agent's own macro-actions
    obs_dim: int
    gamma: float

    @classmethod
    def make(cls, settings, spec) -> "AgentActors":
        net = AgentDRQN(mlp=settings.actor_mlp_sizes, hidden=settings.actor_rnn_size, out=spec.max_actions)
        return cls(net=net, real=real_action_mask(spec.num_actions, spec.max_actions), obs_dim=spec.obs_dim,
                   gamma=spec.discount)

    def init(self, key):
        return init_agent_drqn(self.net, key, self.real.shape[0], self.obs_dim)

    def init_carry(self, n: int):
        return jnp.zeros((n, self.net.hidden), jnp.float32)

    def act(self, params, carry, ts, key, epsilon):
        return actors_step(self.net, params["actor"], carry, ts, key, epsilon, self.real)

    def greedy_act(self, params, carry, ts, key, epsilon):
        return actors_step(self.net, params["actor"], carry, ts, key, epsilon, self.real, greedy=True)

    def loss(self, actor_params, cert: views.CertView, advantage: chex.Array, epsilon: chex.Array):
        """The actors' policy-gradient loss on their Mac-CERT entries; ``advantage`` f32[E, n, K]."""
        logits = decentralised_sequence(self.net, actor_params, cert.obs)  # [E, n, K, A]
        log_probs = epsilon_mixed_log_probs(logits, self.real[:, None, :], epsilon)
        taken = gather_q(log_probs, cert.mac)
        value = per_agent_policy_gradient_loss(taken, advantage, cert.step, self.gamma, cert.mask)
        entropy = -jnp.sum(jnp.exp(log_probs) * jnp.where(self.real[:, None, :], log_probs, 0.0), -1)
        return value, {"policy_entropy": masked_mean(entropy, cert.mask), "cert_entries": cert.mask.sum() / cert.mask.shape[0]}
