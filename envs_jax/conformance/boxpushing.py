"""Box Pushing trace adapter (format: ``docs/traces.md``).

Two checks per file, both on device and vectorised:

* one-step: every valid transition ``(e, t)`` is replayed from the recorded pre-state
  ``S_t`` with ``action[e, t]`` (one ``vmap`` over all of them) and compared with ``S_{t+1}``;
* rollout: every episode is replayed from ``S_0`` (our ``reset`` for ``from_reset``
  episodes, which must equal ``S_0``) with the recorded actions, busy agents' entries
  replaced by junk (−1) to prove they are ignored; the runner's per-agent and joint
  macro-reward accumulators, the discounted return and the horizon truncation are
  rebuilt from our ``t_m``/``mac_done`` and compared as well.
"""

from __future__ import annotations

from typing import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.boxpushing import BoxPushing, BoxPushingConfig, BoxPushingCore
from envs_jax.conformance.common import FileReport, Mismatch, TraceAdapter, compare_fields, register_adapter
from envs_jax.core import EnvState

STATE_FIELDS = ("agent_xy", "agent_ori", "cur_mac", "mac_done", "last_wp", "pushing_bb", "box_xy", "obs", "state")
FLOAT_ATOL = {"state": 1e-5, "reward": 1e-5, "mac_reward": 1e-4, "joint_mac_reward": 1e-4}


def _detects(d: Mapping[str, np.ndarray]) -> bool:
    return {"agent_xy", "box_xy", "pushing_bb", "grid"} <= set(d)


def env_for_trace(d: Mapping[str, np.ndarray]) -> BoxPushing:
    config = BoxPushingConfig(
        grid=int(d["grid"]),
        big_box_reward=float(d["big_box_reward"]),
        small_box_reward=float(d["small_box_reward"]),
        penalty=float(d["penalty"]),
        horizon=int(d["max_steps"]),
        discount=float(d["gamma"]),
    )
    return BoxPushing(config)


def state_from_trace(d: Mapping[str, np.ndarray], t: np.ndarray | int) -> EnvState:
    """EnvState batched over episodes ``[E]`` at state index ``t`` (scalar or i32[E])."""
    e = np.arange(d["agent_xy"].shape[0])
    take = lambda k: np.asarray(d[k])[e, t]  # noqa: E731
    box = take("box_xy")
    core = BoxPushingCore(
        pos=jnp.asarray(np.rint(take("agent_xy") - 0.5), jnp.int32),
        head=jnp.asarray(take("agent_ori"), jnp.int32),
        wp=jnp.asarray(take("last_wp"), jnp.int32),
        lock=jnp.asarray(take("pushing_bb"), bool),
        box_row=jnp.asarray(np.rint(box[..., 1] - 0.5), jnp.int32),  # columns are static
    )
    return EnvState(
        core=core,
        obs_macro=jnp.asarray(take("obs"), jnp.float32),
        mac=jnp.asarray(take("cur_mac"), jnp.int32),
        mac_done=jnp.asarray(take("mac_done"), bool),
        t_m=jnp.zeros(take("cur_mac").shape, jnp.int32),  # not recorded; does not affect dynamics
        t=jnp.full(e.shape, t, jnp.int32),
    )


def trace_view(env: BoxPushing, state: EnvState, ts) -> dict[str, jax.Array]:
    """Our (batched) state/timestep in the trace's field conventions."""
    col = jnp.asarray(env.layout.box_col, jnp.float32) + jnp.array([0.5, 0.5, 1.0])
    box_y = state.core.box_row.astype(jnp.float32) + 0.5
    return {
        "agent_xy": state.core.pos.astype(jnp.float32) + 0.5,
        "agent_ori": state.core.head,
        "cur_mac": state.mac,
        "mac_done": state.mac_done,
        "last_wp": state.core.wp,
        "pushing_bb": state.core.lock,
        "box_xy": jnp.stack([jnp.broadcast_to(col, box_y.shape), box_y], -1),
        "obs": state.obs_macro,
        "state": ts.state,
    }


def _one_step(env: BoxPushing, d: Mapping[str, np.ndarray]):
    E, L = d["valid"].shape
    flat = {k: np.asarray(d[k])[:, :L].reshape(E * L, *d[k].shape[2:]) for k in STATE_FIELDS if k != "state"}
    pre = state_from_trace({k: v[:, None] for k, v in flat.items()}, 0)
    pre = pre.replace(t=jnp.asarray(np.tile(np.arange(L), E), jnp.int32))
    actions = jnp.asarray(d["action"].reshape(E * L, 2), jnp.int32)
    keys = jax.random.split(jax.random.key(0), E * L)
    post, ts = jax.jit(jax.vmap(env.step))(keys, pre, actions)
    got = {k: np.asarray(v).reshape(E, L, *np.shape(v)[1:]) for k, v in trace_view(env, post, ts).items()}
    got["reward"] = np.asarray(ts.reward).reshape(E, L)
    got["terminate"] = np.asarray(ts.terminated).reshape(E, L)
    expected = {k: np.asarray(d[k])[:, 1:] for k in STATE_FIELDS}
    expected["reward"] = d["reward"]
    expected["terminate"] = d["terminate"]
    return compare_fields(expected, got, d["valid"], FLOAT_ATOL, mode="one-step")


def _rollout(env: BoxPushing, d: Mapping[str, np.ndarray]):
    E, L = d["valid"].shape
    gamma = env.spec.discount
    start = state_from_trace(d, 0)
    reset_state, reset_ts = env.reset(jax.random.key(0))
    from_reset = np.asarray(d["from_reset"])
    # Our reset must reproduce S_0 of every from_reset episode.
    reset_view = jax.tree_util.tree_map(lambda x: np.broadcast_to(np.asarray(x), (E,) + np.shape(x)),
                                        trace_view(env, reset_state, reset_ts))
    reset_ok, reset_mismatch = compare_fields(
        {k: np.asarray(d[k])[:, :1] for k in STATE_FIELDS},
        {k: v[:, None] for k, v in reset_view.items()},
        from_reset[:, None], FLOAT_ATOL, mode="reset",
    )
    start = jax.tree_util.tree_map(
        lambda r, s: jnp.where(jnp.asarray(from_reset).reshape((E,) + (1,) * (s.ndim - 1)), r, s),
        jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (E,) + x.shape), reset_state), start,
    )
    # Synthetic starts: the runner's accumulators start fresh at S_0, as if busy agents had
    # just started their macro-action; t_m = -1 makes our progress 0 on the first step.
    start = start.replace(t_m=jnp.where(jnp.asarray(from_reset)[:, None] | start.mac_done, 0, -1))
    actions = jnp.asarray(d["action"], jnp.int32)  # [E, L, 2]
    valid = jnp.asarray(d["valid"], jnp.float32)

    def episode(state, acts, valid):
        def body(carry, inp):
            a, v = inp
            state, acc, joint_acc, ret, disc = carry
            free = state.mac_done
            junk = jnp.where(free, a, -1)  # busy agents' entries must be ignored
            state, ts = env.step(jax.random.key(0), state, junk)
            r = ts.reward
            acc = jnp.where(free, r, acc + gamma ** ts.t_m.astype(jnp.float32) * r)
            joint_k = jnp.where(jnp.any(free), 0, joint_acc[1] + 1)
            joint_r = jnp.where(jnp.any(free), r, joint_acc[0] + gamma ** joint_k.astype(jnp.float32) * r)
            ret = ret + v * disc * r
            out = (trace_view(env, state, ts), r, ts.terminated, ts.truncated, acc, joint_r)
            return (state, acc, (joint_r, joint_k), ret, disc * gamma), out

        init = (state, jnp.zeros(2), (jnp.zeros(()), -jnp.ones((), jnp.int32)), jnp.zeros(()), jnp.ones(()))
        (_, _, _, ret, _), outs = jax.lax.scan(body, init, (acts, valid))
        return outs, ret

    (view, reward, term, trunc, acc, joint), ret = jax.jit(jax.vmap(episode))(start, actions, valid)
    got = {k: np.asarray(v) for k, v in view.items()}
    got.update(reward=np.asarray(reward), terminate=np.asarray(term),
               mac_reward=np.asarray(acc), joint_mac_reward=np.asarray(joint))
    expected = {k: np.asarray(d[k])[:, 1:] for k in STATE_FIELDS}
    expected.update(reward=d["reward"], terminate=d["terminate"],
                    mac_reward=d["mac_reward"], joint_mac_reward=d["joint_mac_reward"])
    ok, first = compare_fields(expected, got, d["valid"], FLOAT_ATOL, mode="rollout")

    # Episode level: discounted return, and truncation exactly at the horizon (reset episodes).
    length = np.asarray(d["length"]).astype(int)
    last = np.clip(length - 1, 0, L - 1)
    trunc_last = np.asarray(trunc)[np.arange(E), last]
    episode_checks = [
        ("disc_ret", np.isclose(np.asarray(ret), d["disc_ret"], atol=1e-3), np.asarray(ret), d["disc_ret"]),
        ("truncated", ~from_reset | (trunc_last == d["truncated"]), trunc_last, d["truncated"]),
    ]
    for name, good, ours, theirs in episode_checks:
        for e in np.flatnonzero(~good):
            ok[e, : length[e]] = False
            cand = Mismatch(int(e), int(last[e]), name, repr(theirs[e]), repr(ours[e]), "rollout")
            if first is None or (cand.episode, cand.step) < (first.episode, first.step):
                first = cand
    for e in np.flatnonzero(~reset_ok[:, 0]):
        ok[e] = False
        first = first if first is not None and first.episode < e else reset_mismatch
    return ok, first


def check(path: str, d: Mapping[str, np.ndarray]) -> FileReport:
    env = env_for_trace(d)
    valid = np.asarray(d["valid"], bool)
    ok_step, first_step = _one_step(env, d)
    ok_roll, first_roll = _rollout(env, d)
    firsts = [m for m in (first_step, first_roll) if m is not None]
    first = min(firsts, key=lambda m: (m.episode, m.step)) if firsts else None
    return FileReport(
        path=path,
        format="boxpushing",
        episodes=int(valid.shape[0]),
        transitions=int(valid.sum()),
        matched=int((ok_step & ok_roll & valid).sum()),
        first_mismatch=first,
    )


register_adapter(TraceAdapter("boxpushing", _detects, check))
