"""Warehouse trace adapter (format: ``docs/traces.md``).

Rows of all episodes are concatenated; row 0 of an episode is its reset, row t >= 1 the
result of step t. Two checks per file, each one compiled, vectorised call:

* one-step: every transition is replayed from its recorded pre-state (row t-1, internal
  state rebuilt exactly, see :func:`state_from_rows`) with ``action_in[t]`` — a single
  ``vmap`` over all transitions of the file — and compared with row t;
* rollout: every episode is replayed from our ``reset`` (compared with its reset row)
  with the recorded actions, busy agents' entries replaced by junk (-1) to prove they are
  ignored (``vmap`` over episodes of a ``lax.scan`` over steps).

Every recorded field is compared: step I/O (obs, cur_mac, mac_done, reward, done/
truncated, state) and every internal field we keep (positions, waypoints, timers, baskets,
F's action/timer/failed flag/staging/search counts, humans, step counter), plus our
macro-action progress ``t_m`` against the one implied by the recorded ``mac_done``.
Paper-config files (no noise) are compared bit-exactly: positions and robot timers are
reconstructed in float64 from our integer state, and the (float32) global state vector must
equal the float32 rounding of the recorded float64 one. ``_noise`` files run the
continuous-motion path with the recorded draws injected
(:class:`~envs_jax.warehouse.InjectedNoiseEnv`); their positions (and the position entries
of the state) are float32 computations and get ``atol``.

Our ``terminated`` is the env's ``done`` (the task is done, or E's horizon: SPEC §12.9);
our ``truncated`` is the horizon cut without it (the trace's ``truncated & ~done``).
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.conformance.common import FileReport, Mismatch, TraceAdapter, compare_fields, register_adapter
from envs_jax.core import EnvState
from envs_jax.warehouse import InjectedNoiseEnv, Noise, WarehouseCore, WarehouseEnv, make_warehouse
from envs_jax.warehouse import variants as V

ATOL: dict[str, float] = {}  # exact motion: everything exact (state: the float32 rounding of the trace's)
ATOL_NOISE = {"state": 1e-5, "rb_xy": 1e-5}  # float32 positions under motion noise


def _detects(d: Mapping[str, np.ndarray]) -> bool:
    return {"rb_xy", "f_staging", "h_step", "meta_json"} <= set(d)


def env_for_trace(meta: dict) -> WarehouseEnv:
    """Our env for a trace's constructor kwargs (``ValueError`` for settings we do not model)."""
    kw = meta["env_kwargs"]
    fixed = {"TB_move_speed": V.SPEED_CENTS / 100, "fetch_pass_obj_tc": V.PASS_DURATION,
             "fetch_look_for_obj_tc": V.SEARCH_DURATION, "TB_move_cost": 0.0, "obs_human_wait": False}
    for key, value in fixed.items():
        if kw.get(key, value) != value:
            raise ValueError(f"trace uses {key}={kw[key]!r}; only {value!r} is modelled")
    noisy = bool(kw["TB_move_noisy"]) or bool(kw["fetch_manip_noisy"])
    env = make_warehouse(
        meta["variant"],
        horizon=int(meta["horizon"]),
        human_durations=tuple(tuple(int(x) for x in row) for row in kw["human_speed_per_step"]),
        n_each_obj=int(meta["n_each_obj"]),
        delay_penalty=float(kw["delay_delivery_penalty"]),
        move_noise_std=float(kw["TB_move_noisy"]),
        fetch_duration_noise=bool(kw["fetch_manip_noisy"]),
    )
    if int(kw.get("terminate_step", meta["horizon"])) != int(meta["horizon"]) and env.config.done_at_horizon:
        raise ValueError("trace's terminate_step differs from its horizon; not modelled")
    return _cached_env(meta["variant"], env.config, noisy)


@functools.lru_cache(maxsize=32)
def _cached_env(variant: str, config: V.WarehouseConfig, injected: bool) -> WarehouseEnv:
    """One env object per configuration, so that compiled replays are reused across files."""
    cls = InjectedNoiseEnv if injected else WarehouseEnv
    return cls(V.LAYOUTS[variant], config, f"warehouse-{variant}")


def _expected_t_m(d: Mapping[str, np.ndarray]) -> np.ndarray:
    """Macro-action progress implied by the recorded ``mac_done`` (0 when free to choose)."""
    t_m = np.zeros(d["mac_done"].shape, np.int32)
    for r in range(1, len(t_m)):
        if d["t"][r] > 0:
            t_m[r] = np.where(d["mac_done"][r - 1], 0, t_m[r - 1] + 1)
    return t_m


def _points(env: WarehouseEnv, xy: np.ndarray) -> np.ndarray:
    """Motion-graph point ids of float64 positions ``[R, nT, 2]`` (-1 if not on the graph)."""
    g = env.graph
    out = np.full(xy.shape[:2], -1, np.int32)
    for i in range(env.n_robots):
        lookup = {g.xy64[i, p].tobytes(): p for p in range(g.n_points[i])}
        out[:, i] = [lookup.get(np.ascontiguousarray(x).tobytes(), -1) for x in xy[:, i]]
    return out


def _tau_cents(tleft: np.ndarray) -> np.ndarray:
    """Robot timers in 1/100 (positive ones are ``round2(d) - 0.8``)."""
    return np.rint(tleft * 100).astype(np.int32)


def _tau_float64(tau: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_tau_cents`, bit-exact w.r.t. the reference's ``dist - speed``."""
    tau = np.asarray(tau).astype(np.int64)
    travelling = (tau + V.SPEED_CENTS).astype(np.float64) / 100.0 - V.SPEED_CENTS / 100
    return np.where(tau > 0, travelling, tau / 100.0)


def state_from_rows(
    env: WarehouseEnv, d: Mapping[str, np.ndarray], rows: np.ndarray, t_m: np.ndarray
) -> tuple[EnvState, np.ndarray]:
    """Batched EnvState (numpy leaves) rebuilt from recorded rows (their full internal
    state), and the motion-graph points of the recorded positions (-1 off the graph;
    exact mode only)."""
    take = lambda k: np.asarray(d[k])[rows]
    xy = take("rb_xy")
    pt = _points(env, xy) if env.exact_motion else np.zeros(xy.shape[:2], np.int32)
    core = WarehouseCore(
        rb_xy=np.asarray(xy, np.float32),
        rb_pt=np.asarray(np.maximum(pt, 0)),
        rb_wp=np.asarray(take("rb_wp"), np.int32),
        rb_tau=np.asarray(_tau_cents(take("rb_tleft"))),
        basket=np.asarray(take("rb_basket"), np.int32),
        f_act=np.asarray(take("f_act"), np.int32),
        f_tau=np.asarray(np.rint(take("f_tleft")), np.int32),
        f_failed=np.asarray(take("f_failed")),
        staging=np.asarray(take("f_staging"), np.int32),
        found=np.asarray(take("f_found_count"), np.int32),
        h_phase=np.asarray(take("h_step"), np.int32),
        h_time=np.asarray(np.rint(take("h_tleft")), np.int32),
        h_got=np.asarray(take("h_obtained")),
        h_fin=np.asarray(take("h_finished")),
        served=np.asarray(take("h_served")),
        count_step=np.asarray(take("count_step"), np.int32),
    )
    mac = np.concatenate([take("rb_act"), take("f_act")[:, None]], axis=1)
    done = np.concatenate([take("rb_done"), take("f_done")[:, None]], axis=1)
    return EnvState(
        core=core,
        obs_macro=np.asarray(take("obs"), np.float32),
        mac=np.asarray(mac, np.int32),
        mac_done=np.asarray(done),
        t_m=np.asarray(t_m[rows]),
        t=np.asarray(take("count_step"), np.int32),
    ), pt


def noise_from_rows(d: Mapping[str, np.ndarray], rows: np.ndarray) -> Noise:
    move = np.where(d["noise_move_drawn"][rows][..., None], d["noise_move"][rows], 0.0)
    fetch = np.where(d["noise_fetch_drawn"][rows], d["noise_fetch"][rows], 0)
    return Noise(move=move.astype(np.float32), fetch=fetch.astype(np.int32))


def view(env: WarehouseEnv, state: EnvState, ts) -> dict[str, jax.Array]:
    """Our (batched) state/timestep under the trace's field names (still integer-coded)."""
    c, n_t = state.core, env.n_robots
    return {
        "obs": ts.obs_macro, "cur_mac": ts.mac, "mac_done": ts.mac_done, "reward": ts.reward,
        "done": ts.terminated, "truncated": ts.truncated, "state": ts.state, "t_m": ts.t_m,
        "rb_xy": c.rb_xy, "rb_pt": c.rb_pt, "rb_wp": c.rb_wp, "rb_act": state.mac[..., :n_t],
        "rb_tau": c.rb_tau, "rb_done": state.mac_done[..., :n_t], "rb_basket": c.basket,
        "f_act": c.f_act, "f_tau": c.f_tau, "f_done": state.mac_done[..., n_t], "f_failed": c.f_failed,
        "f_staging": c.staging, "f_found_count": c.found, "h_step": c.h_phase, "h_tleft": c.h_time,
        "h_obtained": c.h_got, "h_finished": c.h_fin, "h_served": c.served, "count_step": c.count_step,
    }


def to_trace_units(env: WarehouseEnv, got: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Convert integer-coded fields to the reference's float64 values (exactly)."""
    got = dict(got)
    if env.exact_motion:
        pt = got["rb_pt"]
        got["rb_xy"] = env.graph.xy64[np.arange(env.n_robots), pt]
    got.pop("rb_pt")
    got["rb_tleft"] = _tau_float64(got.pop("rb_tau"))
    got["f_tleft"] = got.pop("f_tau").astype(np.float64)
    got["h_tleft"] = got["h_tleft"].astype(np.float64)
    return got


def expected_rows(d: Mapping[str, np.ndarray], rows: np.ndarray, t_m: np.ndarray) -> dict[str, np.ndarray]:
    out = {k: np.asarray(d[k])[rows] for k in (
        "obs", "cur_mac", "mac_done", "reward", "done", "state", "rb_xy", "rb_wp", "rb_act", "rb_tleft",
        "rb_done", "rb_basket", "f_act", "f_tleft", "f_done", "f_failed", "f_staging", "f_found_count",
        "h_step", "h_tleft", "h_obtained", "h_finished", "h_served", "count_step")}
    out["truncated"] = d["truncated"][rows] & ~d["done"][rows]
    out["t_m"] = t_m[rows]
    out["state"] = out["state"].astype(np.float32)  # our state vector is float32 by API
    return out


def _as_el(x: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Rows of transitions ``[E*L, ...]`` (episode-major) as ``[E, L, ...]``."""
    return np.asarray(x).reshape(*shape, *np.shape(x)[1:])


def _episode_rows(d):
    """Episode offsets, ``valid[E, L]`` transitions and their post-step ``rows[E, L]``
    (padding points at the episode's reset row)."""
    offsets = np.asarray(d["ep_offsets"])
    lengths = np.diff(offsets) - 1  # transitions per episode
    L = int(lengths.max())
    valid = np.arange(L)[None, :] < lengths[:, None]
    rows = np.where(valid, offsets[:-1, None] + 1 + np.arange(L)[None, :], offsets[:-1, None])
    return offsets, valid, rows


def _keys(env: WarehouseEnv, d, rows: np.ndarray):
    """Per-transition step "keys": the recorded draws for noise files, else (unused) PRNG keys."""
    if isinstance(env, InjectedNoiseEnv):
        return noise_from_rows(d, rows)
    return np.zeros((rows.size,), np.uint32)  # seeds, turned into keys in the compiled replay


@functools.lru_cache(maxsize=32)
def _replay_fn(env: WarehouseEnv, E: int, L: int):
    """The compiled replay of ``E`` episodes of ``L`` steps (see :func:`_replay`)."""
    injected = isinstance(env, InjectedNoiseEnv)

    def cat(a, b):
        return jnp.concatenate([a, b])

    def body(ours, xs):
        pre_t, keys_t, acts_t = xs
        junk = jnp.where(ours.mac_done, acts_t, -1)  # busy agents' entries must be ignored
        state = jax.tree_util.tree_map(cat, pre_t, ours)
        post, ts = jax.vmap(env.step)(jax.tree_util.tree_map(cat, keys_t, keys_t), state, cat(acts_t, junk))
        return jax.tree_util.tree_map(lambda x: x[E:], post), view(env, post, ts)

    @jax.jit
    def run(pre, keys, actions):
        if not injected:
            keys = jax.vmap(jax.random.key)(keys)
        keys = jax.tree_util.tree_map(lambda x: x.reshape(L, E, *x.shape[1:]), keys)
        reset_state, reset_ts = env.reset(jax.random.key(0))
        start = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (E,) + x.shape), reset_state)
        return view(env, reset_state, reset_ts), jax.lax.scan(body, start, (pre, keys, actions))[1]

    return run


def _replay(env: WarehouseEnv, d, t_m, atol):
    """One-step and rollout checks of a file in a single compiled ``lax.scan`` over time.

    At scan step t a batch of 2E lanes goes through one ``vmap(env.step)``: lanes 0..E-1
    replay transition t of every episode from its recorded pre-state (one-step check),
    lanes E..2E-1 carry our own episodes from ``reset`` (rollout check, busy agents'
    entries replaced by junk -1). One step in the program keeps compilation short.
    """
    offsets, valid, rows = _episode_rows(d)
    E, L = valid.shape
    tm_rows = rows.T  # [L, E] time-major
    pre, pt = state_from_rows(env, d, tm_rows.ravel() - 1, t_m)
    to_lel = lambda x: np.reshape(x, (L, E, *np.shape(x)[1:]))
    pre = jax.tree_util.tree_map(to_lel, pre)
    keys = _keys(env, d, tm_rows.ravel())
    actions = d["action_in"][tm_rows].astype(np.int32)  # [L, E, n]
    reset_view, outs = _replay_fn(env, E, L)(pre, keys, actions)
    outs = {k: np.swapaxes(np.asarray(v), 0, 1) for k, v in outs.items()}  # [2E, L, ...]
    exp = {k: _as_el(v, (E, L)) for k, v in expected_rows(d, rows.ravel(), t_m).items()}

    got = to_trace_units(env, {k: v[:E] for k, v in outs.items()})
    ok_step, first_step = compare_fields(exp, got, valid, atol, mode="one-step")
    if env.exact_motion:  # a pre-state off the motion graph cannot be replayed exactly
        off = (pt < 0).any(-1).reshape(L, E).T & valid
        ok_step &= ~off
        for e, t in np.argwhere(off)[:1]:
            cand = Mismatch(int(e), int(t), "rb_xy (pre-state not on the motion graph)", "on graph", "off", "one-step")
            first_step = cand if first_step is None or (e, t) < (first_step.episode, first_step.step) else first_step

    got = to_trace_units(env, {k: v[E:] for k, v in outs.items()})
    ok_roll, first_roll = compare_fields(exp, got, valid, atol, mode="rollout")
    # Report trace steps (transition index + 1; the reset row is step 0).
    first_step, first_roll = (None if m is None else dataclasses.replace(m, step=m.step + 1)
                              for m in (first_step, first_roll))
    # Reset rows must equal our reset.
    reset_got = to_trace_units(env, {k: np.broadcast_to(np.asarray(v), (E,) + np.shape(v))[:, None]
                                     for k, v in reset_view.items()})
    reset_exp = {k: v[:, None] for k, v in expected_rows(d, offsets[:-1], t_m).items()}
    reset_exp["reward"] = np.zeros_like(reset_exp["reward"])  # reset rows carry no step result
    reset_exp["cur_mac"] = np.full_like(reset_exp["cur_mac"], -1)
    reset_ok, reset_first = compare_fields(reset_exp, reset_got, np.ones((E, 1), bool), atol, mode="reset")
    for e in np.flatnonzero(~reset_ok[:, 0]):
        ok_roll[e] = False
        if first_roll is None or first_roll.episode > e:
            first_roll = reset_first
    return ok_step, first_step, ok_roll, first_roll


def check(path: str, d: Mapping[str, np.ndarray]) -> FileReport:
    meta = json.loads(str(d["meta_json"]))
    env = env_for_trace(meta)
    atol = ATOL if env.exact_motion else ATOL_NOISE
    t_m = _expected_t_m(d)
    ok_step, first_step, ok_roll, first_roll = _replay(env, d, t_m, atol)
    _, valid, _ = _episode_rows(d)
    firsts = [m for m in (first_step, first_roll) if m is not None]
    first = min(firsts, key=lambda m: (m.episode, m.step)) if firsts else None
    return FileReport(
        path=path,
        format="warehouse",
        episodes=int(valid.shape[0]),
        transitions=int(valid.sum()),
        matched=int((ok_step & ok_roll & valid).sum()),
        first_mismatch=first,
    )


register_adapter(TraceAdapter("warehouse", _detects, check))
