"""Seeds sharded over devices in one process (``jax.sharding``): the same training as on one device."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from jaxmac.runs import seed_sharding

# Run in a fresh interpreter: the host must be split into 2 devices before JAX starts its backend.
SCRIPT = textwrap.dedent("""
    import jax, jax.numpy as jnp, numpy as np
    from jaxmac.algos.registry import make_algorithm
    from jaxmac.config import make_env
    from jaxmac.presets import scenario_config
    from jaxmac.runs import seed_sharding
    from jaxmac.trainer import make_train

    assert jax.device_count() == 2, jax.devices()
    config = scenario_config("boxpushing-6x6", tiny=True).override(episodes=32, horizon=30)
    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env))
    state = jax.jit(jax.vmap(trainer.init))(jax.vmap(jax.random.key)(jnp.arange(2)))
    chunk = jax.jit(trainer.seeds_chunk)
    sharded_state = jax.device_put(state, seed_sharding(2, 2))
    for _ in range(2):  # two chunks: gradient steps run in the second
        state, plain = chunk(state)
        sharded_state, sharded = chunk(sharded_state)
    leaf = jax.tree_util.tree_leaves(sharded_state.params)[0]
    assert len(leaf.sharding.device_set) == 2 and leaf.addressable_shards[0].data.shape[0] == 1, leaf.sharding
    assert int(np.asarray(plain["round_updates"]).sum()) > 0
    for name in ("loss", "grad_norm", "train_return", "param_norm"):
        np.testing.assert_allclose(np.asarray(sharded[name]), np.asarray(plain[name]), rtol=1e-5, atol=1e-5,
                                   err_msg=name)
    try:
        seed_sharding(3, 2)
        raise AssertionError("3 seeds over 2 devices must be refused")
    except ValueError as err:
        assert "seeds=3 cannot be split evenly over devices=2" in str(err)
    print("OK")
""")


def test_seeds_sharded_over_two_host_devices_train_as_on_one():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stderr[-3000:]


def test_seed_sharding_refuses_what_it_cannot_do():
    assert seed_sharding(4, 1) is None
    with pytest.raises(ValueError, match="devices=0 must be a positive integer"):
        seed_sharding(4, 0)
    with pytest.raises(ValueError, match=r"devices=64: JAX sees \d+ device"):
        seed_sharding(64, 64)


def test_a_sweep_shards_seeds_over_the_cores_it_may_use_by_default(monkeypatch):
    from jaxmac.runs import resources

    monkeypatch.setattr(resources, "usable_cores", lambda: 2)
    assert resources.default_devices([4, 4]) == 2 and resources.default_devices([2]) == 2
    assert resources.default_devices([4, 1]) == 1  # a cell of one seed cannot be split: one device for all
    assert resources.default_devices([]) == 1
    monkeypatch.setattr(resources, "usable_cores", lambda: 1)  # e.g. under `taskset -c 0`
    assert resources.default_devices([4]) == 1
    # once JAX runs, a default is cut to the devices it sees (this test process: one CPU device)
    assert resources.fit_devices(2, [4]) == 1


# A run trained with its seeds sharded over 2 devices, stopped after its first chunk (and, for reference, the same
# run uninterrupted), in a fresh interpreter split into 2 devices.
SAVE_SHARDED = textwrap.dedent("""
    import sys
    from jaxmac.presets import scenario_config
    from jaxmac.runs import train_run

    config = scenario_config("boxpushing-6x6", tiny=True).override(episodes=32, horizon=30)
    assert train_run(config, 2, sys.argv[1], rounds_per_chunk=2, progress=False, devices=2,
                     stop_after_chunks=1) is None
    train_run(config, 2, sys.argv[2], rounds_per_chunk=2, progress=False, devices=2)
    print("OK")
""")


def test_a_run_saved_from_two_devices_resumes_on_one(tmp_path):
    import csv

    import jax
    import numpy as np

    from jaxmac.runs import resume_run

    assert jax.device_count() == 1
    killed, full = str(tmp_path / "killed"), str(tmp_path / "full")
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", SAVE_SHARDED, killed, full], env=env, capture_output=True, text=True,
                         timeout=900)
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stderr[-3000:]
    with open(os.path.join(killed, "metrics.csv"), newline="") as f:
        before = list(csv.DictReader(f))
    resumed = resume_run(killed, progress=False, devices=1)  # restored from its checkpoint, not started over
    with open(os.path.join(killed, "metrics.csv"), newline="") as f:
        after = list(csv.DictReader(f))
    with open(os.path.join(full, "metrics.csv"), newline="") as f:
        reference = list(csv.DictReader(f))
    assert before and after[:len(before)] == before and len(after) == len(reference) > len(before)
    for name in ("loss", "train_return", "param_norm"):
        np.testing.assert_allclose([float(r[name]) for r in after], [float(r[name]) for r in reference], rtol=1e-5,
                                   atol=1e-5, err_msg=name)
    assert resumed["episodes"] == 32
