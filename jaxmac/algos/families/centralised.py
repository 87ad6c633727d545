"""Pieces of the centralised joint-action learners (Mac-Cen-DDRQN, the centralised half of Mac-Dec-MADDRQN).

A centralised recurrent Q reads the concatenation of every agent's frozen macro-observation and outputs one
value per joint macro-action (|M_1|·…·|M_n|, row-major as in ``jaxmac.algos.targets``); it is trained on Mac-JERT
windows with the conditional double-Q target (docs/baselines.md §1.2) and acts as a centralised controller.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

from envs_jax.core import MacroEnv
from jaxmac.algos.acting import joint_epsilon_greedy
from jaxmac.algos.targets import joint_action_count, joint_conditional_argmax, ravel_joint
from jaxmac.buffer import windows
from jaxmac.losses import masked_mean, td_mse
from jaxmac.networks.drqn import DRQN
from jaxmac.scenarios import SCENARIOS


def check_joint_space(env: MacroEnv, limit: int, algorithm: str) -> int:
    """|M_1|·…·|M_n| of ``env``; a ValueError naming the size and the envs within ``limit`` when it is larger."""
    size = joint_action_count(env.spec.num_actions)
    if size > limit:
        import envs_jax

        sizes = {name: joint_action_count(envs_jax.make(name).spec.num_actions) for name in SCENARIOS}
        fine = [f"{name} ({n})" for name, n in sizes.items() if n <= limit]
        raise ValueError(
            f"{algorithm}: {env.spec.name} has {size} joint macro-actions "
            f"({' x '.join(map(str, env.spec.num_actions))}), more than max_joint_actions={limit} for a centralised "
            f"learner's joint Q table; raise max_joint_actions (memory and time grow with it) or use a decentralised "
            f"learner. Within the limit: {', '.join(fine) or 'none'}")
    return size


def joint_obs(obs: chex.Array) -> chex.Array:
    """f32[..., n, O] -> f32[..., n·O]: the centralised net's input."""
    return obs.reshape(obs.shape[:-2] + (-1,)).astype(jnp.float32)


def sequence_q(net: DRQN, params, obs: chex.Array) -> chex.Array:
    """The centralised net over squeezed sequences ``obs`` f32[B, T, n, O] from a zero state: f32[B, T, J]."""
    x = joint_obs(obs)
    b, steps = x.shape[:2]
    reset = jnp.broadcast_to(jnp.arange(steps) == 0, (b, steps))
    q, _ = net.apply(params, x, reset, jnp.zeros((b, net.hidden)))
    return q


def conditional_double_q_loss(net: DRQN, params, target_params, batch: windows.WindowBatch, action_counts):
    """MacCen-Q's loss on a batch of Mac-JERT windows.

    Returns ``(loss, metrics, best, view)``: ``view`` is the ``jert_window`` view (leaves [B, L, ...]) and ``best``
    i32[B, L, n] the conditional argmax at each of its entries' next decision point (Mac-Dec-MADDRQN's
    decentralised targets read it).
    """
    view, obs = windows.jert_window(batch)  # view leaves [B, L, ...], obs [B, L + 1, n, O]
    q = sequence_q(net, params, obs)  # [B, L + 1, J]
    q_target = sequence_q(net, target_params, obs)
    q_taken = jnp.take_along_axis(q[:, :-1], ravel_joint(view.mac, action_counts)[..., None], -1)[..., 0]
    best = joint_conditional_argmax(jax.lax.stop_gradient(q[:, 1:]), view.avail_next, view.free_next,
                                    view.next_mac, action_counts)
    boot = jnp.take_along_axis(q_target[:, 1:], ravel_joint(best, action_counts)[..., None], -1)[..., 0]
    y = jax.lax.stop_gradient(view.reward + view.discount * boot)
    loss = td_mse(q_taken - y, view.mask)
    metrics = {"cen_loss": loss, "cen_q_mean": masked_mean(q_taken, view.mask),
               "jert_entries": view.mask.sum() / view.mask.shape[0]}
    return loss, metrics, best, view


def controller_step(net: DRQN, params, carry, ts, key, epsilon, action_counts, keep_history: bool):
    """The centralised controller at one primitive step: conditional ε-greedy joint action (busy agents keep
    theirs); the GRU steps only at joint decision points, and only with ``keep_history`` (else every decision is
    valued from a zero state, the originals' exploration without ``h_explore``). Returns ``(carry, actions i32[n])``."""
    carry = jnp.where(ts.t == 0, jnp.zeros_like(carry), carry)
    start = carry if keep_history else jnp.zeros_like(carry)
    q, new_carry = net.apply(params, joint_obs(ts.obs_macro)[None], jnp.zeros((1,), bool), start)
    actions = joint_epsilon_greedy(key, q[0], ts.avail_actions, ts.mac_done, ts.mac, epsilon, action_counts)
    if keep_history:
        carry = jnp.where(jnp.any(ts.mac_done), new_carry, carry)
    return carry, actions
