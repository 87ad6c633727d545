"""Algorithms: each is a small module of networks + losses + acting rule (``jaxmac.trainer.Algorithm``)."""

from __future__ import annotations

from jaxmac.config import CHOICES, TrainConfig


def make_algorithm(config: TrainConfig, env):
    """The ``Algorithm`` named by ``config.algorithm`` for ``env``."""
    if config.algorithm == "tomacvf":
        from jaxmac.algos.tomacvf import make_tomacvf

        return make_tomacvf(config, env)
    raise ValueError(f"unknown algorithm {config.algorithm!r}; valid: {list(CHOICES['algorithm'])}")
