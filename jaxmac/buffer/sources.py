"""Data sources: what a gradient step reads, as ``sample(ring, fresh, key) -> batch``.

``fresh`` are the episode slots just collected (leaves ``[E, ...]``), ``ring`` the replay ring (``buffer.ring``).
Replay learners sample from the ring (``episode_source``; windows of episodes: ``windows.window_source``); on-policy
learners read only the fresh episodes (``on_policy_source``) and store nothing but lengths (``store_length``).
"""

from __future__ import annotations

from typing import Any, Callable

from jaxmac.buffer import ring as ring_lib
from jaxmac.buffer.episode import EpisodeSlot


def episode_source(batch_size: int):
    """The trainer's default: ``batch_size`` whole episodes, uniformly from the ring."""

    def sample(ring, fresh, key):
        del fresh
        return ring_lib.sample(ring, key, batch_size)[0]

    return sample


def on_policy_source(prepare: Callable[[EpisodeSlot], Any]):
    """The on-policy data source: the episodes just collected (leaves ``[E, ...]``), through ``prepare`` (the views
    the learner trains on). The ring is not read; such a learner stores only each episode's length in it."""

    def sample(ring, fresh, key):
        del ring, key
        return prepare(fresh)

    return sample


def store_length(slot: EpisodeSlot):
    """``Algorithm.store`` of an on-policy learner: the ring keeps nothing but the episode's length."""
    return slot.length
