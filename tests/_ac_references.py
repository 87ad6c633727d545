"""Plain-Python references for the actor-critic tests (tests/test_actor_critic.py): macro transitions rebuilt from
raw per-step arrays with the original runner's running accumulators, the original learners' n-step rule, the
ε-mixed policy, and recurrent nets stepped one entry at a time."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np


# --- macro transitions from raw per-step arrays ----------------------------------------------------------------


def squeezed_entries(mac_done, reward, t_m, length, end, gamma, agent=None):
    """The kept entries of one agent (Mac-CERT, ``agent=i``) or of the team (Mac-JERT, ``agent=None``), built as the
    original runner does: a running accumulator per agent (or a joint one) reset on the step after its own (any)
    termination, ``acc += γ^{k−1} r`` otherwise, kept at the steps where the agent's (any agent's) macro-action ended.

    Returns a list of dicts: step (0-based primitive step of the termination), start (first step), tau, R,
    terminal (the episode terminated at that step).
    """
    out, acc, k = [], 0.0, 0
    for t in range(length):
        ended_before = mac_done[t - 1, agent] if agent is not None else mac_done[t - 1].any()
        if t == 0 or ended_before:
            acc, k = float(reward[t]), 1
        else:
            k += 1
            acc += gamma ** (k - 1) * float(reward[t])
        kept = mac_done[t, agent] if agent is not None else mac_done[t].any()
        if kept:
            # the running macro-action(s) started k steps ago; t_m agrees (a cross-check of the fixture)
            expect = int(t_m[t, agent]) if agent is not None else int(t_m[t].min())
            assert expect + 1 == k, (t, agent, expect, k)
            out.append(dict(step=t, start=t - k + 1, tau=k, R=acc, terminal=end == "terminated" and t == length - 1))
    return out


def original_n_step_returns(entries, boot, gamma, n_step):
    """MacroMARL's ``_get_bootstrap_return`` on one squeezed sequence, in its own form: absolute-step discounts
    ``D_k = γ^{step_k}`` (``D_{−1} = γ^{−1}``); the last ``n`` entries Monte-Carlo to the end (bootstrapped there
    with ``γ^{τ}`` V unless terminal), earlier ones ``R_k + Σ_{j=1}^{n−1} D_{k+j−1}/D_{k−1} R_{k+j} +
    D_{k+n−1}/D_{k−1} V_{k+n−1}``; n = 1: ``R_k + γ^{τ_k} V_k (1 − terminal_k)``.

    ``boot[k]``: the target critic's value after entry k. Returns a list of floats.
    """
    count = len(entries)
    if not count:
        return []
    d = [gamma ** e["step"] for e in entries]
    d_prev = lambda k: gamma ** -1 if k == 0 else d[k - 1]  # noqa: E731
    mac_discount = [d[k] / d_prev(k) for k in range(count)]
    if n_step == 1:
        return [e["R"] + (0.0 if e["terminal"] else mac_discount[k] * boot[k]) for k, e in enumerate(entries)]
    g = [e["R"] for e in entries]
    end = count - 1
    if not entries[end]["terminal"]:
        g[end] += mac_discount[end] * boot[end]
    for idx in range(end - 1, -1, -1):
        if idx > end - n_step:
            g[idx] = g[idx] + mac_discount[idx] * g[idx + 1]
        else:
            total = entries[idx]["R"]
            for j in range(1, n_step):
                total += d[idx + j - 1] / d_prev(idx) * entries[idx + j]["R"]
            g[idx] = total + d[idx + n_step - 1] / d_prev(idx) * boot[idx + n_step - 1]
    return g


def joint_index(joint, step):
    """Position of the Mac-JERT entry kept at primitive step ``step`` (searched, not counted)."""
    hits = [j for j, e in enumerate(joint) if e["step"] == step]
    assert len(hits) == 1, (step, hits)
    return hits[0]


def joint_start_index(joint, start):
    """Position of the Mac-JERT entry whose decision row is ``start``."""
    hits = [j for j, e in enumerate(joint) if e["start"] == start]
    assert len(hits) == 1, (start, hits)
    return hits[0]


# --- policies ----------------------------------------------------------------------------------------------------


def log_pi_epsilon(logits, count, epsilon):
    """log of ``(1 − ε) softmax(logits[:count]) + ε / count`` over the first ``count`` actions (float64)."""
    x = np.asarray(logits[:count], np.float64)
    p = np.exp(x - x.max())
    p /= p.sum()
    with np.errstate(divide="ignore"):
        return np.log((1.0 - epsilon) * p + epsilon / count)


def restricted(probs, allowed):
    """``probs`` restricted to ``allowed`` and renormalised."""
    q = np.where(allowed, probs, 0.0)
    return q / q.sum()


def allowed_joint(avail, free, running, counts):
    """bool[Π counts]: joint actions whose busy agents keep ``running`` and whose free agents pick available ones,
    by enumeration."""
    out = np.zeros(int(np.prod(counts)), bool)
    for joint in itertools.product(*[range(c) for c in counts]):
        ok = all((avail[i, a] if free[i] else a == running[i]) for i, a in enumerate(joint))
        out[np.ravel_multi_index(joint, counts)] = ok
    return out


# --- nets stepped one entry at a time ---------------------------------------------------------------------------

_STEPS = {}


def jitted_apply(net):
    if net not in _STEPS:
        _STEPS[net] = jax.jit(net.apply)
    return _STEPS[net]


def agent_sequence(net, params, i, xs, n):
    """Agent i's net of an ``AgentDRQN`` run one input at a time from a zero state (the other agents get zero
    inputs: their parameters are separate). Returns a list of f32[out]."""
    step = jitted_apply(net)
    h, out = jnp.zeros((n, net.hidden)), []
    for x in xs:
        inp = np.zeros((1, n, len(x)), np.float32)
        inp[0, i] = x
        y, h = step(params, jnp.asarray(inp), jnp.zeros((1,), bool), h)
        out.append(np.asarray(y[0, i], np.float64))
    return out


def shared_input_sequence(net, params, xs, n):
    """Every agent's net of an ``AgentDRQN`` on the same inputs, one at a time: a list of f32[n, out]."""
    step = jitted_apply(net)
    h, out = jnp.zeros((n, net.hidden)), []
    for x in xs:
        inp = np.broadcast_to(np.asarray(x, np.float32), (1, n, len(x)))
        y, h = step(params, jnp.asarray(inp), jnp.zeros((1,), bool), h)
        out.append(np.asarray(y[0], np.float64))
    return out


def single_sequence(net, params, xs):
    """A ``DRQN`` run one input at a time from a zero state: a list of f32[out]."""
    step = jitted_apply(net)
    h, out = jnp.zeros((net.hidden,)), []
    for x in xs:
        y, h = step(params, jnp.asarray(x, jnp.float32).reshape(1, -1), jnp.zeros((1,), bool), h)
        out.append(np.asarray(y[0], np.float64))
    return out
