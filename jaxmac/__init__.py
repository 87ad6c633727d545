"""jaxmac: asynchronous cooperative MARL with macro-actions in JAX.

Submodules are imported explicitly (``from jaxmac.buffer import episode, ring, views``) so that
importing the package stays cheap.
"""
