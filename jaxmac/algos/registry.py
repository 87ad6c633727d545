"""The learners jaxmac knows: one ``Learner`` per module, listed once here.

Adding a learner is one new module defining its settings block, its per-scenario values, its factory and a
``LEARNER`` (docs/learners.md shows a complete ~40-line example), plus its line in ``LEARNERS`` below.
"""

from __future__ import annotations

from jaxmac.algos import avf, mac_cac, mac_iaicc, mac_niacc, maccen_ddrqn, macdec_ddrqn, macdec_q, tomacvf
from jaxmac.algos.base import Algorithm, Learner

LEARNERS: tuple[Learner, ...] = (
    tomacvf.LEARNER,
    maccen_ddrqn.LEARNER,
    macdec_q.LEARNER,
    macdec_ddrqn.LEARNER,
    avf.LEARNER,
    mac_iaicc.LEARNER,
    mac_niacc.LEARNER,
    mac_cac.LEARNER,
)
REGISTRY: dict[str, Learner] = {entry.name: entry for entry in LEARNERS}


def learner(name: str) -> Learner:
    """The learner called ``name`` (a ValueError naming the valid ones otherwise)."""
    if name not in REGISTRY:
        raise ValueError(f"unknown algorithm {name!r}; valid: {list(REGISTRY)}")
    return REGISTRY[name]


def make_algorithm(config, env) -> Algorithm:
    """The ``Algorithm`` named by ``config.algorithm`` for ``env``."""
    return learner(config.algorithm).make(config, env)
