"""Where a run runs and what it needs: JAX's persistent compilation cache, host devices, the sharding of seeds over
devices, and the budget and memory checks done before anything compiles.
"""

from __future__ import annotations

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

from jaxmac.config import TrainConfig
from jaxmac.runs.programs import Programs, programs_for
from jaxmac.seeds import SEED_AXIS

def enable_compilation_cache(path: str | None = None) -> None:
    """JAX's persistent compilation cache: a re-run skips most compilation."""
    path = path or os.environ.get("JAXMAC_CACHE", os.path.expanduser("~/.cache/jaxmac/xla"))
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def use_host_devices(count: int) -> None:
    """Let a CPU-only JAX split into ``count`` host devices (one per core) so that seeds can be sharded over them.
    Must run before JAX starts its backend (the first computation); on an accelerator it changes nothing."""
    if count > 1:
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={count}".strip()


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity: 1 under ``taskset -c 0``)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_devices(seed_counts: list[int]) -> int:
    """The devices to shard seeds over when none are asked for: one per usable core, when every count of seeds in
    ``seed_counts`` splits evenly over them, else 1. On this project's 2-core machine one process with 4 seeds
    sharded over both cores trained ToMacVF on Overcooked-A at 1.21x the episodes per second of two processes of 2
    seeds each, one per core (``benchmarks/train_throughput.py``; docs/training.md). Call it before JAX starts; once
    it has, ``fit_devices`` keeps the count within the devices JAX sees."""
    cores = usable_cores()
    return cores if cores > 1 and seed_counts and all(n % cores == 0 for n in seed_counts) else 1


def fit_devices(devices: int, seed_counts: list[int]) -> int:
    """``devices`` (a default, not a request) cut to what JAX sees — an accelerator host has no per-core devices —
    and to 1 when the seeds do not split evenly over what is left."""
    devices = min(devices, len(jax.devices()))
    return devices if all(n % devices == 0 for n in seed_counts) else 1


def seed_sharding(seeds: int, devices: int):
    """The ``NamedSharding`` that splits a state's leading seed axis over the first ``devices`` devices (a mesh
    axis named ``SEED_AXIS``), or None for one device. One jitted program then runs every device's seeds (the same
    command on one GPU, several GPUs, or ``jax.distributed`` hosts)."""
    if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
        raise ValueError(f"devices={devices!r} must be a positive integer")
    if devices == 1:
        return None
    available = jax.devices()
    if devices > len(available):
        raise ValueError(f"devices={devices}: JAX sees {len(available)} device(s) ({available[0].platform}); on a CPU "
                         f"use `jaxmac train --devices N` (it splits the host into N devices before JAX starts)")
    if seeds % devices:
        raise ValueError(f"seeds={seeds} cannot be split evenly over devices={devices}: use a number of seeds that "
                         f"is a multiple of the devices, or fewer devices")
    mesh = jax.sharding.Mesh(np.array(available[:devices]), (SEED_AXIS,))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(SEED_AXIS))


def placed(state, sharding=None):
    """``state`` committed to its device(s) (``sharding``, or the first device), as a restored checkpoint is: a
    fresh and a resumed run then lower to the same program, and the second one loads it from the persistent
    compilation cache instead of compiling it again (an uncommitted array lowers without a sharding)."""
    return jax.device_put(state, sharding if sharding is not None else jax.devices()[0])


# --- sizes checked before anything compiles -------------------------------------------------------------------------

def check_budget(config: TrainConfig) -> None:
    """Every round collects ``num_envs`` episodes per seed: a budget smaller than one round would be overrun."""
    if config.num_envs > config.episodes:
        raise ValueError(f"episodes={config.episodes} is less than one round of num_envs={config.num_envs} episodes: "
                         f"the run would train {config.num_envs} episodes per seed, "
                         f"{config.num_envs / config.episodes:.4g}x its budget. Lower num_envs to at most "
                         f"{config.episodes}, or raise episodes")


def rounded_budget_notice(config: TrainConfig) -> str | None:
    """What a run trains when its budget is not a whole number of rounds (``num_envs`` episodes per seed each): the
    last round is collected whole. ``None`` when it is."""
    if config.episodes % config.num_envs == 0:
        return None
    return (f"episodes={config.episodes} is not a multiple of num_envs={config.num_envs} (the episodes of one round per "
            f"seed): the run trains {config.rounds} rounds, {config.rounds * config.num_envs} episodes per seed")


def say_rounded_budget(config: TrainConfig) -> None:
    """Print ``rounded_budget_notice`` on stderr where there is one (a new run's start, a raised budget)."""
    notice = rounded_budget_notice(config)
    if notice:
        print(f"jaxmac: {notice}", file=sys.stderr)


def check_whole_chunks(config: TrainConfig, rounds_per_chunk: int) -> None:
    """A run trains whole chunks of ``rounds_per_chunk`` rounds: a budget (raised on a resume) that ends inside one
    would be overrun, so it is refused, naming the budgets around it that end on a chunk."""
    unit = rounds_per_chunk * config.num_envs
    if config.rounds % rounds_per_chunk:
        below, above = config.episodes // unit * unit, (config.episodes // unit + 1) * unit
        raise ValueError(f"episodes={config.episodes} ends inside a chunk: this run trains chunks of {rounds_per_chunk} "
                         f"rounds x num_envs={config.num_envs} = {unit} episodes per seed, so it would train "
                         f"{above}. Give episodes=" + (f"{below} or {above}" if below else f"{above}"))


def _nbytes(tree) -> float:
    def itemsize(dtype) -> int:
        try:
            return np.dtype(dtype).itemsize
        except TypeError:  # a PRNG key's extended dtype
            return 8

    return sum(float(np.prod(leaf.shape, dtype=np.float64)) * itemsize(leaf.dtype)
               for leaf in jax.tree_util.tree_leaves(tree))


def abstract_state(programs: Programs, seeds: int):
    """The shapes and dtypes of a fresh training state of ``seeds`` seeds (traced, nothing allocated or compiled)."""
    keys = jax.eval_shape(lambda: jax.vmap(jax.random.key)(jnp.arange(seeds)))
    return jax.eval_shape(programs.init, keys)


def memory_estimate(programs: Programs, seeds: int) -> tuple[float, str]:
    """A rough estimate of the memory a run needs (bytes) and what it is made of: the training state (the replay ring
    of ``buffer_episodes`` episodes per seed above all), a batch of ``batch_size`` episodes gathered for a gradient
    step (counted four times: the gather, its encodings, activations and gradients) and a round's ``num_envs``
    episodes (twice: rollout and write), all per seed."""
    config = programs.trainer.config
    state = abstract_state(programs, seeds)
    state_bytes = _nbytes(state)
    ring_bytes = _nbytes(state.ring)
    per_episode = ring_bytes / max(1, seeds * config.buffer_episodes)
    batch = 4.0 * seeds * config.batch_size * per_episode
    envs = 2.0 * seeds * (config.num_envs + config.eval_episodes) * per_episode
    gib = 2.0 ** 30
    detail = (f"training state {state_bytes / gib:.3g} GiB (replay ring of buffer_episodes={config.buffer_episodes} "
              f"x {seeds} seed(s): {ring_bytes / gib:.3g} GiB), batches of batch_size={config.batch_size}: "
              f"{batch / gib:.3g} GiB, rounds of num_envs={config.num_envs}: {envs / gib:.3g} GiB")
    return state_bytes + batch + envs, detail


def machine_memory(devices: int = 1) -> tuple[float, str]:
    """The memory a run can use (bytes) and where it is: the accelerators' (``devices`` of them) or this host's RAM."""
    device = jax.devices()[0]
    if device.platform != "cpu":
        try:
            limit = (device.memory_stats() or {}).get("bytes_limit")
        except Exception:  # a backend without memory statistics
            limit = None
        if limit:
            return float(limit) * devices, f"{devices} {device.platform} device(s) of {limit / 2 ** 30:.3g} GiB"
    try:
        ram = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return float("inf"), "unknown"
    return ram, f"this machine's {ram / 2 ** 30:.3g} GiB of RAM"


def check_memory(programs: Programs, seeds: int, devices: int = 1) -> None:
    """Refuse, before compiling, a run whose sizes (ring, batch, envs) need more memory than the machine has."""
    need, detail = memory_estimate(programs, seeds)
    have, where = machine_memory(devices)
    if need > have:
        raise ValueError(f"this run needs about {need / 2 ** 30:.3g} GiB ({detail}) but has {where}: lower "
                         "buffer_episodes, batch_size, num_envs or the number of seeds")


def check_new_run(config: TrainConfig, seeds: int, devices: int = 1, rounds_per_chunk: int | None = None) -> None:
    """What ``train_run`` checks of a new run before it writes or compiles anything: the budget and the memory."""
    check_budget(config)
    check_memory(programs_for(config, rounds_per_chunk), seeds, devices)
