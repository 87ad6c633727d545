"""Algorithms: one module each, holding only what is particular to it, on the shared trainer.

``REGISTRY`` is the one list of learners: name → settings block, per-scenario values, tiny test values and
the factory ``make(config, env) -> Algorithm`` (imported when first used, so that reading a configuration
does not import JAX). ``jaxmac.config`` takes its valid algorithm names from here.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

from jaxmac.algos import settings as s


@dataclasses.dataclass(frozen=True)
class Entry:
    settings: type  # the frozen settings block
    factory: str  # "module:function" building the Algorithm
    scenario_values: dict[str, dict[str, Any]]  # original-script values per scenario (shared and block fields)
    tiny_values: dict[str, Any]  # block values for tests and smoke runs
    summary: str
    # the publication's own values where jaxmac's defaults differ from them (``jaxmac train --paper``); None = the
    # defaults are the publication's
    length_buckets: bool = False  # its update reads TrainConfig.length_buckets (runs on the batch's real length)
    paper_values: dict[str, dict[str, Any]] | None = None


_TINY_DRQN = dict(mlp_sizes=(8, 8), rnn_size=8, start_train_episodes=0, eps_decay_start=0, train_every_steps=20,
                  target_update_steps=200)

# on-policy: the batch is the round's episodes, the ring keeps only their lengths
_TINY_AC = dict(actor_mlp_sizes=(8, 8), actor_rnn_size=8, critic_mlp_sizes=(8, 8), critic_rnn_size=8, critic_mid_size=8,
                batch_size=8, buffer_episodes=8, grad_clip=0.0, length_buckets=1)  # one compilation per test

REGISTRY: dict[str, Entry] = {
    "tomacvf": Entry(
        s.ToMacVFSettings, "jaxmac.algos.tomacvf:make_tomacvf", s.TOMACVF,
        dict(rnn_size=8, fc_size=16, mixer_embed=8, attn_dim=8, time_pe_dim=4, progress_pe_dim=4, length_buckets=1,
             packing=False),
        "ToMacVF: temporal agent nets, ATPG-parameterised QMIX, micro- and macro-TD on Mac-SJERT",
        length_buckets=True, paper_values=s.TOMACVF_PAPER),
    "maccen_ddrqn": Entry(
        s.MacCenDDRQNSettings, "jaxmac.algos.maccen_ddrqn:make_maccen_ddrqn", s.MACCEN,
        _TINY_DRQN, "Mac-Cen-DDRQN: centralised recurrent joint Q on Mac-JERT, conditional double-Q"),
    "macdec_q": Entry(
        s.MacDecQSettings, "jaxmac.algos.macdec_q:make_macdec_q", s.MACDEC_Q, _TINY_DRQN,
        "MacDec-Q: independent recurrent Q per agent on Mac-CERT, hysteretic double-Q"),
    "macdec_ddrqn": Entry(
        s.MacDecDDRQNSettings, "jaxmac.algos.macdec_ddrqn:make_macdec_ddrqn", s.MACDEC_DDRQN,
        dict(_TINY_DRQN, cen_mlp_sizes=(8, 8), cen_rnn_size=8),
        "Mac-Dec-MADDRQN: decentralised DRQNs whose targets follow a centralised conditional joint Q"),
    "avf": Entry(
        s.AVFSettings, "jaxmac.algos.avf:make_avf", s.AVF, dict(_TINY_DRQN, mixer_embed=8, hyper_hidden=8),
        "AVF: per-agent recurrent Q on Mac-JERT mixed by VDN/QMIX/QPLEX, conditional double-Q, Polyak target"),
    "mac_iaicc": Entry(
        s.MacIAICCSettings, "jaxmac.algos.mac_iaicc:make_mac_iaicc", s.MAC_IAICC, _TINY_AC,
        "Mac-IAICC: per-agent actors, individual centralised critics V_i (history or state), on-policy",
        length_buckets=True),
    "mac_niacc": Entry(
        s.MacNIACCSettings, "jaxmac.algos.mac_niacc:make_mac_niacc", s.MAC_NIACC, _TINY_AC,
        "Mac-NIACC: per-agent actors, one joint critic (history or state), the joint advantage, on-policy",
        length_buckets=True),
    "mac_cac": Entry(
        s.MacCACSettings, "jaxmac.algos.mac_cac:make_mac_cac", s.MAC_CAC,
        {k: v for k, v in _TINY_AC.items() if k != "critic_mid_size"},
        "Mac-CAC: a joint actor over joint macro-actions and a joint history critic, on-policy",
        length_buckets=True),
}


def make_algorithm(config, env):
    """The ``Algorithm`` named by ``config.algorithm`` for ``env``."""
    if config.algorithm not in REGISTRY:
        raise ValueError(f"unknown algorithm {config.algorithm!r}; valid: {list(REGISTRY)}")
    module, function = REGISTRY[config.algorithm].factory.split(":")
    return getattr(importlib.import_module(module), function)(config, env)
