"""The Python API (``jaxmac.api``, re-exported by ``jaxmac``): a trained run loads, its policy acts under ``jax.jit``
exactly as the learner's own greedy rule, ``evaluate`` equals a plain Python loop over the env, and the README's
snippet runs."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmac
from jaxmac.presets import scenario_config
from jaxmac.runs import train_run

ROOT = os.path.join(os.path.dirname(__file__), "..")
TINY_RUN = dict(horizon=20, episodes=32, num_envs=8, batch_size=8, buffer_episodes=16, eval_every_episodes=16,
                eval_episodes=2, target_update_episodes=16, eps_decay_episodes=16)


@pytest.fixture(scope="module")
def tomacvf_run(tmp_path_factory) -> str:
    out = str(tmp_path_factory.mktemp("api") / "tomacvf")
    train_run(scenario_config("boxpushing-6x6", tiny=True).override(**TINY_RUN), 2, out, progress=False)
    return out


def _episode(env):
    """A jitted episode of a policy (passed as an argument: a ``Policy`` is a pytree): the timesteps acted on, the
    actions and the policy's keys, leaves ``[H, ...]``."""

    @jax.jit
    def run(policy, key):
        k_reset, k_steps = jax.random.split(key)
        state, ts = env.reset(k_reset)

        def body(carry, key):
            state, ts, policy_carry = carry
            k_act, k_step = jax.random.split(key)
            actions, policy_carry = policy.act(ts, policy_carry, k_act)
            state, next_ts = env.step(k_step, state, actions)
            return (state, next_ts, policy_carry), (ts, actions, k_act)

        return jax.lax.scan(body, (state, ts, policy.init_carry()), jax.random.split(k_steps, env.spec.horizon))[1]

    return run


def _replay(act, params, init_carry, seen, keys):
    """The learner's own ``act(params, carry, ts, key, 0.0)`` on the same timesteps: actions ``[H, n]``."""

    def body(carry, x):
        ts, key = x
        carry, actions = act(params, carry, ts, key, 0.0)
        return carry, actions

    return np.asarray(jax.jit(lambda p, s, k: jax.lax.scan(body, init_carry, (s, k))[1])(params, seen, keys))


def _steps(seen) -> int:
    """The steps acted on before the episode ended (a timestep after the end is not one)."""
    done = np.asarray(seen.terminated | seen.truncated)
    return int(np.argmax(done)) if done.any() else len(done)


def test_import_is_cheap():
    code = "import sys, jaxmac; assert 'jax' not in sys.modules; jaxmac.load; assert 'jax' in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_policy_acts_as_the_learners_greedy_act_under_jit(tomacvf_run):
    run = jaxmac.load(tomacvf_run)
    assert run.seeds == [0, 1] and sorted(run.params) == [0, 1] and run.episodes == 32
    assert run.config.algorithm == "tomacvf" and run.summary["seeds"] == 2
    assert set(run.metrics["seed"]) == {0, 1} and np.isfinite(run.metrics["eval_disc_return"]).any()
    env, algo = run.env, run.algorithm
    for seed in run.seeds:
        policy = run.policy(seed=seed)
        assert not policy.sampled
        seen, actions, keys = _episode(env)(policy, jax.random.key(7))
        expected = _replay(algo.act, run.params[seed], algo.init_carry(env.spec.num_agents), seen, keys)
        steps = _steps(seen)
        assert steps > 0
        np.testing.assert_array_equal(np.asarray(actions)[:steps], expected[:steps])
        busy = ~np.asarray(seen.mac_done)[:steps]
        assert busy.any(), "the episode needs busy agents"
        np.testing.assert_array_equal(np.asarray(actions)[:steps][busy], np.asarray(seen.mac)[:steps][busy])
    # jax.jit of the bound method, too
    policy = run.policy()
    state, ts = env.reset(jax.random.key(0))
    a_jit, c_jit = jax.jit(policy.act)(ts, policy.init_carry(), jax.random.key(1))
    a, c = policy.act(ts, policy.init_carry(), jax.random.key(1))
    np.testing.assert_array_equal(a_jit, a)
    jax.tree_util.tree_map(lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-6), c_jit, c)
    leaves = [jax.tree_util.tree_leaves(run.params[s]) for s in run.seeds]
    assert any(not np.array_equal(x, y) for x, y in zip(*leaves)), "each seed has its own parameters"
    with pytest.raises(ValueError, match="not a seed"):
        run.policy(seed=5)


def test_evaluate_equals_a_plain_python_loop(tomacvf_run):
    run = jaxmac.load(tomacvf_run)
    episodes, seed = 3, 1
    out = run.evaluate(seed=seed, episodes=episodes, key=11)
    assert {k: v.shape for k, v in out.items()} == {k: (episodes,) for k in ("discounted", "undiscounted", "length")}
    assert np.isfinite(out["discounted"]).all() and np.isfinite(out["undiscounted"]).all()

    env, policy = run.env, run.policy(seed=seed)
    act, step, reset = jax.jit(policy.act), jax.jit(env.step), jax.jit(env.reset)
    gamma = env.spec.discount
    for i, key in enumerate(jax.random.split(jax.random.key(11), episodes)):
        k_reset, k_steps = jax.random.split(key)
        state, ts = reset(k_reset)
        carry = policy.init_carry()
        disc = undisc = 0.0
        length = 0
        for t, k in enumerate(jax.random.split(k_steps, env.spec.horizon)):
            k_act, k_step = jax.random.split(k)
            actions, carry = act(ts, carry, k_act)
            state, ts = step(k_step, state, actions)
            disc += gamma ** t * float(ts.reward)
            undisc += float(ts.reward)
            length += 1
            if bool(ts.terminated | ts.truncated):
                break
        np.testing.assert_allclose(out["discounted"][i], disc, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(out["undiscounted"][i], undisc, rtol=1e-5, atol=1e-4)
        assert out["length"][i] == length


def _readme_snippets() -> list[str]:
    with open(os.path.join(ROOT, "README.md")) as f:
        text = f.read()
    section = text.split("\n## Python API", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_readme_snippet_runs(tomacvf_run, capsys):
    first, *rest = _readme_snippets()
    code_lines = [line for line in first.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    assert len(code_lines) <= 5, first
    first, count = re.subn(r'jaxmac\.load\("[^"]*"\)', f"jaxmac.load({tomacvf_run!r})", first)
    assert count == 1
    namespace: dict = {}
    for snippet in [first] + rest:
        exec(compile(snippet, "README.md", "exec"), namespace)
    printed = capsys.readouterr().out
    assert "discounted" in printed and "undiscounted" in printed
    assert isinstance(namespace["policy"], jaxmac.Policy)


def test_a_run_without_checkpoints_loads_its_records_only():
    run = jaxmac.load(os.path.join(ROOT, "experiments", "results", "boxpushing-6x6-quickstart"))
    assert run.params == {} and run.summary["final_greedy_return_mean"] > 0
    assert len(run.metrics["eval_disc_return"]) > 0
    with pytest.raises(ValueError, match="no checkpoint"):
        run.policy(seed=0)


def test_train_refuses_a_preset_with_a_scenario():
    with pytest.raises(ValueError, match="fixes the scenario"):
        jaxmac.train("quickstart", scenario="boxpushing-8x8")


def test_an_actor_critic_loads_and_acts(tmp_path):
    """Mac-IAICC (trained through ``jaxmac.train``): the default policy is its ``greedy_act``, ``greedy=False`` its
    sampled evaluation policy, each equal to the learner's own rule step for step."""
    overrides = dict(TINY_RUN, episodes=16, buffer_episodes=8)
    run = jaxmac.train(scenario="boxpushing-6x6", algorithm="mac_iaicc", tiny=True, out_dir=str(tmp_path / "iaicc"),
                       progress=False, **overrides)
    assert run.config.algorithm == "mac_iaicc" and run.seeds == [0] and run.episodes == 16
    env, algo = run.env, run.algorithm
    episode = _episode(env)
    for greedy, own in ((True, algo.greedy_act), (False, algo.act)):
        policy = run.policy(greedy=greedy)
        assert policy.sampled is (not greedy)
        seen, actions, keys = episode(policy, jax.random.key(3))
        steps = _steps(seen)
        expected = _replay(own, run.params[0], algo.init_carry(env.spec.num_agents), seen, keys)
        np.testing.assert_array_equal(np.asarray(actions)[:steps], expected[:steps])
        free = np.asarray(seen.mac_done)[:steps]
        valid = np.take_along_axis(np.asarray(seen.avail_actions)[:steps], np.asarray(actions)[:steps, :, None], -1)
        assert valid[..., 0][free].all(), "free agents choose available macro-actions"
    out = run.evaluate(episodes=2)
    assert np.isfinite(out["discounted"]).all() and out["discounted"].shape == (2,)
    assert jnp.issubdtype(out["length"].dtype, jnp.integer)
