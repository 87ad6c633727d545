"""Replay of macro-action episodes: one ring of fixed-shape episode slots and the views every learner reads.

* ``episode``: the episode slot (rows ``[H+1]``, steps ``[H]``, per-agent segment tables = the paper's D^i)
  and the writer that fills it from a rollout.
* ``segments``: the index arithmetic (left-packing, running accumulators) shared by the writer and the views.
* ``ring``: a FIFO ring of ``N`` slots (``init`` / ``add`` / ``sample`` / ``can_sample``).
* ``views``: Mac-SJERT micro and macro transitions (ToMacVF), Mac-JERT (joint, squeezed by any termination)
  and Mac-CERT (per agent, squeezed by its own terminations) — the baselines' buffers — as masked arrays.
* ``windows``: fixed-length windows of a view (the originals' ``trace_len`` sampling on Box Pushing).

Submodules are imported explicitly (``from jaxmac.buffer import ring, views``).
"""
