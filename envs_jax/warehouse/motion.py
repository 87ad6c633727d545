"""Robot motion of the Warehouse domain (SPEC §2.1), exact and continuous.

The reference moves a robot heading to waypoint q, standing at p, by

    d = round2(|q - p|)                      # numpy rounding of the float64 distance
    d <= 0.8:  p := q                        # arrival (or already there)
    else:      p := p + ((0.8 / d) * (q - p) + eps),  timer := d - 0.8

in float64. float32 cannot hold those positions, so we never do this arithmetic in JAX
when there is no motion noise: a move cannot be interrupted and always starts at the start
position or a waypoint, so every reachable position lies on a finite *motion graph* that we
build here once, in numpy float64 with exactly the reference's operations. The JAX state
then stores a point id; a step is two table look-ups (next point, rounded distance in
hundredths). Positions, timers (``d - 0.8`` is kept as the integer ``d_cents - 80``) and
the F "robot at its table" flag are thereby bit-exact. With motion noise (optional, never
used by the paper) positions leave the graph and :func:`continuous_move` does the rule in
float32 (agrees with float64 to ~1e-6; the rounding of ``d`` could in principle differ
at an exact .005 tie).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from envs_jax.warehouse.variants import SPEED_CENTS, Layout

UNREACHABLE = np.iinfo(np.int32).max // 2  # distance entry of (point, target) pairs no run can reach


@dataclasses.dataclass(frozen=True)
class MotionGraph:
    """Per-robot motion tables, padded to the largest point count P over robots.

    Point ids ``0 … nW-1`` are robot i's waypoints ``W_i`` (so arriving with action k puts
    the robot on point k); ``start[i]`` is its start point. Entries of (point, target)
    pairs that no run can reach (a robot midway to one waypoint never heads to another)
    hold ``next = point`` and ``dist_cents = UNREACHABLE``.
    """

    xy64: np.ndarray  # f64[nT, P, 2] exact reference coordinates of each point
    xy: np.ndarray  # f32[nT, P, 2] the same, rounded to float32 (for the state vector)
    next: np.ndarray  # i32[nT, P, nW] point after one step towards waypoint k (k itself on arrival)
    dist_cents: np.ndarray  # i32[nT, P, nW] round2(distance to waypoint k) in hundredths
    start: np.ndarray  # i32[nT] start point of each robot
    n_points: np.ndarray  # i32[nT] true point count of each robot

    def point_of(self, robot: int, xy: np.ndarray) -> int:
        """Id of the point with exactly these float64 coordinates, or -1."""
        hit = np.flatnonzero((self.xy64[robot, : self.n_points[robot]] == np.asarray(xy, np.float64)).all(-1))
        return int(hit[0]) if len(hit) else -1


def round2_cents(dist: np.ndarray | float) -> int:
    """numpy's ``round(x, 2)`` (scale by 100, round half to even) as an integer in 1/100."""
    return int(np.rint(np.float64(dist) * 100.0))


def _reference_step(p: np.ndarray, q: np.ndarray) -> tuple[int, np.ndarray]:
    """One step of the reference rule in float64, noise 0: (distance cents, new position)."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    dist = np.sqrt(dx**2 + dy**2)
    d_cents = round2_cents(dist)
    if d_cents <= SPEED_CENTS:
        return d_cents, q.copy()
    d = np.rint(dist * 100.0) / 100.0  # the float64 value the reference divides by
    speed = np.float64(SPEED_CENTS) / 100.0
    return d_cents, np.array([p[0] + (speed / d * dx + 0.0), p[1] + (speed / d * dy + 0.0)])


def _robot_graph(waypoints: list[np.ndarray], start: np.ndarray):
    """Points reachable by one robot and its edges ``{(point, k): (next point, d_cents)}``.

    Points are deduplicated by exact coordinates (D/E robot 1 starts on TRW)."""
    points: list[np.ndarray] = []
    index: dict[bytes, int] = {}

    def point_id(xy: np.ndarray) -> int:
        key = xy.tobytes()
        if key not in index:
            index[key] = len(points)
            points.append(xy)
        return index[key]

    for w in waypoints:
        point_id(w)
    start_id = point_id(start)
    edges: dict[tuple[int, int], tuple[int, int]] = {}
    for origin in range(len(points)):  # the waypoints and the start point
        for k, q in enumerate(waypoints):
            p = origin
            while (p, k) not in edges:
                d_cents, xy = _reference_step(points[p], q)
                nxt = k if d_cents <= SPEED_CENTS else point_id(xy)
                edges[(p, k)] = (nxt, d_cents)
                if nxt == k:
                    break
                p = nxt
    return points, edges, start_id


def build_motion_graph(layout: Layout) -> MotionGraph:
    """Enumerate every position a noiseless robot can reach (a few hundred per robot)."""
    n_t = layout.n_robots
    per_robot = [
        _robot_graph([np.array(w, np.float64) for w in layout.waypoints(i)], np.array(layout.starts[i], np.float64))
        for i in range(n_t)
    ]
    n_p = max(len(points) for points, _, _ in per_robot)
    n_w = len(layout.waypoints(0))
    xy64 = np.zeros((n_t, n_p, 2))
    nxt = np.tile(np.arange(n_p, dtype=np.int32)[None, :, None], (n_t, 1, n_w))
    dist = np.full((n_t, n_p, n_w), UNREACHABLE, np.int32)
    for i, (points, edges, _) in enumerate(per_robot):
        xy64[i, : len(points)] = np.stack(points)
        for (p, k), (q, d) in edges.items():
            nxt[i, p, k], dist[i, p, k] = q, d
        # Points are unique by coordinates, so "exactly at the table" means "on the table node".
        at_table = np.flatnonzero((xy64[i, : len(points)] == np.array(layout.tables[i])).all(-1))
        assert at_table.tolist() == [layout.n_humans + 1], "the table node must be unique"
    return MotionGraph(
        xy64=xy64,
        xy=xy64.astype(np.float32),
        next=nxt,
        dist_cents=dist,
        start=np.array([s for _, _, s in per_robot], np.int32),
        n_points=np.array([len(points) for points, _, _ in per_robot], np.int32),
    )


def continuous_move(xy: jnp.ndarray, target: jnp.ndarray, eps: jnp.ndarray):
    """The rule in float32 for any position (motion-noise mode).

    Args: ``xy`` f32[..., 2] positions, ``target`` f32[..., 2] waypoints, ``eps`` f32[..., 2]
    noise added to a moving step. Returns (``dist_cents`` i32[...], moved position f32[..., 2]
    (only meaningful where ``dist_cents > SPEED_CENTS``)).
    """
    delta = target - xy
    dist = jnp.sqrt(jnp.sum(delta * delta, axis=-1))
    d_cents = jnp.rint(dist * 100.0).astype(jnp.int32)
    d = jnp.maximum(d_cents, 1).astype(jnp.float32) / 100.0
    factor = (SPEED_CENTS / 100.0) / d
    return d_cents, xy + (factor[..., None] * delta + eps)
