"""``jaxmac eval``: greedy episodes of a trained run (their returns, equal to ``run_episode``'s), the first one as text
with the per-agent values each choice was made from, drawn as a grid of frames and as a GIF."""

import os
import re

import jax
import numpy as np
import pytest

from jaxmac.algos.registry import make_algorithm
from jaxmac.collect import episode_returns, run_episode
from jaxmac.config import make_env
from jaxmac.runs.evaluation import decision_timesteps, values_along, values_line
from jaxmac.presets import scenario_config


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
    """``jaxmac qtot`` (jaxmac/runs/qtot.py): on a greedy episode every agent takes its greedy (or running) action,
    so the greedy joint Q_tot at the episode's rows is the Q_tot of the taken actions that ToMacVF's micro-TD loss
    fits — its mean equals the loss's ``q_tot_mean`` on the same slot; the return-to-go is the discounted sum."""
    import jax.numpy as jnp

    from jaxmac.algos.base import Progress
    from jaxmac.buffer.episode import SlotConfig, write_episode
    from jaxmac.runs.qtot import qtot_rows

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


TINY_RUN = {"horizon": 20, "episodes": 32, "num_envs": 8, "batch_size": 8, "buffer_episodes": 16,
            "eval_every_episodes": 16, "eval_episodes": 2, "target_update_episodes": 16, "eps_decay_episodes": 16}
# one row of `jaxmac eval`'s table: episode, steps, task done, discounted, undiscounted
ROW = re.compile(r"^ +(\d+) +(\d+) +(yes|no) +(-?\d+\.\d{3}) +(-?\d+\.\d{3})$", re.MULTILINE)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> str:
    """A two-seed ToMacVF run of Box Pushing 6×6 with tiny networks and budgets."""
    from jaxmac.runs import train_run

    out = str(tmp_path_factory.mktemp("eval") / "run")
    train_run(scenario_config("boxpushing-6x6", tiny=True).override(**TINY_RUN), 2, out, progress=False)
    return out


def test_qtot_prints_q_tot_beside_the_return_to_go_of_a_runs_greedy_episode(tiny_run, capsys):
    """``jaxmac qtot RUN --seed-index 1``: the rows of ``qtot_along_episode`` (seed 1's greedy episode at the newest
    checkpoint), the last one the bootstrap row of a truncated episode; a seed index out of range is one line."""
    from jaxmac.cli import main
    from jaxmac.runs.qtot import qtot_along_episode

    assert main(["qtot", tiny_run, "--seed-index", "1"]) == 0
    out = capsys.readouterr().out.splitlines()
    q_tot, to_go, length = qtot_along_episode(tiny_run, 1)
    assert out[0] == f"{tiny_run}, seed index 1: greedy episode of {length} steps"
    rows = {int(line.split()[0]): line.split()[1:] for line in out[2:]}
    assert 0 in rows and length - 1 in rows
    assert float(rows[0][0]) == pytest.approx(q_tot[0], abs=0.051)
    assert float(rows[0][1]) == pytest.approx(to_go[0], abs=0.051)
    if length == 20:  # the tiny horizon: truncated, its bootstrap row printed
        assert rows[length][1:] == ["(bootstrap", "row)"]
    assert main(["qtot", tiny_run, "--seed-index", "2"]) == 2
    assert "has 2 seeds" in capsys.readouterr().err


def test_eval_prints_the_returns_of_n_episodes_and_draws_the_first(tiny_run, capsys):
    """``jaxmac eval RUN --seed-index 1 --episodes 3 --gif``: three rows whose returns are those of
    ``jaxmac.collect.run_episode`` with seed 1's parameters, its greedy policy and keys 0, 1, 2, their mean, a PNG
    of a readable size and a GIF of one frame per state of episode 0 (reset + every step)."""
    from PIL import Image

    from jaxmac.cli import main
    from jaxmac.runs.evaluation import greedy_policy
    from jaxmac.runs import load_run

    assert main(["eval", tiny_run, "--seed-index", "1", "--episodes", "3", "--gif"]) == 0
    out = capsys.readouterr().out
    table = out[out.index("greedy policy of seed 1"):]
    rows = ROW.findall(table)
    assert [int(r[0]) for r in rows] == [0, 1, 2], table
    trainer, state, _, _ = load_run(tiny_run)
    env, algo = trainer.env, trainer.algorithm
    params = jax.tree_util.tree_map(lambda x: x[1], state.params)
    run = jax.jit(lambda k: run_episode(env, greedy_policy(algo), algo.init_carry, params, k, 0.0)[1])
    for e, (_, steps, done, disc, undisc) in enumerate(rows):
        expected = {k: float(v) for k, v in episode_returns(run(jax.random.key(e)), env.spec.discount).items()}
        assert int(steps) == expected["length"], e
        assert (done == "yes") == bool(expected["terminated"]), e
        assert float(disc) == pytest.approx(expected["disc_return"], abs=1.5e-3), e
        assert float(undisc) == pytest.approx(expected["return"], abs=1.5e-3), e
    mean = re.search(r"mean over 3 episodes: discounted (-?\d+\.\d{3})", table)
    assert float(mean.group(1)) == pytest.approx(np.mean([float(r[3]) for r in rows]), abs=2e-3)
    length = int(rows[0][1])
    width, height = Image.open(os.path.join(tiny_run, "greedy_seed1.png")).size
    assert 500 < width < 3000 and height < 3000
    assert f"{width} x {height} px" in table
    assert Image.open(os.path.join(tiny_run, "greedy_seed1.gif")).n_frames == length + 1
    with open(os.path.join(tiny_run, "greedy_seed1.txt")) as f:
        text = f.read()
    assert text.startswith("t=0 (reset)") and text.count("\nafter step ") == length


def test_evaluate_run_keeps_its_contract(tiny_run):
    """``evaluate_run(run)``: ``(txt, png, stats)`` with episode 0's statistics, one episode, no GIF; the text frames
    of ``greedy_episode_frames`` are the file's."""
    from jaxmac.runs.evaluation import evaluate_run, greedy_episode_frames, panel_indices

    txt, png, stats = evaluate_run(tiny_run)
    assert os.path.basename(txt) == "greedy_seed0.txt" and os.path.basename(png) == "greedy_seed0.png"
    assert os.path.exists(png) and stats["gif"] is None and not os.path.exists(os.path.join(tiny_run,
                                                                                            "greedy_seed0.gif"))
    assert stats["episodes"]["disc_return"] == [stats["disc_return"]] and stats["chunks_trained"] > 0
    frames, same = greedy_episode_frames(tiny_run, 0)
    assert {k: same[k] for k in ("length", "return", "disc_return")} == {
        k: stats[k] for k in ("length", "return", "disc_return")}
    assert len(frames) == int(stats["length"]) + 1
    with open(txt) as f:
        assert f.read() == "\n\n".join(frames) + "\n"
    assert list(panel_indices(30)) == [0, 3, 5, 8, 11, 13, 16, 18, 21, 24, 26, 29]
    assert list(panel_indices(5)) == [0, 1, 2, 3, 4]
