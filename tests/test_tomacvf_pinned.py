"""ToMacVF's training metrics on a fixed seed are pinned: refactors of the shared framework must not change them.

``tests/data/tomacvf_pinned.json`` was written by ``python tests/test_tomacvf_pinned.py`` with the code
before the framework refactor (issue 12); on the same machine the refactored code reproduced it bit for bit.
The test allows float32 round-off (1e-5 relative) so that a CPU with other vector units still passes.
"""

from __future__ import annotations

import json
import pathlib
import sys

import jax
import numpy as np
import pytest

from jaxmac.algos.registry import make_algorithm
from jaxmac.config import make_env
from jaxmac.presets import scenario_config
from jaxmac.trainer import make_train

PINNED = pathlib.Path(__file__).parent / "data" / "tomacvf_pinned.json"
CASES = {
    "mac_sjert": dict(updates_per_round=2, overestimate_weight=0.5),
    "mac_jert": dict(buffer="mac_jert", obs_mode="macro"),
}


def pinned_metrics(case: str) -> dict[str, list[float]]:
    config = scenario_config("boxpushing-6x6", tiny=True).override(
        horizon=20, episodes=48, num_envs=8, batch_size=8, buffer_episodes=16, eval_every_episodes=16,
        eval_episodes=2, target_update_episodes=16, eps_decay_episodes=16, **CASES[case])
    env = make_env(config)
    trainer = make_train(config, env, make_algorithm(config, env), rounds_per_chunk=3)
    state = jax.jit(trainer.init)(jax.random.key(3))
    chunk = jax.jit(trainer.train_chunk)
    rows = []
    for _ in range(trainer.total_chunks):
        state, m = chunk(state)
        rows.append(jax.device_get(m))
    metrics = {k: np.concatenate([np.asarray(r[k], np.float64) for r in rows]).tolist() for k in rows[0]}
    leaves = jax.tree_util.tree_leaves(state.params)
    metrics["param_sum"] = [float(sum(np.abs(np.asarray(x, np.float64)).sum() for x in leaves))]
    return metrics


@pytest.mark.parametrize("case", sorted(CASES))
def test_tomacvf_metrics_match_the_pinned_run(case):
    pinned = json.loads(PINNED.read_text())[case]
    got = pinned_metrics(case)
    for key, want in pinned.items():
        assert key in got, f"metric {key!r} is no longer reported"
        np.testing.assert_allclose(np.asarray(got[key]), np.asarray(want), rtol=1e-5, atol=1e-6, err_msg=key,
                                   equal_nan=True)


if __name__ == "__main__":  # regenerate (only when a change of behaviour is intended)
    PINNED.write_text(json.dumps({case: pinned_metrics(case) for case in sorted(CASES)}, indent=1))
    sys.exit(0)
