"""``jaxmac eval``'s greedy episode with the per-agent values each choice was made from."""

import jax
import numpy as np
import pytest

from jaxmac.algos import make_algorithm
from jaxmac.collect import episode_returns, run_episode
from jaxmac.config import make_env, scenario_config
from jaxmac.evaluate import decision_timesteps, values_along, values_line


@pytest.mark.parametrize("algorithm", ["tomacvf", "macdec_q", "macdec_ddrqn", "avf"])
def test_greedy_choices_are_the_argmax_of_the_values_printed_beside_them(algorithm):
    """On a greedy episode (random initial parameters, Box Pushing 6×6) of each learner with per-agent utilities,
    every free agent's choice is the argmax of ``values_along`` over its available macro-actions and every busy
    agent re-sends its running one: the values ``jaxmac eval`` shows are the ones the policy acted on, step for
    step (recurrent state included)."""
    config = scenario_config("boxpushing-6x6", algorithm=algorithm, tiny=True)
    env = make_env(config)
    algo = make_algorithm(config, env)
    params = algo.init_params(jax.random.key(3))
    reset_ts, traj = jax.jit(lambda p, k: run_episode(env, algo.act, algo.init_carry, p, k, 0.0)[:2])(
        params, jax.random.key(5))
    chosen_on = decision_timesteps(reset_ts, traj)
    q = values_along(algo, params, chosen_on)
    free, avail = np.asarray(chosen_on.mac_done), np.asarray(chosen_on.avail_actions)
    actions, running = np.asarray(traj.mac), np.asarray(chosen_on.mac)
    assert q.shape == (env.spec.horizon, env.spec.num_agents, avail.shape[-1])
    steps = int(episode_returns(traj, env.spec.discount)["length"])
    assert free[:steps].sum() >= 4 and (~free[:steps]).sum() > 0, "need free and busy choices"
    for t in range(steps):
        for i in range(env.spec.num_agents):
            if free[t, i]:
                assert actions[t, i] == np.argmax(np.where(avail[t, i], q[t, i], -np.inf)), (t, i)
            else:
                assert actions[t, i] == running[t, i], (t, i)
    line = values_line(env.spec.action_names[0], q[0, 0], avail[0, 0])
    assert line.startswith(f"Q: {env.spec.action_names[0][actions[0, 0]]} ")
    assert len(line[3:].split("  ")) == int(avail[0, 0].sum())  # every available macro-action, once


def test_qtot_along_a_greedy_episode_is_what_the_loss_fits():
    """``experiments/qtot_along_episode.py``: on a greedy episode every agent takes its greedy (or running) action,
    so the greedy joint Q_tot at the episode's rows is the Q_tot of the taken actions that ToMacVF's micro-TD loss
    fits — its mean equals the loss's ``q_tot_mean`` on the same slot; the return-to-go is the discounted sum."""
    import pathlib
    import sys

    import jax.numpy as jnp

    from jaxmac.algos.base import Progress
    from jaxmac.buffer.episode import SlotConfig, write_episode

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "experiments"))
    from qtot_along_episode import qtot_rows

    config = scenario_config("boxpushing-6x6", tiny=True)
    env = make_env(config)
    algo = make_algorithm(config, env)
    params = algo.init_params(jax.random.key(3))
    reset_ts, traj = jax.jit(lambda p, k: run_episode(env, algo.act, algo.init_carry, p, k, 0.0)[:2])(
        params, jax.random.key(5))
    q_tot, to_go, length = qtot_rows(config, env, params, reset_ts, traj)
    assert q_tot.shape == (env.spec.horizon + 1,) and 4 < length
    batch = jax.tree_util.tree_map(lambda x: x[None], write_episode(SlotConfig.from_spec(env.spec), reset_ts, traj))
    progress = Progress(episodes=jnp.int32(0), env_steps=jnp.int32(0), updates=jnp.int32(0))
    _, metrics = jax.jit(algo.loss)(params, params, batch, jax.random.key(0), progress)
    np.testing.assert_allclose(q_tot[:length].mean(), float(metrics["q_tot_mean"]), rtol=1e-5, atol=1e-6)
    reward = np.asarray(traj.reward)
    gamma = env.spec.discount
    np.testing.assert_allclose(to_go[0], sum(gamma**t * reward[t] for t in range(length)), rtol=1e-5)
    np.testing.assert_allclose(to_go[length - 1], reward[length - 1], rtol=1e-6)
