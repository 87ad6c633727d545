"""jaxmac: asynchronous cooperative MARL with macro-actions in JAX.

Submodules are imported explicitly (``from jaxmac.buffer import episode, ring, views``) so that
importing the package stays cheap. The Python API (``jaxmac.api``) is re-exported here and imported on
first use::

    import jaxmac
    run = jaxmac.load("runs/boxpushing-6x6-tomacvf-TIME")   # or jaxmac.train("quickstart")
    policy = run.policy(seed=0)                             # policy.act(timestep, carry, key) -> (actions, carry)
    print(run.evaluate(seed=0, episodes=10))
"""

_API = ("train", "load", "Run", "Policy", "evaluate_policy")
__all__ = list(_API)


def __getattr__(name: str):
    if name in _API:
        from jaxmac import api

        return getattr(api, name)
    raise AttributeError(f"module 'jaxmac' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_API))
