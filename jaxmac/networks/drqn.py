"""The recurrent Q network of the MacroMARL baselines (docs/baselines.md §1.0), one per agent or centralised.

    fc1(D→m0) –LReLU– fc2(m0→m0) –LReLU– GRU(m0→h) – fc3(h→m1) –LReLU– fc4(m1→out)

Dense weights Xavier-uniform with the leaky-ReLU gain (fc4: gain 1), zero biases; the GRU's weights and
biases uniform in ±1/√h (PyTorch's default). The GRU runs over a sequence of decision points (the squeezed
Mac-JERT / Mac-CERT entries) with reset flags; ``out`` is |M_i| for an agent's net and |M_1|·…·|M_n| for the
centralised one.

Shapes::

    net = DRQN(mlp=(32, 32), hidden=64, out=64)
    q, carry_T = net.apply(params, x, reset, carry)     # x f32[..., T, D], reset bool[..., T], carry f32[..., h]
                                                        # -> q f32[..., T, out], carry_T f32[..., h]
    agents = AgentDRQN(mlp, hidden, out)                 # separate parameters per agent (stacked on axis 0):
    q, carry_T = agents.apply(params, x, reset, carry)   # x f32[..., T, n, D], reset bool[..., T], carry [..., n, h]
                                                        # -> q f32[..., T, n, out]

The same net serves the actor-critic baselines (§1.4–1.6): an actor is a DRQN whose ``out`` are logits, a history
critic a DRQN with ``out = 1``. Their state critics (``*ISC``/``*ASC``) are ``StateCritic``, a recurrence-free MLP::

    fc1(S→m0) –LReLU– fc2(m0→m0) –LReLU– fc3(m1→mid) –LReLU– fc4(mid→m1) –LReLU– fc5(m1→1)

(fc3 reads ``m1`` inputs as the original: only consistent when m0 = m1, which every script has).
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.networks.agent import gru_scan

_LEAKY_GAIN = float(np.sqrt(2.0 / (1.0 + 0.01**2)))  # torch.nn.init.calculate_gain('leaky_relu')


def _xavier(gain: float):
    return nn.initializers.variance_scaling(gain**2, "fan_avg", "uniform")


def _torch_gru_uniform(hidden: int):
    bound = 1.0 / np.sqrt(hidden)

    def init(key, shape, dtype=jnp.float32):
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


class DRQN(nn.Module):
    """One recurrent Q network (see the module docstring)."""

    mlp: Sequence[int]
    hidden: int
    out: int

    @nn.compact
    def __call__(self, x, reset, carry):
        m0, m1 = self.mlp
        h = self.hidden
        dense = lambda width, name, gain=_LEAKY_GAIN: nn.Dense(  # noqa: E731
            width, name=name, kernel_init=_xavier(gain), bias_init=nn.initializers.zeros_init())
        y = nn.leaky_relu(dense(m0, "fc1")(x))
        y = nn.leaky_relu(dense(m0, "fc2")(y))
        gru_init = _torch_gru_uniform(h)
        gx = nn.Dense(3 * h, name="gru_in", kernel_init=gru_init, bias_init=gru_init)(y)
        u = self.param("gru_hh_kernel", gru_init, (h, 3 * h))
        b_hn = self.param("gru_hh_bias", gru_init, (h,))
        hs, carry_t = gru_scan(gx, reset, carry, u, b_hn)
        y = nn.leaky_relu(dense(m1, "fc3")(hs))
        return dense(self.out, "fc4", 1.0)(y), carry_t


class AgentDRQN(nn.Module):
    """``DRQN`` per agent with separate parameters: agents on axis -2 of ``x`` and ``q``, -2 of ``carry``."""

    mlp: Sequence[int]
    hidden: int
    out: int

    @nn.compact
    def __call__(self, x, reset, carry):
        per_agent = nn.vmap(DRQN, variable_axes={"params": 0}, split_rngs={"params": True},
                            in_axes=(-2, None, -2), out_axes=(-2, -2))
        return per_agent(mlp=tuple(self.mlp), hidden=self.hidden, out=self.out, name="agents")(x, reset, carry)


class StateCritic(nn.Module):
    """The originals' state-value MLP (see the module docstring): x f32[..., S] -> f32[..., 1]."""

    mlp: Sequence[int]
    mid: int

    @nn.compact
    def __call__(self, x):
        m0, m1 = self.mlp
        if m0 != m1:
            raise ValueError(f"StateCritic: mlp={tuple(self.mlp)!r} must have equal widths (fc3 reads mlp[1] inputs)")
        dense = lambda width, name, gain=_LEAKY_GAIN: nn.Dense(  # noqa: E731
            width, name=name, kernel_init=_xavier(gain), bias_init=nn.initializers.zeros_init())
        y = nn.leaky_relu(dense(m0, "fc1")(x))
        y = nn.leaky_relu(dense(m0, "fc2")(y))
        y = nn.leaky_relu(dense(self.mid, "fc3")(y))
        y = nn.leaky_relu(dense(m1, "fc4")(y))
        return dense(1, "fc5", 1.0)(y)


class AgentStateCritic(nn.Module):
    """``StateCritic`` per agent with separate parameters: x f32[..., n, S] -> f32[..., n, 1]."""

    mlp: Sequence[int]
    mid: int

    @nn.compact
    def __call__(self, x):
        per_agent = nn.vmap(StateCritic, variable_axes={"params": 0}, split_rngs={"params": True},
                            in_axes=-2, out_axes=-2)
        return per_agent(mlp=tuple(self.mlp), mid=self.mid, name="agents")(x)
