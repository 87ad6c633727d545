"""Trace adapter for Overcooked (format: ``docs/traces.md``).

Two replays, run together as lanes of one compiled ``vmap(scan(step))`` (see ``replayer``):

* one-step: every transition from its recorded pre-state;
* rollout: every episode from reset, fed only ``t_mac_in``, which also checks that inputs of
  running agents are ignored (the ``junk`` episodes send random indices for them).

Every recorded field is compared: world state, grid, beliefs and belief maps, macro bookkeeping,
observations (cached and fresh), global state, primitive actions, reward, done, truncation.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.conformance.common import FileReport, TraceAdapter, compare_fields, register_adapter
from envs_jax.core import EnvState

# Float fields: observations are k/7 and c/3 in float64 in the original, float32 here; the reward
# is float32 here, whose spacing at 200 is 1.5e-5, so it gets a looser (still exact-in-float32) tolerance.
ATOL = {"obs": 1e-6, "obs_real": 1e-6, "gstate": 1e-6, "reward": 1e-4}
STATE_FIELDS = ("pos", "chop", "chopped", "hold", "plate_has", "knife_hold", "deliv_hold", "grid", "belief",
                "pomap", "mac_cur", "mac_done", "chop_ctr", "obs", "gstate")


def _detects(data: Mapping[str, np.ndarray]) -> bool:
    return "s_pomap" in data and "s_knife_hold" in data and "meta_json" in data


@functools.cache
def replayer(map_type: str, horizon: int):
    """(env, jitted replay) for one map, cached so that re-checking a file does not recompile.

    ``replay(pre, actions, one_step)`` runs lanes [M] of ``L`` steps each: a lane with
    ``one_step`` steps from the recorded pre-state ``pre[m, t]`` at every step, the others carry
    their own state from reset (a rollout fed only the recorded inputs). Both kinds share one
    compiled scan. Also returns our reset state's fields."""
    from envs_jax.registry import make

    env = make(f"overcooked-{map_type}", horizon=horizon)
    key = jax.random.key(0)

    @jax.jit
    def replay(pre: EnvState, actions: jax.Array, one_step: jax.Array):
        s0, ts0 = env.reset(key)

        def lane(pre_m, actions_m, one_step_m):
            def body(carry, inp):
                pre_t, a = inp
                state = jax.tree_util.tree_map(lambda r, c: jnp.where(one_step_m, r, c), pre_t, carry)
                nxt, ts = env.step(key, state, a)
                return nxt, _transition(env, nxt, ts)

            return jax.lax.scan(body, s0, (pre_m, actions_m))[1]

        return _observed(env, s0, ts0), jax.vmap(lane)(pre, actions, one_step)

    return env, replay


def trace_state(data: Mapping[str, np.ndarray], rows: np.ndarray, t: np.ndarray) -> EnvState:
    """``EnvState`` (numpy leaves, batched) of the recorded states ``rows``, at episode step ``t``."""
    from envs_jax.overcooked.world import OvercookedState

    i32 = lambda k: np.asarray(data[k][rows], np.int32)
    n = len(rows)
    core = OvercookedState(
        pos=i32("s_pos"),
        chop=i32("s_chop"),
        hold=i32("s_hold"),
        plate_has=np.asarray(data["s_plate_has"][rows], bool),
        knife_hold=i32("s_knife_hold"),
        deliv_hold=i32("s_deliv_hold"),
        belief=i32("s_belief"),
        chop_ctr=i32("s_chop_ctr"),
        prim=np.full((n, 3), 4, np.int32),
    )
    return EnvState(
        core=core,
        obs_macro=np.asarray(data["s_obs"][rows], np.float32),
        mac=i32("s_mac_cur"),
        mac_done=np.asarray(data["s_mac_done"][rows], bool),
        t_m=np.zeros((n, 3), np.int32),  # not recorded; does not affect the dynamics
        t=np.asarray(t, np.int32),
    )


def _observed(env, state: EnvState, ts) -> dict[str, jax.Array]:
    """Our values of the recorded state fields (one state, unbatched)."""
    from envs_jax.overcooked import world

    core = state.core
    return {
        "pos": core.pos,
        "chop": core.chop,
        "chopped": core.chop == 3,
        "hold": core.hold,
        "plate_has": core.plate_has,
        "knife_hold": core.knife_hold,
        "deliv_hold": core.deliv_hold,
        "grid": world.true_grid(env.layout, core),
        "belief": core.belief,
        "pomap": env.belief_maps(state),
        "mac_cur": state.mac,
        "mac_done": state.mac_done,
        "chop_ctr": core.chop_ctr,
        "obs": ts.obs_macro,
        "gstate": ts.state,
    }


def _transition(env, state: EnvState, ts) -> dict[str, jax.Array]:
    out = _observed(env, state, ts)
    out.update(
        prim=state.core.prim,
        reward=ts.reward,
        done=ts.terminated,
        truncated=ts.truncated,
        # Fresh observations must equal the emitted ones wherever a macro-action just ended.
        obs_real=jnp.where(state.mac_done[:, None], ts.obs_real, 0.0),
    )
    return out


def _expected(data, meta, next_rows: np.ndarray, step: np.ndarray, ep: np.ndarray, trans: np.ndarray):
    """Recorded values for transitions ``trans`` (flat) whose post-states are ``next_rows``."""
    exp = {f: data[f"s_{f}"][next_rows] for f in STATE_FIELDS}
    exp["chopped"] = exp["chopped"].astype(bool)
    exp["plate_has"] = exp["plate_has"].astype(bool)
    exp["mac_done"] = exp["mac_done"].astype(bool)
    exp["prim"] = data["t_prim"][trans]
    exp["reward"] = data["t_reward"][trans]
    exp["done"] = data["t_done"][trans].astype(bool)
    truncated_ep = np.array([bool(e["truncated"]) for e in meta["episodes"]])
    exp["truncated"] = truncated_ep[ep] & (step + 1 == data["ep_len"][ep])
    exp["obs_real"] = np.where(exp["mac_done"][..., None], exp["obs"], 0.0)
    return exp


def _to_episodes(flat: dict, ep: np.ndarray, step: np.ndarray, n_ep: int, max_len: int) -> dict:
    out = {}
    for k, v in flat.items():
        v = np.asarray(v)
        pad = np.zeros((n_ep, max_len, *v.shape[1:]), v.dtype)
        pad[ep, step] = v
        out[k] = pad
    return out


def check(path: str, data: Mapping[str, np.ndarray]) -> FileReport:
    meta = json.loads(str(data["meta_json"]))
    _, replay = replayer(str(meta["map_type"]), int(meta["horizon"]))
    ep_len = data["ep_len"].astype(np.int64)
    n_ep, max_len = len(ep_len), int(ep_len.max())
    ep = np.repeat(np.arange(n_ep), ep_len)
    step = np.concatenate([np.arange(n) for n in ep_len])
    trans = data["ep_step_start"][ep] + step
    rows = data["ep_state_start"][ep] + step
    valid = np.arange(max_len)[None, :] < ep_len[:, None]
    expected = _to_episodes(_expected(data, meta, rows + 1, step, ep, trans), ep, step, n_ep, max_len)

    # Pre-states and inputs laid out [episode, step]; padding repeats the episode's first state.
    pre_rows = np.repeat(data["ep_state_start"][:, None], max_len, axis=1)
    pre_rows[ep, step] = rows
    # Lanes 0..E-1: rollouts from reset; lanes E..2E-1: one-step replays from recorded states.
    pre_rows = np.concatenate([pre_rows, pre_rows])
    pre = trace_state(data, pre_rows.reshape(-1), np.tile(np.arange(max_len), 2 * n_ep))
    pre = jax.tree_util.tree_map(lambda x: x.reshape(2 * n_ep, max_len, *x.shape[1:]), pre)
    actions = np.zeros((n_ep, max_len, 3), np.int32)
    actions[ep, step] = data["t_mac_in"][trans]
    one_step = np.repeat([False, True], n_ep)
    got_reset, got = jax.device_get(replay(pre, np.concatenate([actions, actions]), one_step))
    ok_roll, first_roll = compare_fields(expected, {k: v[:n_ep] for k, v in got.items()}, valid, ATOL, mode="rollout")
    ok_one, first = compare_fields(expected, {k: v[n_ep:] for k, v in got.items()}, valid, ATOL, mode="one-step")

    # The reset state (state 0 of every episode) must match too; a mismatch there counts against step 0.
    reset_rows = data["ep_state_start"]
    exp_reset = _expected(data, meta, reset_rows, np.full(n_ep, -5), np.arange(n_ep), data["ep_step_start"])
    exp_reset = {k: v[:, None] for k, v in exp_reset.items() if k in STATE_FIELDS}
    got_reset = {k: np.broadcast_to(np.asarray(got_reset[k]), (n_ep, *np.shape(got_reset[k])))[:, None] for k in exp_reset}
    ok_reset, first_reset = compare_fields(exp_reset, got_reset, np.ones((n_ep, 1), bool), ATOL, mode="reset")
    ok_roll[:, 0] &= ok_reset[:, 0]

    firsts = [m for m in (first, first_reset, first_roll) if m is not None]
    first = min(firsts, key=lambda m: (m.episode, m.step)) if firsts else None
    matched = int(np.sum(ok_one & ok_roll & valid))
    return FileReport(path, "overcooked", n_ep, int(valid.sum()), matched, first)


register_adapter(TraceAdapter("overcooked", _detects, check))
