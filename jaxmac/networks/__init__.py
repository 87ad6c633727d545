"""Networks: ToMacVF's temporal agent networks (D2, D3), ATPG (D4, D5), mixers (D6, D19), and the originals'
DRQNs. See each submodule's docstring for shapes (conditional greedy actions live in ``jaxmac.algos.targets``; masks,
argmaxes and gathers over actions in ``jaxmac.ops``).

Typical training-side use on a batch of episode slots (leaves ``[B, H, ...]``, rows ``T = H + 1``)::

    inputs, tau = slot_inputs(slots)                                   # NetInputs [B, T, ...], tau [B, T, n]
    q, _, _ = agent_net.apply(agent_params, inputs, initial_carry(agent_cfg, (B,)), tau)  # [B, T, n, A]
    weights, _ = mixer.apply(mixer_params, slots.decode_state(), inputs)                 # MixWeights [B, T]
    q_tot = mix(weights, ops.gather_q(q, actions))                                          # [B, T]
"""

from jaxmac.networks.agent import (
    AgentNetConfig,
    GRUTorso,
    QHead,
    TemporalAgentNet,
    agent_features,
    dummy_inputs,
    init_agent_params,
    initial_carry,
)
from jaxmac.networks.atpg import (
    ATPG,
    AgentAttention,
    ATPGConfig,
    ATPGOutput,
    TemporalSelfAttention,
    temporal_mask,
)
from jaxmac.networks.inputs import NetInputs, jert_inputs, jert_sequence, slot_inputs, timestep_inputs
from jaxmac.networks.mixers import (
    MIXER_KINDS,
    HyperMLP,
    Mixer,
    MixerConfig,
    MixWeights,
    init_mixer_params,
    mix,
    take_rows,
)

__all__ = [
    "ATPG",
    "MIXER_KINDS",
    "ATPGConfig",
    "ATPGOutput",
    "AgentAttention",
    "AgentNetConfig",
    "GRUTorso",
    "HyperMLP",
    "MixWeights",
    "Mixer",
    "MixerConfig",
    "NetInputs",
    "QHead",
    "TemporalAgentNet",
    "TemporalSelfAttention",
    "agent_features",
    "dummy_inputs",
    "init_agent_params",
    "init_mixer_params",
    "initial_carry",
    "jert_inputs",
    "jert_sequence",
    "mix",
    "slot_inputs",
    "take_rows",
    "temporal_mask",
    "timestep_inputs",
]
