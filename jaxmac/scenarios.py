"""The paper's 13 scenarios in one place: their names, their families and the returns results are compared with.

A bottom-layer module (imports nothing of jaxmac): settings tables, sweeps, statistics and run summaries read it.
"""

from __future__ import annotations

BOXPUSHING = tuple(f"boxpushing-{g}x{g}" for g in (6, 8, 10, 12, 14))
OVERCOOKED = ("overcooked-A", "overcooked-B", "overcooked-C")
WAREHOUSE = tuple(f"warehouse-{v}" for v in "ABCDE")
SCENARIOS = BOXPUSHING + OVERCOOKED + WAREHOUSE
FAMILIES = {"boxpushing": BOXPUSHING, "overcooked": OVERCOOKED, "warehouse": WAREHOUSE}

# Box Pushing's optimal discounted returns (γ 0.98), computed by search over the grid (docs/envs/boxpushing.md §13)
OPTIMAL_DISC_RETURN = {
    "boxpushing-6x6": 270.605, "boxpushing-8x8": 259.691, "boxpushing-10x10": 244.125,
    "boxpushing-12x12": 229.475, "boxpushing-14x14": 215.686,
}
# The returns of the jittable scripted cooperative policies (envs_jax/overcooked/scripted.py, discounted with γ 0.99;
# envs_jax/warehouse/scripted.py, undiscounted: γ 1); tests check them
SCRIPTED_RETURN = {
    "overcooked-A": 164.3, "overcooked-B": 149.8, "overcooked-C": 149.8,
    "warehouse-A": 533.0, "warehouse-B": 533.0, "warehouse-C": 801.0, "warehouse-D": 803.0, "warehouse-E": 1053.0,
}
# What results are compared with (the "ceiling"): the optimum where it is known, else the scripted policy's return
CEILINGS = {**OPTIMAL_DISC_RETURN, **SCRIPTED_RETURN}


def family(scenario: str) -> str:
    """``boxpushing``, ``overcooked`` or ``warehouse`` (a ValueError naming the valid scenarios otherwise)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; valid scenarios: {list(SCENARIOS)}")
    return scenario.rsplit("-", 1)[0]
