"""``jaxmac.drawing``: every env family's state drawn on a matplotlib ``Figure`` (agents, items, legend), checked on
the artists, not on pixels; the frame grid and the GIF; the text symbols' legends that ``jaxmac rollout`` prints."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from matplotlib.figure import Figure

import envs_jax
from jaxmac import drawing

FAMILIES = ["boxpushing-6x6", "boxpushing-10x10", "overcooked-A", "overcooked-B", "warehouse-A", "warehouse-E"]


def _reset(name):
    env = envs_jax.make(name)
    state, _ = env.reset(jax.random.key(0))
    return env, state


def _drawn(env, state, legend=True):
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    entries = drawing.draw_state(env, state, ax, legend=legend)
    return fig, ax, entries


def _gids(ax, gid):
    return [p for p in ax.patches if p.get_gid() == gid]


@pytest.mark.parametrize("name", FAMILIES)
def test_reset_state_draws_one_marker_per_agent_and_a_legend(name):
    env, state = _reset(name)
    _, ax, entries = _drawn(env, state)
    agents = drawing.agent_patches(ax)
    assert len(agents) == env.spec.num_agents
    colours = {tuple(p.get_facecolor()) for p in agents}
    assert len(colours) == env.spec.num_agents, "every agent has its own colour"
    for patch in agents:  # numbered: a text at every agent's centre
        centre = tuple(np.round(getattr(patch, "center", getattr(patch, "xy", None)), 6))
        assert any(tuple(np.round(t.get_position(), 6)) == centre and t.get_text() for t in ax.texts), centre
    legend = ax.get_legend()
    assert legend is not None
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == [label for _, label in entries] and len(labels) > env.spec.num_agents
    if name.startswith("boxpushing"):
        assert len(_gids(ax, "box")) == 3  # two small boxes and the big one
    elif name.startswith("overcooked"):
        assert len(_gids(ax, "food")) == 3 and len(_gids(ax, "plate")) == 2
    else:
        assert len(_gids(ax, "work_area")) == env.n_humans


def test_overcooked_held_plated_and_chopped_items():
    """Agent 1 holds plate 1 with a chopped tomato and lettuce; the onion lies on knife 1 after two chops: still three
    foods and two plates, the chopped ones as stars (polygons), the onion as a disc with its chop count."""
    from matplotlib.patches import Circle, Polygon

    env, state = _reset("overcooked-A")
    core = state.core
    core = core.replace(hold=core.hold.at[0].set(3), chop=jnp.array([3, 3, 2], jnp.int32),
                        plate_has=core.plate_has.at[0, :2].set(True), pos=core.pos.at[2].set(jnp.array([1, 0])))
    _, ax, _ = _drawn(env, state.replace(core=core), legend=False)
    foods = _gids(ax, "food")
    assert len(foods) == 3 and len(_gids(ax, "plate")) == 2 and len(drawing.agent_patches(ax)) == 3
    assert sum(isinstance(p, Polygon) for p in foods) == 2 and sum(isinstance(p, Circle) for p in foods) == 1
    assert "2" in {t.get_text() for t in ax.texts}  # the onion's chop count


def test_boxpushing_agents_sharing_a_cell_or_off_the_grid():
    env, state = _reset("boxpushing-6x6")
    core = state.core.replace(pos=jnp.array([[2, 2], [2, 2]], jnp.int32))
    _, ax, _ = _drawn(env, state.replace(core=core), legend=False)
    centres = [tuple(p.center) for p in drawing.agent_patches(ax)]
    assert len(centres) == 2 and centres[0] != centres[1]  # side by side, both visible
    core = state.core.replace(pos=jnp.array([[-1, 2], [7, 2]], jnp.int32))  # no walls stop them (Q3)
    _, ax, _ = _drawn(env, state.replace(core=core), legend=False)
    lo, hi = ax.get_xlim()
    assert lo < -1 and hi > 7


def test_frame_grid_and_gif(tmp_path):
    from PIL import Image

    env, state = _reset("warehouse-E")
    states = [state] * 5
    fig = drawing.frames_figure(env, states, [f"frame {k}" for k in range(5)], [f"cap {k}" for k in range(5)],
                                title="a title")
    assert sum(len(drawing.agent_patches(ax)) for ax in fig.axes) == 5 * env.spec.num_agents
    fig.savefig(tmp_path / "grid.png")
    width, height = Image.open(tmp_path / "grid.png").size
    assert 600 < width < 3000 and height < 3000
    frames = drawing.write_gif(env, states, [f"frame {k}" for k in range(5)], str(tmp_path / "a.gif"), note="note")
    assert frames == 5 and Image.open(tmp_path / "a.gif").n_frames == 5


def test_other_envs_are_refused():
    class Other:
        spec = envs_jax.make("boxpushing-6x6").spec

    with pytest.raises(ValueError, match="no picture"):
        drawing.draw_state(Other(), None, Figure().subplots())


def _grid_lines(name, text):
    lines = text.splitlines()
    if name.startswith("boxpushing"):
        return lines[: envs_jax.make(name).config.grid]
    if name.startswith("overcooked"):
        return lines[:8]
    return lines[1:12]


@pytest.mark.parametrize("name", ["boxpushing-6x6", "overcooked-A", "warehouse-E"])
def test_every_text_symbol_is_in_the_legend(name):
    """Every non-digit character the text grid shows (reset, and after random steps) appears in the env's
    ``render_legend``."""
    from jaxmac.collect import random_policy, run_episode

    env, state = _reset(name)
    legend = env.render_legend
    assert legend and all(isinstance(s, str) and isinstance(m, str) and m for s, m in legend)
    known = set("".join(symbol for symbol, _ in legend)) | set(" 0123456789")
    init_carry, act = random_policy()
    _, _, final = run_episode(env, act, init_carry, None, jax.random.key(1), 0.0)
    for s in (state, final):
        shown = set("".join(_grid_lines(name, env.render(s))))
        assert shown <= known, (shown - known, env.render(s))


def test_rollout_prints_the_legend(capsys):
    from jaxmac.cli import main

    assert main(["rollout", "--env", "boxpushing-6x6", "--episodes", "2"]) == 0
    out = capsys.readouterr().out
    assert "legend:" in out
    for symbol, meaning in envs_jax.make("boxpushing-6x6").render_legend:
        assert re.search(rf"^  {re.escape(symbol)} +{re.escape(meaning)}$", out, re.MULTILINE), symbol


BACKEND_SCRIPT = r"""
import os, sys
import matplotlib
before = matplotlib.get_backend()
import jax, envs_jax
import jaxmac.drawing, jaxmac.runs.evaluation
out = sys.argv[1]
env = envs_jax.make("overcooked-A")
state, _ = env.reset(jax.random.key(0))
jaxmac.drawing.frames_figure(env, [state, state], ["a", "b"]).savefig(os.path.join(out, "grid.png"))
jaxmac.drawing.state_figure(env, state, "one").savefig(os.path.join(out, "one.png"))
jaxmac.drawing.write_gif(env, [state, state], ["a", "b"], os.path.join(out, "a.gif"))
print("BACKENDS", before, matplotlib.get_backend())
print("PYPLOT", "matplotlib.pyplot" in sys.modules)
"""


def test_drawing_keeps_the_global_backend(tmp_path):
    """As tests/test_plotting_backend.py for the drawings and the GIF writer: no pyplot, the backend unchanged."""
    env = dict(os.environ, MPLBACKEND="svg")
    proc = subprocess.run([sys.executable, "-c", BACKEND_SCRIPT, str(tmp_path)], env=env, capture_output=True,
                          text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    lines = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if " " in line)
    assert lines["BACKENDS"].split() == ["svg", "svg"]
    assert lines["PYPLOT"] == "False"
    for name in ("grid.png", "one.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "a.gif").read_bytes()[:6] == b"GIF89a"


def test_axis_labels_name_the_measure(tmp_path):
    import json

    from jaxmac.plotting import return_label, run_discount

    assert "γ = 0.98" in return_label(0.98) and "discounted" in return_label(0.98)
    assert "undiscounted" in return_label(1.0)
    assert "discounted" in return_label(None)
    csv_path = tmp_path / "metrics.csv"
    assert run_discount(str(csv_path)) is None  # no summary.json yet
    (tmp_path / "summary.json").write_text(json.dumps({"discount": 0.99}))
    assert run_discount(str(csv_path)) == 0.99
