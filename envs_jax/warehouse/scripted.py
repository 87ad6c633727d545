"""A centralised, hand-written cooperative policy for Warehouse A–E (jittable).

It reads the env internals (like the reference's own scripted controller) and follows a
per-variant *delivery plan*: the order in which F passes the 3·nH tools, which human
each is for (the c-th item of human h is tool c) and which robot carries it. The rules:

* **F**: if a tool is staged and the plan's robot for it is waiting at its table
  (arrived, timer <= 0, doing Get-Tool), pass it; else, if the staging area is empty,
  search the next planned tool; else wait (searching ahead would delay the pass).
* **robot** (when free): stay for a pass in progress to it; else deliver the tools it
  carries, in plan order, by going to (and re-issuing Go-W at) each human's work area until
  that human takes it; unless the plan says ``keep`` (wait at the table for its next tool
  first); else, if the plan still has tools for it, Get-Tool (re-issued after a time-out);
  else park at the tool-room spot.

The plans (worked out by hand from SPEC §2.1 travel times and §5.3 phase windows, F busy
every step so passes end at 10, 20, 30, …):

* A, B: robots alternate, each delivers right away: A 533, B 533 (the upper bound).
* C (2 robots, 9 tools): a round trip to W1/W2 (18 steps + 1 waiting) is too long for
  strict alternation (20 steps between a robot's passes), so F waits 2 steps once (4th
  pass ends at 42) and later each robot carries two tools in one trip (robot 0 the tool 1s
  of humans 1, 2; robot 1 their tool 2s); the last tool goes to W0 at step 99: 801 (the
  reference's best, bound 803).
* D: three robots in rotation: 803 (the bound).
* E: rotation; the fourth tool 0 is necessarily late, given to human 2 whose later
  deadlines then still fit: 1053 (the bound).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from envs_jax.core import EnvState
from envs_jax.warehouse.env import WarehouseEnv

# variant -> [(human, robot, keep)] in pass order.
PLANS: dict[str, tuple[tuple[int, int, bool], ...]] = {
    "A": ((0, 0, False), (1, 1, False), (0, 0, False), (1, 1, False), (0, 0, False), (1, 1, False)),
    "B": ((0, 0, False), (0, 1, False), (0, 0, False), (1, 1, False), (1, 0, False), (1, 1, False)),
    "C": ((0, 0, False), (1, 1, False), (2, 0, False), (0, 1, False), (1, 0, True), (2, 0, False),
          (1, 1, True), (2, 1, False), (0, 0, False)),
    "D": ((2, 0, False), (1, 1, False), (0, 2, False), (2, 0, False), (1, 1, False), (0, 2, False),
          (2, 0, False), (1, 1, False), (0, 2, False)),
    "E": ((1, 0, False), (3, 1, False), (0, 2, False), (2, 0, False), (1, 1, False), (3, 2, False),
          (0, 0, False), (2, 1, False), (1, 2, False), (3, 0, False), (0, 1, False), (2, 2, False)),
}


class ScriptedPolicy:
    """``policy(state) -> actions i32[n]`` for one (unbatched) state; ``vmap`` for batches.

    Busy agents get their running macro-action (ignored by the env anyway). Meant for the
    paper configs (no motion noise).
    """

    def __init__(self, env: WarehouseEnv, plan: tuple[tuple[int, int, bool], ...] | None = None):
        plan = PLANS[env.layout.variant] if plan is None else plan
        n_h, n_t = env.n_humans, env.n_robots
        human = np.array([p[0] for p in plan], np.int32)
        if sorted(human.tolist()) != sorted(list(range(n_h)) * 3) or not all(0 <= p[1] < n_t for p in plan):
            raise ValueError(f"{env.spec.name}: a plan must name every human 3 times and robots in 0..{n_t - 1}")
        self.env = env
        self.human = human
        self.robot = np.array([p[1] for p in plan], np.int32)
        self.keep = np.array([p[2] for p in plan], bool)
        self.tool = np.array([np.sum(human[:k] == human[k]) for k in range(len(plan))], np.int32)

    def __call__(self, state: EnvState):
        env, core = self.env, state.core
        n_t = env.n_robots
        human, robot, tool = (jnp.asarray(x) for x in (self.human, self.robot, self.tool))
        items = jnp.arange(len(self.human))
        n_found = jnp.sum(core.found)
        n_staged = jnp.sum(core.staging >= 0)
        n_passed = n_found - n_staged
        handed = jnp.minimum(core.h_phase + core.h_got, 3)  # tools each human has received
        delivered = handed[human] > tool
        passed = items < n_passed
        mine = robot[None, :] == jnp.arange(n_t)[:, None]  # [nT, items]
        held = mine & passed & ~delivered
        pending = (mine & ~passed).any(axis=1)
        last_received = jnp.max(jnp.where(mine & passed, items, -1), axis=1)
        keep = jnp.where(last_received >= 0, jnp.asarray(self.keep)[jnp.maximum(last_received, 0)], False)
        passing_to = jnp.where((core.f_act >= 1) & (core.f_act <= n_t) & ~state.mac_done[n_t], core.f_act - 1, -1)
        first_held = jnp.argmax(held, axis=1)

        go_deliver = held.any(axis=1) & ~keep
        robot_choice = jnp.where(
            passing_to == jnp.arange(n_t), env.get_tool,
            jnp.where(go_deliver, human[first_held], jnp.where(pending, env.get_tool, env.go_tr)),
        )
        robot_act = jnp.where(state.mac_done[:n_t], robot_choice, state.mac[:n_t])

        nxt = jnp.clip(n_passed, 0, len(self.human) - 1)
        r = robot[nxt]
        ready = (core.rb_wp[r] == env.get_tool) & (core.rb_tau[r] <= 0) & (robot_act[r] == env.get_tool)
        search = 1 + n_t + tool[jnp.clip(n_found, 0, len(self.human) - 1)]
        f_choice = jnp.where(
            (n_staged > 0) & ready, 1 + r,
            jnp.where((n_staged == 0) & (n_found < len(self.human)), search, 0),
        )
        f_act = jnp.where(state.mac_done[n_t], f_choice, state.mac[n_t])
        return jnp.concatenate([robot_act, f_act[None]]).astype(jnp.int32)
