"""jaxmac: asynchronous cooperative MARL with macro-actions in JAX.

Submodules are imported explicitly (``from jaxmac import episode, ring, views``) so that
importing the package stays cheap.
"""
