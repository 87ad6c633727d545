"""ToMacVF (the paper's method): ``settings`` (its block and per-scenario values) and ``model`` (the networks'
wiring, the losses and acting as module-level pure functions, and the factory ``make_tomacvf``)."""

from jaxmac.algos.base import Learner
from jaxmac.algos.tomacvf.model import (
    ToMacVFModel,
    act,
    bootstrap,
    build_model,
    conditional_target,
    forward,
    greedy_q_tot,
    init_params,
    jert_terms,
    macro_td,
    make_tomacvf,
    micro_td,
    network_configs,
    packed_forward,
    q_tot,
    sjert_terms,
    step_values,
    term_weights,
)
from jaxmac.algos.tomacvf.settings import LEARNING_CHANGES, PAPER_VALUES, SCENARIO_VALUES, ToMacVFSettings

LEARNER = Learner(
    "tomacvf", ToMacVFSettings, make_tomacvf, SCENARIO_VALUES,
    dict(rnn_size=8, fc_size=16, mixer_embed=8, attn_dim=8, time_pe_dim=4, progress_pe_dim=4, length_buckets=1,
         packing=False),
    "ToMacVF: temporal agent nets, ATPG-parameterised QMIX, micro- and macro-TD on Mac-SJERT",
    paper_values=PAPER_VALUES)

__all__ = [
    "ToMacVFModel",
    "act",
    "bootstrap",
    "build_model",
    "conditional_target",
    "forward",
    "greedy_q_tot",
    "init_params",
    "jert_terms",
    "macro_td",
    "make_tomacvf",
    "micro_td",
    "network_configs",
    "packed_forward",
    "q_tot",
    "sjert_terms",
    "step_values",
    "term_weights",
    "LEARNING_CHANGES",
    "PAPER_VALUES",
    "SCENARIO_VALUES",
    "ToMacVFSettings",
    "LEARNER",
]
