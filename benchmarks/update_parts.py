"""ToMacVF's update at Overcooked-A's full-length shapes, piece by piece in isolation: what each shape can reach here.

    taskset -c 0 python benchmarks/update_parts.py [--repeats 9]

Two tables (milliseconds are medians of ``--repeats`` calls of ``jax.jit``; run it on an idle core):

* **matmuls**: the per-row layers' matmul, [B·T·n × din] · [din × dout] with B 64, T 201, n 3, timed forward, as the
  input gradient (dX = dY Wᵀ) and as the weight gradient (dW = Xᵀ dY, a reduction over 38,592 rows) — with one weight
  shared by every row, with one weight per agent in the agent-minor layout the networks take ([B·T, n, din],
  einsum), and agent-major ([n, B·T, din], a batched matmul);
* **sequential and attention parts**: the GRU recurrence (``networks.agent.gru_scan`` vmapped over the agents, h 32)
  and the causal temporal attention (``networks.atpg.causal_attention``, d 32), each as the update runs it: the
  online pass with its backward plus a target forward.

The update's own split is ``benchmarks/update_profile.py --roofline``; these are the rates its parts are measured
against (docs/training.md, "Where the update's time goes").
"""

from __future__ import annotations

import argparse
import statistics
import time

B, T, N_AGENTS, HIDDEN, EMBED = 64, 201, 3, 32, 32


def median_seconds(fn, *args, repeats: int = 9) -> float:
    import jax

    fn = jax.jit(fn)
    jax.block_until_ready(fn(*args))  # compile
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def matmul_rows(repeats: int) -> list[str]:
    import jax
    import jax.numpy as jnp

    key, rows, n = jax.random.key(0), B * T * N_AGENTS, N_AGENTS
    lines = ["| shape | weights | forward | dX | dW |", "|---|---|---|---|---|"]
    for din, dout in ((64, 64), (64, 96), (32, 64), (96, 64)):
        gflop = 2 * rows * din * dout / 1e9
        x, dy = jax.random.normal(key, (rows, din)), jax.random.normal(key, (rows, dout))
        w, w_agents = jax.random.normal(key, (din, dout)), jax.random.normal(key, (n, din, dout))
        xa, dya = x.reshape(B * T, n, din), dy.reshape(B * T, n, dout)
        xm, dym = x.reshape(n, B * T, din), dy.reshape(n, B * T, dout)
        layouts = {
            "shared": ((lambda x, w: x @ w, x, w), (lambda dy, w: dy @ w.T, dy, w), (lambda x, dy: x.T @ dy, x, dy)),
            "per agent, agent-minor": ((lambda x, w: jnp.einsum("rni,nio->rno", x, w), xa, w_agents),
                                       (lambda dy, w: jnp.einsum("rno,nio->rni", dy, w), dya, w_agents),
                                       (lambda x, dy: jnp.einsum("rni,rno->nio", x, dy), xa, dya)),
            "per agent, agent-major": ((lambda x, w: x @ w, xm, w_agents),
                                       (lambda dy, w: dy @ jnp.swapaxes(w, 1, 2), dym, w_agents),
                                       (lambda x, dy: jnp.swapaxes(x, 1, 2) @ dy, xm, dym)),
        }
        for name, calls in layouts.items():
            rates = [gflop / median_seconds(fn, *args, repeats=repeats) for fn, *args in calls]
            lines.append(f"| [{rows:,} × {din}] · [{din} × {dout}] | {name} | "
                         + " | ".join(f"{r:.0f} GFLOP/s" for r in rates) + " |")
    return lines


def part_rows(repeats: int) -> list[str]:
    import jax
    import jax.numpy as jnp

    from jaxmac.networks.agent import gru_scan
    from jaxmac.networks.atpg import causal_attention

    key, n, h, d = jax.random.key(0), N_AGENTS, HIDDEN, EMBED
    gx = jax.random.normal(key, (n, B, T, 3 * h))
    u, b_hn = 0.1 * jax.random.normal(key, (n, h, 3 * h)), jnp.zeros((n, h))
    reset, carry = jnp.zeros((n, B, T), bool).at[..., 0].set(True), jnp.zeros((n, B, h))
    gru = jax.vmap(gru_scan)

    def gru_update(gx, u, u_target):
        grads = jax.grad(lambda gx, u: jnp.sum(gru(gx, reset, carry, u, b_hn)[0] ** 2), argnums=(0, 1))(gx, u)
        return grads, gru(gx, reset, carry, u_target, b_hn)[0]

    q = jax.random.normal(key, (B, n, T, d))
    segment, window = jnp.zeros((B, 1, T), jnp.int32), jnp.asarray(0, jnp.int32)

    def attention_update(q, k, v):
        grads = jax.grad(lambda q, k, v: jnp.sum(causal_attention(q, k, v, segment, window) ** 2),
                         argnums=(0, 1, 2))(q, k, v)
        return grads, causal_attention(0.9 * q, k, v, segment, window)

    # matmul GFLOP: GRU 3 passes of h·3h per agent, row and step; attention (2 forward matmuls over the 3/4 of T × T
    # its two query blocks compute) × (online forward + its backward's 4 + target forward 2) / 2
    gru_gflop = 3 * 2 * n * B * T * h * 3 * h / 1e9
    attention_gflop = 0.75 * 2 * B * n * T * T * d * (2 + 4 + 2) / 1e9
    lines = ["| part (online forward + backward, target forward) | GFLOP | ms | GFLOP/s |", "|---|---|---|---|"]
    for name, gflop, fn, args in (("GRU recurrence, 201 steps", gru_gflop, gru_update, (gx, u, 0.9 * u)),
                                  ("causal temporal attention", attention_gflop, attention_update,
                                   (q, 0.5 * q, 0.3 * q))):
        seconds = median_seconds(fn, *args, repeats=repeats)
        lines.append(f"| {name} | {gflop:.2f} | {1e3 * seconds:.1f} | {gflop / seconds:.1f} |")
    return lines


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=9)
    args = p.parse_args(argv)
    print(f"Overcooked-A full-length shapes: B {B}, T {T}, n {N_AGENTS}; one process, the cores it may use\n")
    print("\n".join(matmul_rows(args.repeats)) + "\n")
    print("\n".join(part_rows(args.repeats)))


if __name__ == "__main__":
    main()
