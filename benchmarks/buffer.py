"""Episode-ring throughput and memory: Mac-SJERT views versus the Mac-JERT view.

    python benchmarks/buffer.py [--envs boxpushing-6x6 overcooked-A warehouse-A]
                                [--capacity 256] [--episodes-per-add 16] [--batch 32] [--n-step 5]

Per env (names not registered yet are skipped with a message):

* storage: bytes per slot (every view comes from it) and the largest round-trip error of
  the env's observations through the configured codec on the collected episodes;
* add: episodes/s of ``write_episode`` (vmapped over E rollouts, segment tables included)
  plus a donated ``ring.add`` of the E slots — the env rollout itself is excluded;
* sample: batches/s of ``ring.sample`` of B episodes followed by the Mac-SJERT views
  (``micro_view`` with n-step returns + ``macro_view``) or the Mac-JERT view (``jert_view``);
* view bytes: size per episode of each view if materialised.

Compile time is reported apart from run time (best of ``--repeats``). The ring is filled with
uniform-random episodes collected once up front.
"""

from __future__ import annotations

import argparse
import functools
import time

import jax
import numpy as np

import envs_jax
from jaxmac import collect
from jaxmac.buffer import episode, ring, views


def nbytes(tree) -> int:
    return int(sum(x.size * x.dtype.itemsize for x in jax.tree_util.tree_leaves(tree)))


def timed(fn, *args, repeats: int):
    """(compile seconds, best run seconds, output) of a jitted ``fn``."""
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        best = min(best, time.perf_counter() - t0)
    return compile_s, best, out


def bench_env(name: str, capacity: int, e: int, b: int, n_step: int, repeats: int) -> dict | None:
    try:
        env = envs_jax.make(name)
    except ValueError as err:
        print(f"[skip] {name}: not registered yet ({str(err).splitlines()[0][:100]})")
        return None
    config = episode.SlotConfig.from_spec(env.spec)
    keys = jax.random.split(jax.random.key(0), e)
    init_carry, act = collect.random_policy()
    reset_ts, traj, _ = jax.jit(jax.vmap(lambda k: collect.run_episode(env, act, init_carry, None, k, 0.0)))(keys)
    write = jax.vmap(functools.partial(episode.write_episode, config))

    # storage loss on what the env actually emits
    exact = max(config.obs.roundtrip_error(traj.obs_real), config.obs.roundtrip_error(traj.obs_macro))

    # add: write E slots + donated ring insert (ring pre-filled so add overwrites)
    def write_and_add(r, reset_ts, traj):
        return ring.add(r, write(reset_ts, traj))

    add_fn = jax.jit(write_and_add, donate_argnums=0)
    r = ring.init(config, capacity)
    t0 = time.perf_counter()
    compiled_add = add_fn.lower(r, reset_ts, traj).compile()
    add_compile = time.perf_counter() - t0
    for _ in range(-(-capacity // e)):  # fill the ring
        r = compiled_add(r, reset_ts, traj)
    jax.block_until_ready(r)
    add_best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = jax.block_until_ready(compiled_add(r, reset_ts, traj))
        add_best = min(add_best, time.perf_counter() - t0)

    def sjert(r, key):
        batch, _ = ring.sample(r, key, b)
        return views.micro_view(batch, n_step), views.macro_view(batch)

    def jert(r, key):
        batch, _ = ring.sample(r, key, b)
        return views.jert_view(batch)

    key = jax.random.key(1)
    sj_compile, sj_best, (micro, macro) = timed(jax.jit(sjert), r, key, repeats=repeats)
    j_compile, j_best, jv = timed(jax.jit(jert), r, key, repeats=repeats)
    cert = jax.jit(views.cert_view)(ring.sample(r, key, b)[0])
    return dict(
        name=name, config=config, exact=exact, slot_bytes=episode.slot_nbytes(config),
        ring_mib=nbytes(r) / 2**20,
        mean_len=float(np.mean(np.asarray(r.slots.length))),
        add_compile=add_compile, add_eps=e / add_best,
        sj_compile=sj_compile, sj_batches=1 / sj_best, j_compile=j_compile, j_batches=1 / j_best,
        micro_bytes=nbytes(micro) // b, macro_bytes=nbytes(macro) // b, jert_bytes=nbytes(jv) // b,
        cert_bytes=nbytes(cert) // b,
        macro_per_ep=float(np.asarray(macro.mask).sum()) / b, jert_per_ep=float(np.asarray(jv.mask).sum()) / b,
    )


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", nargs="+", default=["boxpushing-6x6", "boxpushing-14x14", "overcooked-A", "warehouse-A"])
    p.add_argument("--capacity", type=int, default=256, help="ring size N")
    p.add_argument("--episodes-per-add", type=int, default=16, help="E slots written and added per call")
    p.add_argument("--batch", type=int, default=32, help="B episodes per sample")
    p.add_argument("--n-step", type=int, default=5, help="n of the micro-view n-step returns")
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args(argv)
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}; N={a.capacity} E={a.episodes_per_add} "
          f"B={a.batch} n-step={a.n_step}; best of {a.repeats}")
    rows = [bench_env(n, a.capacity, a.episodes_per_add, a.batch, a.n_step, a.repeats) for n in a.envs]
    rows = [r for r in rows if r]
    if not rows:
        return
    print()
    print("| env | H | n | obs storage | max round-trip error | bytes/slot | ring MiB | mean len | add eps/s (compile s) "
          "| SJERT sample+micro+macro batches/s (compile s) | JERT sample+view batches/s (compile s) "
          "| view bytes/episode micro / macro / JERT / CERT | macro transitions / JERT transitions per episode |")
    print("|---" * 13 + "|")
    for r in rows:
        c = r["config"]
        print(f"| {r['name']} | {c.horizon} | {c.num_agents} | {c.obs.dtype}×{c.obs.scale:g} | {r['exact']:.1e} "
              f"| {r['slot_bytes']:,} | {r['ring_mib']:.1f} | {r['mean_len']:.1f} "
              f"| {r['add_eps']:,.0f} ({r['add_compile']:.1f}) | {r['sj_batches']:,.1f} ({r['sj_compile']:.1f}) "
              f"| {r['j_batches']:,.1f} ({r['j_compile']:.1f}) "
              f"| {r['micro_bytes']:,} / {r['macro_bytes']:,} / {r['jert_bytes']:,} / {r['cert_bytes']:,} "
              f"| {r['macro_per_ep']:.1f} / {r['jert_per_ep']:.1f} |")


if __name__ == "__main__":
    main()
