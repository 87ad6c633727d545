"""ToMacVF networks: temporal agent net (D2, D3), ATPG (D4, D5), mixers (D6, D19), conditional max (D9).

Tiny sizes, module-scope fixtures, few compiled functions. Test functions are compiled with XLA's
backend optimisation off (``tjit``): semantics are the same, compilation is ~4x cheaper on CPU, and
run time is irrelevant at these sizes. One test compares the default ``jax.jit`` with eager apply.
"""

import functools
import itertools
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _buffer_fixtures import config_for, synthetic_rollout

from jaxmac.buffer import episode, views
from jaxmac.encodings import EncodingConfig
from jaxmac.networks import (
    ATPG,
    AgentNetConfig,
    ATPGConfig,
    Mixer,
    MixerConfig,
    NetInputs,
    TemporalAgentNet,
    agent_features,
    init_agent_params,
    init_mixer_params,
    initial_carry,
    jert_inputs,
    mix,
    slot_inputs,
    take_rows,
    temporal_mask,
    timestep_inputs,
)
from jaxmac.ops import MASK_VALUE, gather_q, mask_unavailable, masked_argmax
from jaxmac.algos.targets import conditional_greedy

N, O, A, S, B, T = 3, 5, 4, 6, 2, 10
FAST = dict(xla_backend_optimization_level=0, xla_llvm_disable_expensive_passes=True)
tjit = functools.partial(jax.jit, compiler_options=FAST)


def fast_init(init_fn, config, key):
    """A library init (jitted with the config static) compiled with ``FAST``: a function of the key."""
    return init_fn.lower(config, key).compile(FAST)


def jitter(params, seed, scale=0.3):
    """Random parameters: the init plus Gaussian noise on every leaf (zero biases included)."""
    rng = np.random.default_rng(seed)
    return jax.tree_util.tree_map(lambda x: np.asarray(x) + scale * rng.normal(size=x.shape).astype(np.float32),
                                  params)
ENC = EncodingConfig(dim_t=8, dim_tm=4)


def random_inputs(seed, batch=(B,), length=T, n=N, reset_rows=(0,)):
    """Random but well-formed inputs: prev_mac ∈ [-1, A), progress, times 0..T-1."""
    rng = np.random.default_rng(seed)
    t = np.broadcast_to(np.arange(length, dtype=np.int32), batch + (length,))
    prev_mac = rng.integers(-1, A, batch + (length, n)).astype(np.int32)
    reset = np.zeros(batch + (length,), bool)
    reset[..., list(reset_rows)] = True
    return NetInputs(
        obs=jnp.asarray(rng.normal(size=batch + (length, n, O)), jnp.float32), t=jnp.asarray(t),
        prev_t=jnp.asarray(t - 1), prev_mac=jnp.asarray(prev_mac),
        prev_t_m=jnp.asarray(rng.integers(0, 6, batch + (length, n)), jnp.int32), reset=jnp.asarray(reset),
    )


def replace_rows(a: NetInputs, b: NetInputs, rows) -> NetInputs:
    """``a`` with the time rows ``rows`` taken from ``b`` (time axis 1)."""
    rows = np.asarray(rows)
    return jax.tree_util.tree_map(lambda x, y: x.at[:, rows].set(y[:, rows]), a, b)


def mixer_config(kind, n=N):
    atpg = ATPGConfig(num_agents=n, obs_dim=O, num_actions=A, embed=8, token_hidden=16, encoding=ENC)
    return MixerConfig(num_agents=n, state_dim=S, kind=kind, embed=8, hyper_hidden=16, atpg=atpg)


# ----------------------------------------------------------------------------------------
# fixtures (module scope: one init and one compile per function)


@pytest.fixture(scope="module")
def agent():
    cfg = AgentNetConfig(num_agents=N, obs_dim=O, num_actions=A, hidden=8, fc=16, head_hidden=(16,), encoding=ENC)
    net = TemporalAgentNet(cfg)
    init = fast_init(init_agent_params, cfg, jax.random.PRNGKey(0))
    seq = tjit(net.apply)
    step = tjit(functools.partial(net.apply, method="step"))
    return types.SimpleNamespace(cfg=cfg, net=net, params=init(jax.random.PRNGKey(0)), seq=seq, step=step, init=init)


def _weights(mixer, params, state, inputs):
    return mixer.apply(params, state, inputs)[0]


@pytest.fixture(scope="module")
def mixers():
    """kind -> (random params, compiled weights fn(params, state, inputs)); 'atpg_qmix' also
    returns its unperturbed init."""
    out = {}
    for k, kind in enumerate(("atpg_qmix", "qmix", "vdn")):
        cfg = mixer_config(kind)
        init = fast_init(init_mixer_params, cfg, jax.random.PRNGKey(0))
        params = init(jax.random.PRNGKey(10 + k))
        out[kind] = (jitter(params, k), tjit(functools.partial(_weights, Mixer(cfg))))
        if kind == "atpg_qmix":
            out["init"] = init
    return out


@pytest.fixture(scope="module")
def atpg(mixers):
    """ATPG with the (perturbed) ATPG parameters of the atpg_qmix mixer; full and windowed apply."""
    cfg = mixer_config("atpg_qmix").atpg
    params = {"params": mixers["atpg_qmix"][0]["params"]["atpg"]}
    full, win = ATPG(cfg), ATPG(ATPGConfig(**{**cfg.__dict__, "attn_window": 3}))
    both = tjit(lambda p, x: (full.apply(p, x), win.apply(p, x)))
    return cfg, params, both




# ----------------------------------------------------------------------------------------
# temporal agent network


def test_agent_shapes_masks_and_per_agent_params(agent):
    cfg, params, seq = agent.cfg, agent.params, agent.seq
    inputs = random_inputs(0)
    tau = jnp.zeros((B, T, N), jnp.int32)
    q, hs, carry = seq(params, inputs, initial_carry(cfg, (B,)), tau)
    assert q.shape == (B, T, N, A) and hs.shape == (B, T, N, cfg.hidden) and carry.shape == (B, N, cfg.hidden)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(carry, hs[:, -1])
    # one stacked parameter slice per agent, and they differ (split rngs over the agent axis)
    for leaf in jax.tree_util.tree_leaves(params):
        assert leaf.shape[0] == N
        if leaf.std() > 0:  # biases start at zero
            assert not np.allclose(leaf[0], leaf[1]) and not np.allclose(leaf[1], leaf[2])
    # agent i's Q reads agent i's parameter slice only: perturbing agent 1's slice moves agent 1's Q alone
    # (inputs carry a one-hot agent id, so "Q differs per agent" alone would hold with shared parameters too)
    moved = jax.tree_util.tree_map(lambda x: x.at[1].add(0.3), params)
    q_moved = seq(moved, inputs, initial_carry(cfg, (B,)), tau)[0]
    np.testing.assert_allclose(q_moved[..., [0, 2], :], q[..., [0, 2], :], rtol=1e-6, atol=1e-6)
    assert not np.allclose(q_moved[..., 1, :], q[..., 1, :])
    # action masks
    rng = np.random.default_rng(0)
    avail = rng.random(q.shape) < 0.5
    avail[..., 0] |= ~avail.any(-1)
    greedy = np.asarray(masked_argmax(q, avail))
    assert np.take_along_axis(avail, greedy[..., None], -1).all()
    np.testing.assert_array_equal(mask_unavailable(q, avail), np.where(avail, q, MASK_VALUE))
    ref = np.where(avail, np.asarray(q), -np.inf).argmax(-1)
    np.testing.assert_array_equal(greedy, ref)


def test_sequence_replay_equals_stepping_with_carries(agent):
    cfg, params, seq, step = agent.cfg, agent.params, agent.seq, agent.step
    inputs = random_inputs(1, reset_rows=(0, 6))  # an episode start in the middle too
    tau = jnp.asarray(np.random.default_rng(1).integers(0, 5, (B, T, N)), jnp.int32)
    junk = jax.random.normal(jax.random.PRNGKey(3), (B, N, cfg.hidden))  # erased by the reset at row 0
    q_seq, hs, carry_seq = seq(params, inputs, junk, tau)
    carry = initial_carry(cfg, (B,))
    for t in range(T):
        row = jax.tree_util.tree_map(lambda x: x[:, t], inputs)
        q_t, carry = step(params, row, carry, tau[:, t])
        np.testing.assert_allclose(q_t, q_seq[:, t], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(carry, hs[:, t], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(carry, carry_seq, rtol=1e-5, atol=1e-5)


def test_reset_in_the_middle_equals_a_fresh_start(agent):
    cfg, params, seq = agent.cfg, agent.params, agent.seq
    k = 4
    inputs = random_inputs(2, reset_rows=(0, k))
    tau = jnp.asarray(np.random.default_rng(2).integers(0, 5, (B, T, N)), jnp.int32)
    q, hs, _ = seq(params, inputs, initial_carry(cfg, (B,)), tau)
    # the suffix from row k as its own episode (padded back to T rows with rows from the start)
    roll = lambda x: jnp.roll(x, -k, axis=1)
    fresh = jax.tree_util.tree_map(roll, inputs)
    q_f, hs_f, _ = seq(params, fresh, initial_carry(cfg, (B,)), roll(tau))
    np.testing.assert_allclose(q_f[:, : T - k], q[:, k:], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(hs_f[:, : T - k], hs[:, k:], rtol=1e-5, atol=1e-5)
    # the head alone at other τ: same as the full apply with those τ, and τ matters
    head = tjit(functools.partial(agent.net.apply, method="q_values"))
    np.testing.assert_allclose(head(params, hs, tau), q, rtol=1e-5, atol=1e-5)
    assert not np.allclose(head(params, hs, tau + 1), q)
    # without the reset the history before k matters
    no_reset = inputs.replace(reset=inputs.reset.at[:, k].set(False))
    assert not np.allclose(seq(params, no_reset, initial_carry(cfg, (B,)), tau)[0][:, k:], q[:, k:])


def test_features_layout_and_dropping_absolute_time():
    inputs = random_inputs(3)
    features = tjit(agent_features, static_argnums=0)
    cfg = AgentNetConfig(num_agents=N, obs_dim=O, num_actions=A, encoding=ENC)
    x = np.asarray(features(cfg, inputs))
    assert x.shape == (B, T, N, cfg.feature_dim) == (B, T, N, O + 8 + A + 8 + 4 + N)
    np.testing.assert_array_equal(x[..., :O], inputs.obs)
    np.testing.assert_array_equal(x[..., -N:], np.broadcast_to(np.eye(N), (B, T, N, N)))
    act = x[..., O + 8: O + 8 + A + 8 + 4]
    none = np.asarray(inputs.prev_mac) < 0
    assert none.any() and np.all(act[none] == 0)  # no previous macro-action: whole block zero
    np.testing.assert_array_equal(act[~none][:, :A].argmax(-1), np.asarray(inputs.prev_mac)[~none])
    # use_t=False: the features no longer depend on absolute time
    cfg_nt = AgentNetConfig(num_agents=N, obs_dim=O, num_actions=A, encoding=EncodingConfig(8, 4, use_t=False))
    shifted = inputs.replace(t=inputs.t + 37, prev_t=inputs.prev_t + 37)
    x0, x1 = features(cfg_nt, inputs), features(cfg_nt, shifted)
    assert x0.shape[-1] == cfg_nt.feature_dim == O + A + 4 + N
    np.testing.assert_array_equal(x0, x1)
    assert not np.array_equal(features(cfg, inputs), features(cfg, shifted))


def test_jit_equals_eager_and_init_is_deterministic(agent, mixers):
    cfg, net, params, seq, init = agent.cfg, agent.net, agent.params, agent.seq, agent.init
    inputs = random_inputs(4)
    tau = jnp.zeros((B, T, N), jnp.int32)
    args = (inputs, initial_carry(cfg, (B,)), tau)
    eager = net.apply(params, *args)
    np.testing.assert_allclose(eager[0], jax.jit(net.apply)(params, *args)[0], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(eager[0], seq(params, *args)[0], rtol=1e-5, atol=1e-5)
    # init: deterministic for a key, different across keys
    same = lambda a, b: jax.tree_util.tree_all(jax.tree_util.tree_map(np.array_equal, a, b))
    assert same(params, init(jax.random.PRNGKey(0)))
    assert not np.array_equal(params["params"]["torso"]["fc"]["kernel"],
                              init(jax.random.PRNGKey(1))["params"]["torso"]["fc"]["kernel"])
    minit = mixers["init"]
    assert same(minit(jax.random.PRNGKey(5)), minit(jax.random.PRNGKey(5)))
    assert not same(minit(jax.random.PRNGKey(5)), minit(jax.random.PRNGKey(6)))
    # the mixer too (vanilla QMIX: eager ATPG costs seconds of op-by-op compilation; ATPG's own math
    # is checked against a NumPy reference in test_agent_attention_masks)
    state = jnp.asarray(np.random.default_rng(4).normal(size=(B, T, S)), jnp.float32)
    mparams, jitted_fn = mixers["qmix"]
    eager = Mixer(mixer_config("qmix")).apply(mparams, state, None)[0]
    jitted = jitted_fn(mparams, state, inputs)
    for a, b in zip(jax.tree_util.tree_leaves(eager), jax.tree_util.tree_leaves(jitted)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


# ----------------------------------------------------------------------------------------
# ATPG


def test_temporal_attention_is_causal_and_windowed(atpg):
    _, params, both = atpg
    a, b = random_inputs(5), random_inputs(6)
    base_full, base_win = both(params, a)
    for t in (0, 4, T - 2):
        changed = replace_rows(a, b, range(t + 1, T))  # change everything after row t
        out = both(params, changed)[0]
        for name in ("e", "e_hat", "alpha"):
            np.testing.assert_allclose(getattr(out, name)[:, : t + 1], getattr(base_full, name)[:, : t + 1],
                                       rtol=1e-5, atol=1e-6)
        assert not np.allclose(out.e[:, t + 1:], base_full.e[:, t + 1:])
    # window 3: a change at row s reaches rows s, s+1, s+2 only
    s = 2
    out_full, out = both(params, replace_rows(a, b, [s]))
    diff = np.abs(np.asarray(out.e - base_win.e)).max(axis=(0, 2, 3))
    assert np.all(diff[:s] == 0) and np.all(diff[s: s + 3] > 0) and np.all(diff[s + 3:] < 1e-6)
    # without a window the change at s reaches the end
    diff_full = np.abs(np.asarray(out_full.e - base_full.e)).max(axis=(0, 2, 3))
    assert np.all(diff_full[s:] > 0)
    m = temporal_mask(5, 2)
    np.testing.assert_array_equal(m, np.tri(5, dtype=bool) & ~np.tri(5, k=-2, dtype=bool))
    np.testing.assert_array_equal(temporal_mask(4, None), np.tri(4, dtype=bool))


def test_agent_attention_masks(atpg):
    cfg, params, both = atpg
    inputs = random_inputs(7)
    # a large δ with 4 agents so that some weights are cut
    n4 = 4
    cfg4 = ATPGConfig(**{**cfg.__dict__, "num_agents": n4, "delta": 0.3})
    net4 = ATPG(cfg4)
    inputs4 = random_inputs(8, n=n4)

    @tjit
    def init_apply(key, x):
        p = net4.init(key, x)
        sharpen = lambda k: k * 4.0
        p = {"params": {**p["params"], "agents": {name: {"kernel": sharpen(w["kernel"]) if name != "value"
                                                         else w["kernel"]} for name, w in p["params"]["agents"].items()}}}
        return p, net4.apply(p, x)

    p4, out = init_apply(jax.random.PRNGKey(2), inputs4)
    alpha = np.asarray(out.alpha)
    assert alpha.shape == (B, T, n4, n4)
    assert np.all(alpha[..., np.arange(n4), np.arange(n4)] == 0)
    assert np.all((alpha == 0) | (alpha >= 0.3)) and (alpha == 0).sum() > B * T * n4  # some cut beyond the diagonal
    assert np.all(alpha.sum(-1) <= 1 + 1e-6) and np.any(alpha.sum(-1) < 1 - 1e-3)
    # reference: softmax over j ≠ i from the module's own projections, threshold, no renormalisation
    ag = p4["params"]["agents"]
    e = np.asarray(out.e, np.float64)
    q, k, v = (e @ np.asarray(ag[name]["kernel"], np.float64) for name in ("query", "key", "value"))
    logits = np.einsum("btid,btjd->btij", q, k) / np.sqrt(cfg4.embed)
    logits[..., np.arange(n4), np.arange(n4)] = -np.inf
    ref = np.exp(logits - logits.max(-1, keepdims=True))
    ref /= ref.sum(-1, keepdims=True)
    ref[ref < 0.3] = 0
    np.testing.assert_allclose(alpha, ref, atol=1e-5)
    np.testing.assert_allclose(out.e_hat, np.einsum("btij,btjd->btid", ref, v), rtol=1e-4, atol=1e-5)
    # default δ = 0.05 with n = 3 via the fixture: same invariants
    a3 = np.asarray(both(params, inputs)[0].alpha)
    assert np.all(a3[..., np.arange(N), np.arange(N)] == 0) and np.all((a3 == 0) | (a3 >= 0.05))
    assert np.all(a3.sum(-1) <= 1 + 1e-6)
    # n = 1: no other agent -> ê = 0, α = 0, finite gradients
    cfg1 = ATPGConfig(**{**cfg.__dict__, "num_agents": 1})
    in1 = random_inputs(9, n=1)
    net1 = ATPG(cfg1)

    @tjit
    def init_apply_grad(key, x):
        p = net1.init(key, x)
        g = jax.grad(lambda p: jnp.sum(net1.apply(p, x).e ** 2))(p)
        return net1.apply(p, x), g

    out1, g1 = init_apply_grad(jax.random.PRNGKey(3), in1)
    assert out1.e_hat.shape == (B, T, 1, cfg.embed) and np.all(out1.e_hat == 0) and np.all(out1.alpha == 0)
    assert all(np.all(np.isfinite(g)) for g in jax.tree_util.tree_leaves(g1))


# ----------------------------------------------------------------------------------------
# mixers and the conditional max


@pytest.mark.parametrize("kind", ["atpg_qmix", "qmix", "vdn"])
def test_q_tot_is_monotone_in_every_q_i(kind, mixers):
    params, fn = mixers[kind]
    for seed in range(3):
        rng = np.random.default_rng(100 + seed)
        inputs = random_inputs(100 + seed)
        state = jnp.asarray(rng.normal(size=(B, T, S)) * 2, jnp.float32)
        w = fn(params, state, inputs)
        q = jnp.asarray(rng.normal(size=(B, T, N)) * 5, jnp.float32)
        grad = np.asarray(jax.grad(lambda q: mix(w, q).sum())(q))
        assert grad.shape == (B, T, N) and np.all(grad >= 0) and np.all(np.isfinite(grad))
        if kind != "vdn":
            assert w.w1.shape == (B, T, N, 8) and w.b1.shape == (B, T, 8) and w.w2.shape == (B, T, 8)
            assert w.b2.shape == (B, T) and np.all(w.w1 >= 0) and np.all(w.w2 >= 0)
            assert np.any(grad > 0)
        else:
            np.testing.assert_allclose(mix(w, q), q.sum(-1), rtol=1e-6)
    # broadcasting: C candidate joint actions against [B, T] weights
    qc = jnp.asarray(np.random.default_rng(5).normal(size=(7, B, T, N)), jnp.float32)
    assert mix(w, qc).shape == (7, B, T)
    np.testing.assert_allclose(mix(w, qc)[3], mix(w, qc[3]), rtol=1e-6)


def test_mixer_weights_do_not_depend_on_choices_at_t(mixers):
    """D4: the action chosen at row t enters as prev_mac of row t+1, never at rows ≤ t."""
    params, fn = mixers["atpg_qmix"]
    a, b = random_inputs(11), random_inputs(12)
    state = jnp.asarray(np.random.default_rng(11).normal(size=(B, T, S)), jnp.float32)
    t = 5
    changed = a.replace(prev_mac=a.prev_mac.at[:, t + 1].set(b.prev_mac[:, t + 1]))
    w0, w1 = fn(params, state, a), fn(params, state, changed)
    for x, y in zip(jax.tree_util.tree_leaves(w0), jax.tree_util.tree_leaves(w1)):
        np.testing.assert_allclose(x[:, : t + 1], y[:, : t + 1], rtol=1e-5, atol=1e-6)
    # ... while W1 and b1 (fed by ATPG) do see them from row t+1 on (W2, b2 read the state only)
    assert not np.allclose(w0.w1[:, t + 1], w1.w1[:, t + 1]) and not np.allclose(w0.b1[:, t + 1], w1.b1[:, t + 1])


@pytest.mark.parametrize("kind", ["atpg_qmix", "qmix", "vdn"])
def test_conditional_greedy_matches_brute_force(kind, mixers):
    params, fn = mixers[kind]
    rng = np.random.default_rng(200)
    inputs = random_inputs(200)
    state = jnp.asarray(rng.normal(size=(B, T, S)), jnp.float32)
    w = fn(params, state, inputs)  # [B, T]: B*T independent rows
    q = rng.normal(size=(B, T, N, A)).astype(np.float32) * 3
    avail = rng.random((B, T, N, A)) < 0.6
    avail[..., 0] |= ~avail.any(-1)
    free = rng.random((B, T, N)) < 0.6
    running = rng.integers(0, A, (B, T, N)).astype(np.int32)
    joint = np.asarray(conditional_greedy(q, avail, free, running))
    assert joint.shape == (B, T, N) and joint.dtype == np.int32
    np.testing.assert_array_equal(joint[~free], running[~free])
    assert np.take_along_axis(avail, joint[..., None], -1)[..., 0][free].all()
    q_greedy = np.asarray(mix(w, gather_q(q, joint)))
    # brute force: every joint action; free agents range over their available actions, busy ones pinned
    cands = np.array(list(itertools.product(range(A), repeat=N)), np.int32)  # [C, n]
    c = cands[:, None, None, :]  # [C, 1, 1, n]
    allowed = np.where(free, np.take_along_axis(avail[None], np.broadcast_to(c, (len(cands), B, T, N))[..., None],
                                                -1)[..., 0], c == running).all(-1)  # [C, B, T]
    q_c = np.take_along_axis(np.broadcast_to(q, (len(cands), B, T, N, A)),
                             np.broadcast_to(c, (len(cands), B, T, N))[..., None], -1)[..., 0]
    q_tot_c = np.where(allowed, np.asarray(mix(w, jnp.asarray(q_c))), -np.inf)
    np.testing.assert_allclose(q_greedy, q_tot_c.max(0), rtol=1e-5, atol=1e-5)
    assert free.any(-1).mean() > 0.5 and (~free).any()


# ----------------------------------------------------------------------------------------
# inputs from slots and timesteps, helpers, configs


def test_slot_and_timestep_inputs_agree_with_the_views():
    rng = np.random.default_rng(0)
    h, n = 9, 2
    mac_done = rng.random((h, n)) < 0.4
    reset_ts, traj, info = synthetic_rollout(mac_done, rng.normal(size=h), 7, end="truncated", obs_dim=O,
                                             num_actions=A)
    cfg = config_for(h, n, 0.9, obs_dim=O, num_actions=A)

    @tjit
    def build(reset_ts, traj):
        slot = episode.write_episode(cfg, reset_ts, traj)
        batched = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), slot)
        jv = views.jert_view(slot)
        return (slot, slot_inputs(slot), views.micro_view(slot, 1), slot_inputs(batched, "macro"), jv,
                jert_inputs(slot, jv), jert_inputs(batched, views.jert_view(batched)))

    slot, (inputs, tau), mv, (inputs2, tau2), jv, (ji, jtau), (ji2, _) = build(reset_ts, traj)
    assert inputs.obs.shape == (h + 1, n, O) and tau.shape == (h + 1, n)
    np.testing.assert_array_equal(inputs.obs[:8], info["obs_real"][:8])  # rows 0..length
    np.testing.assert_array_equal(inputs.reset, np.arange(h + 1) == 0)
    valid = np.asarray(slot.valid)
    np.testing.assert_array_equal(np.asarray(tau)[:h][valid], np.asarray(slot.t_m)[valid])  # executing action's τ
    boot_tau = np.asarray(tau)[np.asarray(mv.boot_row)]
    np.testing.assert_array_equal(boot_tau[valid], np.asarray(mv.boot_t_m)[valid])  # incl. row `length`
    # the rollout's TimeStep after step r-1 gives the same inputs as slot row r
    for r in range(1, 8):
        ts = jax.tree_util.tree_map(lambda x: x[r - 1], traj)
        got, want = timestep_inputs(ts), jax.tree_util.tree_map(lambda x: x[r], inputs)
        for name in ("obs", "t", "prev_t", "prev_mac", "prev_t_m", "reset"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    first = timestep_inputs(reset_ts)
    assert bool(first.reset) and np.all(first.prev_mac == -1)
    # batched slots: leading axes pass through
    assert inputs2.prev_mac.shape == (2, h + 1, n) and tau2.shape == (2, h + 1, n)
    np.testing.assert_array_equal(inputs2.obs[1, :8], info["obs_macro"][:8])
    np.testing.assert_array_equal(tau2[1], tau)
    # Mac-JERT (D16): entry k is decision row start[k]; its inputs are that row's, from obs_macro
    m = np.asarray(jv.mask)
    start = np.asarray(jv.start)[m]
    assert m.sum() >= 2 and start[0] == 0
    for name in ("obs", "t", "prev_t", "prev_mac", "prev_t_m"):
        np.testing.assert_array_equal(getattr(ji, name)[m], getattr(inputs2, name)[0][start], err_msg=name)
    np.testing.assert_array_equal(jtau[m], np.asarray(tau)[start])
    np.testing.assert_array_equal(ji.reset, np.arange(h) == 0)
    np.testing.assert_array_equal(ji2.prev_mac[1], ji.prev_mac)


def test_take_rows_and_gather_q():
    x = jnp.arange(2 * 5 * 3).reshape(2, 5, 3)
    rows = jnp.array([[[0, 4], [1, 1]], [[2, 3], [4, 0]]])  # [B=2, n=2, K=2]
    got = take_rows({"a": x}, rows, batch_ndim=1)["a"]
    assert got.shape == (2, 2, 2, 3)
    np.testing.assert_array_equal(got[1, 0, 1], x[1, 3])
    q = jnp.arange(2 * 3 * 4, dtype=jnp.float32).reshape(2, 3, 4)
    np.testing.assert_array_equal(gather_q(q, jnp.array([[0, 3, 1], [2, -1, 0]])), [[0, 7, 9], [14, 16, 20]])


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: AgentNetConfig(num_agents=0, obs_dim=3, num_actions=2), "num_agents=0"),
        (lambda: AgentNetConfig(num_agents=2, obs_dim=3, num_actions=2, head_hidden=[64]), "head_hidden"),
        (lambda: ATPGConfig(num_agents=2, obs_dim=3, num_actions=2, attn_window=0), "attn_window=0"),
        (lambda: ATPGConfig(num_agents=2, obs_dim=3, num_actions=2, delta=1.5), "delta=1.5"),
        (lambda: MixerConfig(num_agents=2, state_dim=4, kind="qtrn"), "valid choices"),
        (lambda: MixerConfig(num_agents=2, state_dim=4, kind="atpg_qtran"), "needs an ATPGConfig"),
        (lambda: MixerConfig(num_agents=2, state_dim=4, kind="atpg_qmix"), "needs an ATPGConfig"),
        (lambda: MixerConfig(num_agents=3, state_dim=4, atpg=ATPGConfig(2, 3, 2)), "must equal"),
    ],
)
def test_bad_configs_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_from_spec_and_bad_input_shapes(agent):
    spec = types.SimpleNamespace(num_agents=3, obs_dim=32, max_actions=14, state_dim=32)  # overcooked-A's
    a = AgentNetConfig.from_spec(spec, hidden=32)
    assert (a.num_agents, a.obs_dim, a.num_actions, a.hidden) == (3, 32, 14, 32)
    m = MixerConfig.from_spec(spec, atpg_overrides=dict(attn_window=32))
    assert m.state_dim == 32 and m.atpg.attn_window == 32 and m.atpg.num_agents == 3
    assert MixerConfig.from_spec(spec, kind="vdn").atpg is None
    with pytest.raises(ValueError, match="unknown override"):
        AgentNetConfig.from_spec(spec, hiden=32)
    cfg, net, params = agent.cfg, agent.net, agent.params
    bad = random_inputs(0).replace(obs=jnp.zeros((B, T, N, O + 1)))
    with pytest.raises(ValueError, match="inputs.obs has shape"):
        net.apply(params, bad, initial_carry(cfg, (B,)), jnp.zeros((B, T, N), jnp.int32))
